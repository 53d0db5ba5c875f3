"""The Lua scripts of the job state; each gets every key it touches through KEYS.

Scripts that need the time read Redis's own clock, so workers and API hosts need not agree on it.
"""

from __future__ import annotations

# KEYS: job. ARGV: allowed states (comma-separated, '' = any), then field, value pairs.
# Conditional HSET: a deleted job is never half re-created by a late worker update.
UPDATE = """
if redis.call('exists', KEYS[1]) == 0 then return 0 end
if ARGV[1] ~= '' then
  local s = redis.call('hget', KEYS[1], 'state')
  local ok = false
  for st in string.gmatch(ARGV[1], '[^,]+') do if st == s then ok = true end end
  if not ok then return 0 end
end
redis.call('hset', KEYS[1], unpack(ARGV, 2))
return 1
"""

# KEYS: job, running set, queue. ARGV: job id, then field, value pairs.
# Queued (or running again) -> running: joins the running set, then leaves the queue order,
# so it is always counted ahead of the others. Not queued or running: leaves the queue only.
START = """
local s = redis.call('hget', KEYS[1], 'state')
if s ~= 'queued' and s ~= 'running' then
  redis.call('zrem', KEYS[3], ARGV[1])
  return 0
end
redis.call('hset', KEYS[1], unpack(ARGV, 2))
redis.call('sadd', KEYS[2], ARGV[1])
redis.call('zrem', KEYS[3], ARGV[1])
return 1
"""

# Fair order between owners: a queued job's score is round * ROUND + arrival, where an owner's
# next job goes into the round now running (the round of the last job started) or, when the
# owner already has a job in that round or later, one round after its last one. Taking the
# lowest score is round-robin across owners (first come first served inside a round), and the
# queue's order is the order jobs start, so a queue position reads it directly.
ROUND = 2 ** 21  # arrivals per round before the tie-break wraps (scores stay exact to 2^53)

# KEYS: queue, fair clock, owners' last rounds, arrival counter. ARGV: job id, owner, front,
# ROUND.
# Queue a job in fair order ('1' = front: a job already started once, whose worker died).
ENQUEUE = """
if redis.call('zscore', KEYS[1], ARGV[1]) then return -1 end
if ARGV[3] == '1' then
  redis.call('zadd', KEYS[1], 0, ARGV[1])
  return 0
end
local clock = tonumber(redis.call('get', KEYS[2]) or '0')
local last = tonumber(redis.call('hget', KEYS[3], ARGV[2]) or '0')
local round = math.max(clock, last + 1)
redis.call('hset', KEYS[3], ARGV[2], round)
local unit = tonumber(ARGV[4])
local seq = redis.call('incr', KEYS[4]) % unit
redis.call('zadd', KEYS[1], 'NX', string.format('%d', round * unit + seq), ARGV[1])
return round
"""

# KEYS: queue, job, claim, running set, fair clock. ARGV: job id, worker, claim ttl ms, now,
# ROUND, then field, value pairs. Queued -> running on ``worker`` in one step: the claim is
# taken, the job joins the running set and leaves the queue, and the fair clock moves to its
# round.
# Returns 1 when taken, 0 when it left the queue meanwhile, -1 when it was no longer queued
# (removed from the queue), -2 when another worker claims it.
TAKE = """
local score = redis.call('zscore', KEYS[1], ARGV[1])
if not score then return 0 end
if redis.call('hget', KEYS[2], 'state') ~= 'queued' then
  redis.call('zrem', KEYS[1], ARGV[1])
  return -1
end
local holder = redis.call('get', KEYS[3])
if holder and holder ~= ARGV[2] then return -2 end
redis.call('set', KEYS[3], ARGV[2], 'PX', ARGV[3])
if (redis.call('hget', KEYS[2], 'started_at') or '') == '' then
  redis.call('hset', KEYS[2], 'started_at', ARGV[4])
end
redis.call('hset', KEYS[2], unpack(ARGV, 6))
redis.call('sadd', KEYS[4], ARGV[1])
redis.call('zrem', KEYS[1], ARGV[1])
local round = math.floor(tonumber(score) / tonumber(ARGV[5]))
if round > tonumber(redis.call('get', KEYS[5]) or '0') then
  redis.call('set', KEYS[5], round)
end
return 1
"""

# KEYS: its tombstone, running set. ARGV: job id.
# A worker's heartbeat puts its job back in the running set unless the job was deleted (a job
# Redis lost in a restart is re-seeded from state.json through that set; a deleted one must
# not come back).
MARK_RUNNING = """
if redis.call('exists', KEYS[1]) == 1 then return 0 end
redis.call('sadd', KEYS[2], ARGV[1])
return 1
"""

# KEYS: job, its claim, running set, queue. ARGV: job id, dead worker, max attempts, now, error.
# Running -> queued (or failed past the attempt bound), only while still held by the dead worker.
# A job queued again goes to the front of the queue: it had its turn already.
REQUEUE = """
if redis.call('hget', KEYS[1], 'state') ~= 'running' then return -1 end
if (redis.call('hget', KEYS[1], 'worker') or '') ~= ARGV[2] then return -1 end
if redis.call('exists', KEYS[2]) == 1 then return -1 end
local attempts = (tonumber(redis.call('hget', KEYS[1], 'attempts') or '0') or 0) + 1
redis.call('srem', KEYS[3], ARGV[1])
if attempts >= tonumber(ARGV[3]) then
  redis.call('hset', KEYS[1], 'state', 'failed', 'attempts', attempts, 'worker', '',
             'finished_at', ARGV[4], 'updated_at', ARGV[4], 'eta_s', '', 'error', ARGV[5])
  return 0
end
redis.call('hset', KEYS[1], 'state', 'queued', 'attempts', attempts, 'worker', '',
           'updated_at', ARGV[4], 'eta_s', '')
redis.call('zadd', KEYS[4], 0, ARGV[1])
return attempts
"""

# KEYS: job, its claim, running set, queue. ARGV: job id, worker, now.
# Running on ``worker`` -> queued at the front, its claim released: the worker was asked to stop
# and gives the job back (no attempt is counted; the job resumes from its checkpoints).
HAND_BACK = """
if redis.call('hget', KEYS[1], 'state') ~= 'running' then return 0 end
if (redis.call('hget', KEYS[1], 'worker') or '') ~= ARGV[2] then return 0 end
if redis.call('get', KEYS[2]) == ARGV[2] then redis.call('del', KEYS[2]) end
redis.call('srem', KEYS[3], ARGV[1])
redis.call('hset', KEYS[1], 'state', 'queued', 'worker', '', 'updated_at', ARGV[3], 'eta_s', '')
redis.call('zadd', KEYS[4], 0, ARGV[1])
return 1
"""

# KEYS: claim. ARGV: worker, ttl ms. Take or refresh a claim: only when free or already ours.
CLAIM = """
local holder = redis.call('get', KEYS[1])
if holder and holder ~= ARGV[1] then return 0 end
redis.call('set', KEYS[1], ARGV[1], 'PX', ARGV[2])
return 1
"""

# KEYS: claim. ARGV: worker. Release only our own claim.
RELEASE = """
if redis.call('get', KEYS[1]) == ARGV[1] then return redis.call('del', KEYS[1]) end
return 0
"""

# KEYS: worker's key, worker set. ARGV: name, ttl ms, info JSON.
BEAT = """
local t = redis.call('time')
local now = tonumber(t[1]) + tonumber(t[2]) / 1e6
redis.call('set', KEYS[1], ARGV[3], 'PX', ARGV[2])
redis.call('zadd', KEYS[2], now + tonumber(ARGV[2]) / 1000, ARGV[1])
redis.call('zremrangebyscore', KEYS[2], '-inf', now)
return 1
"""

# KEYS: worker set. Names of the workers whose heartbeat has not expired.
LIVE = """
local t = redis.call('time')
return redis.call('zrangebyscore', KEYS[1], tonumber(t[1]) + tonumber(t[2]) / 1e6, '+inf')
"""

# KEYS: an owner's recent submissions. ARGV: member, window s, limit.
# Sliding-window rate limit on Redis's clock: records the submission and returns -1 when under
# the limit, else the seconds until the oldest one in the window leaves it.
RATE = """
local t = redis.call('time')
local now = tonumber(t[1]) + tonumber(t[2]) / 1e6
local window = tonumber(ARGV[2])
redis.call('zremrangebyscore', KEYS[1], '-inf', now - window)
if redis.call('zcard', KEYS[1]) >= tonumber(ARGV[3]) then
  local oldest = redis.call('zrange', KEYS[1], 0, 0, 'WITHSCORES')
  return tostring(math.max(0, tonumber(oldest[2]) + window - now))
end
redis.call('zadd', KEYS[1], now, ARGV[1])
redis.call('expire', KEYS[1], math.ceil(window) + 1)
return '-1'
"""

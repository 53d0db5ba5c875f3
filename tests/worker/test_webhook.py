"""Webhooks: signed body, retries with backoff on failures, bounded attempts."""

from __future__ import annotations

import hashlib
import hmac
import json
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from worker.webhook import SIGNATURE_HEADER, send_webhook, sign


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
                self.end_headers()

            def log_message(self, *args: object) -> None:
                return

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/hook"
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
    assert send_webhook(receiver.url, payload, "s3cret", sleep=delays.append, tries=4)
    assert len(receiver.calls) == 3 and delays == [1.0, 2.0]
    body, headers = receiver.calls[-1]
    assert json.loads(body) == payload
    expected = "sha256=" + hmac.new(b"s3cret", body, hashlib.sha256).hexdigest()
    assert headers[SIGNATURE_HEADER] == expected == sign(body, "s3cret")


def test_gives_up_after_the_last_try_and_on_client_errors(receiver_factory) -> None:
    failing = receiver_factory([500])
    delays: list[float] = []
    assert not send_webhook(failing.url, {}, "k", sleep=delays.append, tries=3)
    assert len(failing.calls) == 3 and delays == [1.0, 2.0]
    refused = receiver_factory([404])
    assert not send_webhook(refused.url, {}, "k", sleep=delays.append, tries=3)
    assert len(refused.calls) == 1


def test_unreachable_receiver_and_unsigned_body(receiver_factory) -> None:
    assert not send_webhook("http://127.0.0.1:1/hook", {}, "", sleep=lambda _: None, tries=2,
                            timeout_s=1.0)
    receiver = receiver_factory([204])
    assert send_webhook(receiver.url, {"a": 1}, "", sleep=lambda _: None)
    assert SIGNATURE_HEADER not in receiver.calls[0][1]

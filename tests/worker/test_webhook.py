"""Webhooks: signed body, retries with backoff on failures, bounded attempts, no internal hosts,
and the connection pinned to the address that was checked (no DNS rebinding).

The receivers listen on 127.0.0.1, so the delivery tests pass ``allow_private=True`` (or make
127.0.0.1 count as public for the rebinding test).
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import json
import logging
import shutil
import socket
import ssl
import subprocess
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import httpx
import pytest

import worker.webhook
from worker.webhook import SIGNATURE_HEADER, refusal, send_webhook, sign

_GETADDRINFO = socket.getaddrinfo  # the real resolver, for the fakes below


class Receiver:
    """A local HTTP server answering with a scripted list of status codes."""

    def __init__(self, statuses: list[int], tls: ssl.SSLContext | None = None) -> None:
        self.statuses = statuses
        self.calls: list[tuple[bytes, dict[str, str]]] = []
        self.server_names: list[str | None] = []  # SNI of each TLS handshake
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
        if tls is not None:
            tls.sni_callback = lambda _sock, name, _ctx: self.server_names.append(name)
            self.server.socket = tls.wrap_socket(self.server.socket, server_side=True)
            self.url = f"https://127.0.0.1:{self.port}/hook"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()


@pytest.fixture()
def receiver_factory() -> Iterator:
    made: list[Receiver] = []

    def make(statuses: list[int], tls: ssl.SSLContext | None = None) -> Receiver:
        made.append(Receiver(statuses, tls))
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


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def _answers(addresses: tuple[str, ...], port: int | str | None) -> list:
    answers = []
    for address in addresses:
        family = socket.AF_INET6 if ":" in address else socket.AF_INET
        answers += _GETADDRINFO(address, port, family, socket.SOCK_STREAM)
    return answers


def _resolving_to(monkeypatch: pytest.MonkeyPatch, *addresses: str) -> list[str]:
    """Make every name resolve to ``addresses``; returns the names looked up.

    IP literals (what the HTTP client looks up once the address is pinned) resolve as usual.
    """
    return _rebinding(monkeypatch, addresses)


def _rebinding(monkeypatch: pytest.MonkeyPatch, first: tuple[str, ...],
               later: tuple[str, ...] | None = None) -> list[str]:
    """Make every name resolve to ``first`` on its first lookup and to ``later`` after (a
    rebinding DNS server); returns the names looked up. IP literals resolve as usual."""
    asked: list[str] = []

    def fake(host: str, port: int | str | None, *args: object, **kwargs: object) -> list:
        if _is_ip(host):
            return _GETADDRINFO(host, port, *args, **kwargs)  # type: ignore[arg-type]
        asked.append(host)
        return _answers(first if len(asked) == 1 or later is None else later, port)

    monkeypatch.setattr(socket, "getaddrinfo", fake)
    return asked


@pytest.fixture()
def no_env_proxy(monkeypatch: pytest.MonkeyPatch) -> None:
    """Point the proxy variables at a dead port: a delivery that used them would fail."""
    for name in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "http_proxy", "https_proxy",
                 "all_proxy"):
        monkeypatch.setenv(name, "http://127.0.0.1:1")
    for name in ("NO_PROXY", "no_proxy"):
        monkeypatch.delenv(name, raising=False)


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


def test_the_connection_goes_to_the_address_resolved_once(receiver_factory, monkeypatch,
                                                         no_env_proxy) -> None:
    receiver = receiver_factory([200])
    asked = _rebinding(monkeypatch, ("127.0.0.1",), later=("127.0.0.2",))
    url = f"http://hooks.example.com:{receiver.port}/hook"
    assert send_webhook(url, {"id": "j"}, "k", sleep=lambda _: None, tries=1, timeout_s=2.0,
                        allow_private=True)
    assert asked == ["hooks.example.com"]  # the HTTP client did not look the name up again
    assert len(receiver.calls) == 1
    assert receiver.calls[0][1]["Host"] == f"hooks.example.com:{receiver.port}"


def test_a_rebinding_name_cannot_reach_a_private_address(receiver_factory, monkeypatch,
                                                         caplog) -> None:
    """The check passes on a 'public' first answer; the second answer (private) is never used."""
    receiver = receiver_factory([200])
    real_check = worker.webhook.non_public_reason

    def loopback_receiver_is_public(address: str) -> str | None:
        return None if address == "127.0.0.1" else real_check(address)

    monkeypatch.setattr(worker.webhook, "non_public_reason", loopback_receiver_is_public)
    asked = _rebinding(monkeypatch, ("127.0.0.1",), later=("127.0.0.2",))
    url = f"http://hooks.example.com:{receiver.port}/hook"
    with caplog.at_level(logging.WARNING, logger="worker.webhook"):
        assert send_webhook(url, {"id": "j"}, "k", sleep=lambda _: None, tries=1,
                            timeout_s=2.0)
    assert asked == ["hooks.example.com"] and len(receiver.calls) == 1
    assert receiver.calls[0][1]["Host"] == f"hooks.example.com:{receiver.port}"
    # The next delivery resolves afresh: the private answer is checked and refused.
    assert not send_webhook(url, {"id": "j2"}, "k", sleep=lambda _: None, tries=1)
    assert len(receiver.calls) == 1 and "127.0.0.2" in caplog.text and "loopback" in caplog.text


def test_a_private_address_among_public_ones_is_refused_without_connecting(monkeypatch,
                                                                           caplog) -> None:
    def no_request(*args: object, **kwargs: object) -> httpx.Response:
        raise AssertionError("a refused webhook was sent")

    monkeypatch.setattr(httpx.HTTPTransport, "handle_request", no_request)
    asked = _resolving_to(monkeypatch, "93.184.216.34", "10.1.2.3")
    delays: list[float] = []
    with caplog.at_level(logging.WARNING, logger="worker.webhook"):
        assert not send_webhook("https://hooks.example.com/x", {"id": "job-9"}, "",
                                sleep=delays.append)
    assert asked == ["hooks.example.com"] and delays == []
    assert "job-9" in caplog.text and "10.1.2.3" in caplog.text and "private" in caplog.text


def test_the_next_vetted_address_is_tried_when_one_does_not_connect(receiver_factory,
                                                                    monkeypatch) -> None:
    receiver = receiver_factory([200])
    asked = _resolving_to(monkeypatch, "127.0.0.2", "127.0.0.1")  # nothing listens on .2
    url = f"http://hooks.example.com:{receiver.port}/hook"
    assert send_webhook(url, {"id": "j"}, "", sleep=lambda _: None, tries=1, allow_private=True)
    assert asked == ["hooks.example.com"] and len(receiver.calls) == 1


def test_a_failed_connection_names_the_addresses_tried(monkeypatch, caplog) -> None:
    _resolving_to(monkeypatch, "127.0.0.1")
    with caplog.at_level(logging.WARNING, logger="worker.webhook"):
        assert not send_webhook("http://hooks.example.com:1/x", {}, "", sleep=lambda _: None,
                                tries=1, allow_private=True)
    assert "could not connect to hooks.example.com (127.0.0.1:" in caplog.text


def _self_signed(tmp_path: Path, name: str) -> tuple[Path, Path]:
    """A certificate for ``name`` only (no IP in it) and its key, made with the openssl tool."""
    cert, key = tmp_path / f"{name}.pem", tmp_path / f"{name}.key"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt",
                    "ec_paramgen_curve:prime256v1", "-nodes", "-days", "1", "-subj",
                    f"/CN={name}", "-addext", f"subjectAltName=DNS:{name}", "-keyout", str(key),
                    "-out", str(cert)], check=True, capture_output=True)
    return cert, key


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_https_checks_the_certificate_and_sni_against_the_host_name(
        receiver_factory, monkeypatch, tmp_path, no_env_proxy, caplog) -> None:
    good_cert, good_key = _self_signed(tmp_path, "hooks.example.com")
    other_cert, other_key = _self_signed(tmp_path, "other.example.com")
    trusted = tmp_path / "trusted.pem"  # both certificates are trusted: only names differ
    trusted.write_bytes(good_cert.read_bytes() + other_cert.read_bytes())
    monkeypatch.setenv("SSL_CERT_FILE", str(trusted))
    good_tls = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    good_tls.load_cert_chain(good_cert, good_key)
    receiver = receiver_factory([200], good_tls)
    _resolving_to(monkeypatch, "127.0.0.1")
    url = f"https://hooks.example.com:{receiver.port}/hook"
    assert send_webhook(url, {"id": "j"}, "", sleep=lambda _: None, tries=1, timeout_s=5.0,
                        allow_private=True)
    assert receiver.server_names == ["hooks.example.com"] and len(receiver.calls) == 1
    assert receiver.calls[0][1]["Host"] == f"hooks.example.com:{receiver.port}"
    # A trusted certificate for another name is refused: the name checked is the URL's.
    other_tls = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    other_tls.load_cert_chain(other_cert, other_key)
    impostor = receiver_factory([200], other_tls)
    url = f"https://hooks.example.com:{impostor.port}/hook"
    with caplog.at_level(logging.WARNING, logger="worker.webhook"):
        assert not send_webhook(url, {"id": "j"}, "", sleep=lambda _: None, tries=1,
                                timeout_s=5.0, allow_private=True)
    assert impostor.calls == [] and "not valid for 'hooks.example.com'" in caplog.text

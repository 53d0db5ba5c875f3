"""Job-finished webhooks: a JSON body signed with HMAC-SHA256, retried with backoff.

A webhook is only sent when every address its host resolves to is public (unless
CADNERF_WEBHOOK_ALLOW_PRIVATE allows otherwise), and redirects are never followed: a job's URL
must not reach the service's own network (Redis, cloud metadata...).

The host is resolved once per attempt and the connection goes to one of the addresses that were
just checked (the URL's host is swapped for that IP; the ``Host`` header keeps the original
name, and for https the TLS server name and certificate check use the original name through
httpx's ``sni_hostname`` request extension). The HTTP client never resolves the name itself, so a
DNS server that answers a public address to the check and a private one to the connection
(DNS rebinding) gains nothing. Proxies from the environment (HTTP_PROXY...) are not used: they
would connect wherever their own resolver says.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import socket
import time
from collections.abc import Callable
from typing import Any

import httpx

from app.settings import non_public_reason

log = logging.getLogger(__name__)

SIGNATURE_HEADER = "X-CadNerf-Signature"


def sign(body: bytes, secret: str) -> str:
    """``sha256=<hex>`` HMAC of the body (what receivers recompute to trust a call).

    Args:
        body: the exact bytes sent.
        secret: the shared secret (CADNERF_WEBHOOK_SECRET).

    Returns:
        The header value.
    """
    return "sha256=" + hmac.new(secret.encode("utf-8"), body, hashlib.sha256).hexdigest()


def _resolve(host: str) -> list[str]:
    """Every address ``host`` resolves to, in the resolver's order, each once.

    Raises:
        OSError: the host name cannot be resolved (``socket.gaierror``).
    """
    addresses: list[str] = []
    for *_, sockaddr in socket.getaddrinfo(host, None, type=socket.SOCK_STREAM):
        address = str(sockaddr[0])
        if address not in addresses:
            addresses.append(address)
    return addresses


def _first_refusal(host: str, addresses: list[str]) -> str | None:
    """Why ``host`` must not be called given its ``addresses``; None when all are public."""
    for address in addresses:
        reason = non_public_reason(address)
        if reason:
            return (f"{host} is {reason}" if address == host
                    else f"{host} resolves to {address}, {reason}")
    return None


def refusal(url: str) -> str | None:
    """Why ``url`` must not be called: a host resolving to any non-public address.

    Args:
        url: the webhook URL.

    Returns:
        A reason naming the host and address; None when every resolved address is public.

    Raises:
        OSError: the host name cannot be resolved (``socket.gaierror``).
    """
    host = httpx.URL(url).raw_host.decode("ascii")  # IDNA-encoded, as the resolver wants it
    if not host:
        return "the URL has no host"
    return _first_refusal(host, _resolve(host))


def _post_pinned(client: httpx.Client, url: httpx.URL, addresses: list[str], body: bytes,
                 headers: dict[str, str]) -> httpx.Response:
    """POST to ``url`` connecting to ``addresses`` (in order) instead of resolving its host.

    The request URL carries the IP; the ``Host`` header and, for https, the TLS server name
    (SNI) and certificate check keep ``url``'s host. The next address is tried only when the
    connection could not be made (nothing was sent), as a socket connect does over a host's
    addresses.

    Raises:
        httpx.HTTPError: the request failed; ``httpx.ConnectError`` naming every address tried
            when none could be connected to.
    """
    host = url.raw_host.decode("ascii")
    pinned_headers = {**headers, "Host": url.netloc.decode("ascii")}
    failures: list[str] = []
    for address in addresses:
        try:
            return client.post(url.copy_with(host=address), content=body,
                               headers=pinned_headers, extensions={"sni_hostname": host})
        except (httpx.ConnectError, httpx.ConnectTimeout) as exc:
            failures.append(f"{address}: {str(exc) or type(exc).__name__}")
    raise httpx.ConnectError(f"could not connect to {host} ({'; '.join(failures)})"
                             if failures else f"{host} resolved to no address")


def send_webhook(url: str, payload: dict[str, Any], secret: str, *, allow_private: bool = False,
                 tries: int = 4, base_delay_s: float = 1.0, timeout_s: float = 5.0,
                 sleep: Callable[[float], None] = time.sleep) -> bool:
    """POST ``payload`` to ``url``; retry on errors and 5xx/429 with exponential backoff.

    The host is resolved once before each attempt; any non-public address stops the delivery
    (no retry) with a warning. The connection then goes to the addresses just resolved, never to
    a second resolution (no DNS rebinding), with the original ``Host`` header and, for https,
    the certificate verified against the original host name. Redirects are not followed (a 3xx
    counts as a refusal), and proxies from the environment are not used.

    Args:
        url: the job's webhook URL.
        payload: the JSON body (its "id" names the job in the log).
        secret: HMAC key; empty sends the body unsigned.
        allow_private: send to private, loopback and link-local addresses too
            (CADNERF_WEBHOOK_ALLOW_PRIVATE).
        tries: attempts in all (bounded).
        base_delay_s: delay before the second attempt; doubled each time.
        timeout_s: per-attempt timeout.
        sleep: waits between attempts.

    Returns:
        True once the receiver answered 2xx; False after the last failed attempt or a refusal.
    """
    body = json.dumps(payload, separators=(",", ":")).encode("utf-8")
    headers = {"Content-Type": "application/json", "User-Agent": "cadnerf-webhook/1"}
    if secret:
        headers[SIGNATURE_HEADER] = sign(body, secret)
    try:
        target = httpx.URL(url)
    except httpx.InvalidURL as exc:
        log.warning("webhook of job %s not sent: invalid URL (%s)", payload.get("id"), exc)
        return False
    if not target.raw_host:
        log.warning("webhook of job %s not sent: the URL has no host", payload.get("id"))
        return False
    for attempt in range(tries):
        outcome = _attempt(url, target, body, headers, allow_private, timeout_s,
                           payload.get("id"))
        if outcome is not None:
            return outcome
        if attempt + 1 < tries:
            sleep(base_delay_s * 2**attempt)
    return False


def _attempt(url: str, target: httpx.URL, body: bytes, headers: dict[str, str],
             allow_private: bool, timeout_s: float, job_id: Any) -> bool | None:
    """One delivery: True when done, False when refused (no retry), None to try again."""
    host = target.raw_host.decode("ascii")  # IDNA-encoded, as the resolver wants it
    try:
        addresses = _resolve(host)
        reason = None if allow_private else _first_refusal(host, addresses)
        if reason:
            log.warning("webhook of job %s not sent: %s (set CADNERF_WEBHOOK_ALLOW_PRIVATE="
                        "true to allow it on a closed network)", job_id, reason)
            return False
        # An explicit transport: no proxy from the environment (it would resolve the name
        # itself); SSL_CERT_FILE / SSL_CERT_DIR still apply to certificate verification.
        with httpx.Client(transport=httpx.HTTPTransport(), timeout=timeout_s,
                          follow_redirects=False) as client:
            response = _post_pinned(client, target, addresses, body, headers)
        if response.is_success:
            return True
        if response.is_redirect:  # its target was never checked: not followed
            log.warning("webhook %s redirects (%d); redirects are not followed",
                        url, response.status_code)
            return False
        if response.status_code < 500 and response.status_code != 429:
            log.warning("webhook %s refused with %d; not retried", url, response.status_code)
            return False
        log.warning("webhook %s answered %d", url, response.status_code)
    except (httpx.HTTPError, OSError) as exc:  # OSError: the name did not resolve
        log.warning("webhook %s failed: %s", url, exc)
    return None

"""Job-finished webhooks: a JSON body signed with HMAC-SHA256, retried with backoff.

A webhook is only sent when every address its host resolves to is public (unless
CADNERF_WEBHOOK_ALLOW_PRIVATE allows otherwise), and redirects are never followed: a job's URL
must not reach the service's own network (Redis, cloud metadata...).
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
    for *_, sockaddr in socket.getaddrinfo(host, None, type=socket.SOCK_STREAM):
        address = str(sockaddr[0])
        reason = non_public_reason(address)
        if reason:
            return (f"{host} is {reason}" if address == host
                    else f"{host} resolves to {address}, {reason}")
    return None


def send_webhook(url: str, payload: dict[str, Any], secret: str, *, allow_private: bool = False,
                 tries: int = 4, base_delay_s: float = 1.0, timeout_s: float = 5.0,
                 sleep: Callable[[float], None] = time.sleep) -> bool:
    """POST ``payload`` to ``url``; retry on errors and 5xx/429 with exponential backoff.

    The host is resolved before each attempt; any non-public address stops the delivery (no
    retry) with a warning. Redirects are not followed (a 3xx counts as a refusal).

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
    for attempt in range(tries):
        try:
            reason = None if allow_private else refusal(url)
            if reason:
                log.warning("webhook of job %s not sent: %s (set CADNERF_WEBHOOK_ALLOW_PRIVATE="
                            "true to allow it on a closed network)", payload.get("id"), reason)
                return False
            response = httpx.post(url, content=body, headers=headers, timeout=timeout_s,
                                  follow_redirects=False)
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
        if attempt + 1 < tries:
            sleep(base_delay_s * 2**attempt)
    return False

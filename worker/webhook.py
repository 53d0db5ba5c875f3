"""Job-finished webhooks: a JSON body signed with HMAC-SHA256, retried with backoff."""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import time
from collections.abc import Callable
from typing import Any

import httpx

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


def send_webhook(url: str, payload: dict[str, Any], secret: str, *, tries: int = 4,
                 base_delay_s: float = 1.0, timeout_s: float = 5.0,
                 sleep: Callable[[float], None] = time.sleep) -> bool:
    """POST ``payload`` to ``url``; retry on errors and 5xx/429 with exponential backoff.

    Args:
        url: the job's webhook URL.
        payload: the JSON body.
        secret: HMAC key; empty sends the body unsigned.
        tries: attempts in all (bounded).
        base_delay_s: delay before the second attempt; doubled each time.
        timeout_s: per-attempt timeout.
        sleep: waits between attempts.

    Returns:
        True once the receiver answered 2xx; False after the last failed attempt.
    """
    body = json.dumps(payload, separators=(",", ":")).encode("utf-8")
    headers = {"Content-Type": "application/json", "User-Agent": "cadnerf-webhook/1"}
    if secret:
        headers[SIGNATURE_HEADER] = sign(body, secret)
    for attempt in range(tries):
        try:
            response = httpx.post(url, content=body, headers=headers, timeout=timeout_s,
                                  follow_redirects=False)
            if response.is_success:
                return True
            if response.status_code < 500 and response.status_code != 429:
                log.warning("webhook %s refused with %d; not retried", url, response.status_code)
                return False
            log.warning("webhook %s answered %d", url, response.status_code)
        except httpx.HTTPError as exc:
            log.warning("webhook %s failed: %s", url, exc)
        if attempt + 1 < tries:
            sleep(base_delay_s * 2**attempt)
    return False

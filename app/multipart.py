"""Streaming multipart receiver: writes file parts to disk as they arrive, enforcing limits.

Starlette's form parser spools whole files before a route sees them; this one counts bytes per
file and per request while reading and stops at the first byte over a limit, so a client cannot
make the server store more than the limits allow (whatever its Content-Length says).

It also bounds time and concurrency, which uvicorn does not (it has no request-body timeout): an
upload that sends nothing for ``idle_s`` or is not complete after ``deadline_s`` gets 408, and
an upload arriving while ``max_concurrent`` others are being received gets 503 before its body
is read (see ``Pacing``).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from python_multipart.exceptions import FormParserError
from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.requests import ClientDisconnect, Request

from app.errors import ApiError
from app.settings import Settings

FILE_FIELDS = ("images", "masks")
TEXT_FIELDS = ("config", "webhook_url")
MAX_TEXT_BYTES = 64 * 1024
MAX_BOUNDARY_BYTES = 70  # RFC 2046
UPLOAD_RETRY_AFTER_S = 10


@dataclass(frozen=True)
class Limits:
    """Upload limits in bytes and counts."""

    max_file_bytes: int
    max_total_bytes: int
    max_files_per_field: int


@dataclass(frozen=True)
class Pacing:
    """Time limits of one upload, and how many uploads may be received at once.

    ``idle_s`` (default 30 s): a client that sends no byte for this long has stalled (a dead
    link, a suspended laptop, or a client holding the connection on purpose); 30 s outlasts a
    mobile hand-over or a brief dead spot, and frees the staging folder soon after.

    ``deadline_s`` (default 600 s): a fixed cap on the whole body rather than one derived from
    a minimum rate, so operators and clients can state it in one number. It stops a client that
    trickles a byte just often enough to dodge the idle limit. The default request limit
    (150 MiB) fits in it at about 256 KiB/s (2 Mbit/s); a typical job (10 phone photos,
    30-50 MB) needs only 50-90 KB/s. A larger ``CADNERF_MAX_TOTAL_MB`` may need a larger one.

    ``max_concurrent`` (default 8): uploads received at the same time. It bounds staging disk
    use (``max_concurrent`` x the request limit) and open files, and how many stalled clients
    can be waiting on their timeouts; one more is refused with 503 + Retry-After at once.
    """

    idle_s: float = 30.0
    deadline_s: float = 600.0
    max_concurrent: int = 8

    @classmethod
    def from_settings(cls, settings: Settings) -> Pacing:
        """From ``CADNERF_UPLOAD_IDLE_TIMEOUT_S``, ``_DEADLINE_S``, ``_MAX_CONCURRENT_UPLOADS``."""
        return cls(settings.upload_idle_timeout_s, settings.upload_deadline_s,
                   settings.max_concurrent_uploads)


class UploadSlots:
    """Counts the uploads being received; refuses one over the limit instead of queueing it.

    A plain counter rather than an ``asyncio.Semaphore``: nothing waits for a slot, and all
    callers run on the event loop's thread, so check-and-increment cannot interleave.
    """

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.active = 0

    @contextlib.contextmanager
    def hold(self) -> Iterator[None]:
        """Hold one slot for the duration of the ``with`` block.

        Raises:
            ApiError: 503 ``too_many_uploads`` (with Retry-After) when all slots are taken.
        """
        if self.active >= self.limit:
            raise ApiError(503, "too_many_uploads",
                           f"{self.limit} uploads are already being received",
                           hint=f"try again in {UPLOAD_RETRY_AFTER_S} seconds",
                           headers={"Retry-After": str(UPLOAD_RETRY_AFTER_S)})
        self.active += 1
        try:
            yield
        finally:
            self.active -= 1


def upload_slots(request: Request, limit: int) -> UploadSlots:
    """The app's ``UploadSlots`` (``app.state.upload_slots``), made on first use."""
    state = request.app.state
    slots = getattr(state, "upload_slots", None)
    if not isinstance(slots, UploadSlots):
        slots = state.upload_slots = UploadSlots(limit)
    return slots


def _pacing_of(request: Request) -> Pacing:
    settings = getattr(request.app.state, "settings", None)
    return Pacing.from_settings(settings) if isinstance(settings, Settings) else Pacing()


@dataclass
class StoredPart:
    """One file part written to disk."""

    field: str
    filename: str
    path: Path
    size: int = 0


@dataclass
class ReceivedForm:
    """What a multipart request carried: files (on disk, in order) and text fields."""

    files: dict[str, list[StoredPart]] = field(default_factory=lambda: {f: [] for f in FILE_FIELDS})
    texts: dict[str, str] = field(default_factory=dict)


def display_name(filename: str, index: int, what: str = "photo") -> str:
    """A client's file name made safe to echo back (no control characters, bounded length)."""
    base = filename.replace("\\", "/").rsplit("/", 1)[-1]
    clean = "".join(ch for ch in base if ch.isprintable())[:100]
    return clean or f"{what} {index + 1}"


class _Receiver:
    """python-multipart callbacks that stream file parts into ``folder``."""

    def __init__(self, folder: Path, limits: Limits) -> None:
        self.folder = folder
        self.limits = limits
        self.form = ReceivedForm()
        self.total = 0
        self._header_name = b""
        self._header_value = b""
        self._disposition = b""
        self._part: StoredPart | None = None
        self._text_name: str | None = None
        self._text = bytearray()
        self._handle: BinaryIO | None = None

    def on_part_begin(self) -> None:
        self._disposition = b""
        self._part, self._text_name, self._text = None, None, bytearray()

    def on_header_field(self, data: bytes, start: int, end: int) -> None:
        self._header_name += data[start:end]

    def on_header_value(self, data: bytes, start: int, end: int) -> None:
        self._header_value += data[start:end]

    def on_header_end(self) -> None:
        if self._header_name.lower() == b"content-disposition":
            self._disposition = self._header_value
        self._header_name, self._header_value = b"", b""

    def on_headers_finished(self) -> None:
        _, options = parse_options_header(self._disposition)
        name = options.get(b"name", b"").decode("utf-8", "replace")
        filename = options.get(b"filename")
        if name in FILE_FIELDS and filename is not None:
            self._begin_file(name, filename.decode("utf-8", "replace"))
        elif name in TEXT_FIELDS and filename is None:
            self._text_name = name
        elif name in FILE_FIELDS or name in TEXT_FIELDS:
            kind = "a file" if name in FILE_FIELDS else "a text field"
            raise ApiError(422, "wrong_field_type", f"`{name}` must be {kind}", field=name,
                           hint="see the API description at /docs")
        else:
            raise ApiError(422, "unknown_field", f"unknown form field `{name[:50]}`",
                           field=name[:50], hint="send only images, masks, config and webhook_url")

    def _begin_file(self, name: str, filename: str) -> None:
        parts = self.form.files[name]
        if len(parts) >= self.limits.max_files_per_field:
            raise ApiError(422, "too_many_files",
                           f"more than {self.limits.max_files_per_field} files in `{name}`",
                           field=name, hint=f"send at most {self.limits.max_files_per_field}")
        index = len(parts)
        path = self.folder / f"{name}-{index:03d}.part"
        self._part = StoredPart(name, display_name(filename, index, name[:-1]), path)
        parts.append(self._part)
        self._handle = path.open("wb")

    def on_part_data(self, data: bytes, start: int, end: int) -> None:
        size = end - start
        self.total += size
        if self.total > self.limits.max_total_bytes:
            mib = self.limits.max_total_bytes / 2**20
            raise ApiError(413, "request_too_large", f"the upload exceeds {mib:.0f} MiB in total",
                           hint="send smaller (downscaled or recompressed) photos")
        if self._part is not None and self._handle is not None:
            self._part.size += size
            if self._part.size > self.limits.max_file_bytes:
                mib = self.limits.max_file_bytes / 2**20
                raise ApiError(413, "file_too_large", f"this file exceeds {mib:.0f} MiB",
                               photo=self._part.filename, field=self._part.field,
                               hint="downscale or recompress it (a few megapixels is plenty)")
            self._handle.write(data[start:end])
        elif self._text_name is not None:
            self._text += data[start:end]
            if len(self._text) > MAX_TEXT_BYTES:
                raise ApiError(413, "field_too_large", f"`{self._text_name}` exceeds 64 KiB",
                               field=self._text_name, hint="send a shorter value")

    def on_part_end(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None
        if self._text_name is not None:
            if self._text_name in self.form.texts:
                raise ApiError(422, "duplicate_field", f"`{self._text_name}` was sent twice",
                               field=self._text_name, hint="send it once")
            self.form.texts[self._text_name] = self._text.decode("utf-8", "replace")

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()


def _boundary(request: Request) -> bytes:
    content_type = request.headers.get("content-type", "")
    kind, params = parse_options_header(content_type)
    boundary = params.get(b"boundary")
    if kind != b"multipart/form-data" or not boundary:
        raise ApiError(415, "unsupported_media_type", "the request must be multipart/form-data",
                       hint="post the photos as form fields `images` (and optional `masks`)")
    if len(boundary) > MAX_BOUNDARY_BYTES:
        raise ApiError(400, "malformed_multipart",
                       f"the multipart boundary is {len(boundary)} bytes; at most "
                       f"{MAX_BOUNDARY_BYTES} are allowed (RFC 2046)",
                       hint="let your HTTP client build the multipart body")
    return boundary


def _check_declared_length(request: Request, limits: Limits) -> None:
    declared = request.headers.get("content-length", "")
    slack = 1 << 20  # multipart headers and text fields on top of the file bytes
    if declared.isdigit() and int(declared) > limits.max_total_bytes + slack:
        mib = limits.max_total_bytes / 2**20
        raise ApiError(413, "request_too_large", f"the upload exceeds {mib:.0f} MiB in total",
                       hint="send smaller (downscaled or recompressed) photos")


async def receive_form(request: Request, folder: Path, limits: Limits,
                       pacing: Pacing | None = None) -> ReceivedForm:
    """Stream a multipart request body into ``folder``, enforcing the limits while reading.

    Args:
        request: the incoming request (its body is consumed).
        folder: an existing, empty staging folder the file parts are written to.
        limits: byte and count limits.
        pacing: time limits and the concurrency cap (default: from ``app.state.settings``).

    Returns:
        The received files (in order, per field) and text fields.

    Raises:
        ApiError: 413 on a limit, 415 when not multipart, 400 on a malformed body, 408 when the
            client stalls or is too slow, 503 when too many uploads are being received. The
            open file is closed; the caller removes ``folder`` (as for every failure).
    """
    pacing = pacing or _pacing_of(request)
    boundary = _boundary(request)
    _check_declared_length(request, limits)
    with upload_slots(request, pacing.max_concurrent).hold():
        receiver = _Receiver(folder, limits)
        callbacks = {name: getattr(receiver, name) for name in (
            "on_part_begin", "on_part_data", "on_part_end", "on_header_field", "on_header_value",
            "on_header_end", "on_headers_finished")}
        try:
            parser = MultipartParser(boundary, callbacks)  # type: ignore[arg-type]
            await _feed(request, parser, pacing)
            parser.finalize()
        except (FormParserError, ValueError) as exc:
            raise ApiError(400, "malformed_multipart", "the multipart body could not be parsed",
                           hint="let your HTTP client build the multipart body") from exc
        except ClientDisconnect as exc:
            raise ApiError(400, "client_disconnected", "the upload was interrupted",
                           hint="send it again") from exc
        finally:
            receiver.close()
    return receiver.form


async def _feed(request: Request, parser: MultipartParser, pacing: Pacing) -> None:
    """Write the body into ``parser`` chunk by chunk, within the idle limit and the deadline.

    Raises:
        ApiError: 408 ``upload_stalled`` when no byte arrived for ``pacing.idle_s``, 408
            ``upload_too_slow`` when the body is not complete after ``pacing.deadline_s``. Both
            ask the server to close the connection (the rest of the body is not wanted).
    """
    loop = asyncio.get_running_loop()
    deadline_at = loop.time() + pacing.deadline_s
    window_end = deadline_at
    try:
        async with contextlib.aclosing(request.stream()) as chunks, \
                asyncio.timeout(None) as window:
            while True:
                window_end = min(loop.time() + pacing.idle_s, deadline_at)
                window.reschedule(window_end)
                chunk = await anext(chunks, None)
                if chunk is None:
                    return
                parser.write(chunk)
    except TimeoutError:
        close = {"Connection": "close"}
        if window_end >= deadline_at:
            raise ApiError(408, "upload_too_slow",
                           f"the upload was not complete after {pacing.deadline_s:g} seconds",
                           hint="send smaller (downscaled) photos, or use a faster connection",
                           headers=close) from None
        raise ApiError(408, "upload_stalled",
                       f"no data arrived for {pacing.idle_s:g} seconds; the upload was dropped",
                       hint="check your connection and send the photos again",
                       headers=close) from None

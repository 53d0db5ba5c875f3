"""Streaming multipart receiver: writes file parts to disk as they arrive, enforcing limits.

Starlette's form parser spools whole files before a route sees them; this one counts bytes per
file and per request while reading and stops at the first byte over a limit, so a client cannot
make the server store more than the limits allow (whatever its Content-Length says).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from python_multipart.exceptions import FormParserError
from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.requests import ClientDisconnect, Request

from app.errors import ApiError

FILE_FIELDS = ("images", "masks")
TEXT_FIELDS = ("config", "webhook_url")
MAX_TEXT_BYTES = 64 * 1024
MAX_BOUNDARY_BYTES = 70  # RFC 2046


@dataclass(frozen=True)
class Limits:
    """Upload limits in bytes and counts."""

    max_file_bytes: int
    max_total_bytes: int
    max_files_per_field: int


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


async def receive_form(request: Request, folder: Path, limits: Limits) -> ReceivedForm:
    """Stream a multipart request body into ``folder``, enforcing the limits while reading.

    Args:
        request: the incoming request (its body is consumed).
        folder: an existing, empty staging folder the file parts are written to.
        limits: byte and count limits.

    Returns:
        The received files (in order, per field) and text fields.

    Raises:
        ApiError: 413 on a limit, 415 when not multipart, 400 on a malformed body.
    """
    boundary = _boundary(request)
    _check_declared_length(request, limits)
    receiver = _Receiver(folder, limits)
    callbacks = {name: getattr(receiver, name) for name in (
        "on_part_begin", "on_part_data", "on_part_end", "on_header_field", "on_header_value",
        "on_header_end", "on_headers_finished")}
    try:
        parser = MultipartParser(boundary, callbacks)  # type: ignore[arg-type]
        async for chunk in request.stream():
            parser.write(chunk)
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

"""Validation of a job upload and the job folder it becomes.

Photos are checked by content (magic bytes): JPEG, PNG, WebP, HEIC/HEIF (pillow-heif) and AVIF
where Pillow reads it. Dimensions are read from the header without decoding (decompression bombs
are refused before any pixel is decoded), masks must match their photos,
and the config is resolved once with the core's torch-free ``resolve_config``. The files are
laid out by the core's ``JobFolder`` (stored names ``NNN_<sanitised>.<ext>``; each mask under
its photo's name): the client's name never becomes a path.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pillow_heif
from PIL import Image, features
from pydantic import AnyHttpUrl, TypeAdapter, ValidationError

from app.core import (
    COVER_SIDE,
    JobFolder,
    PipelineConfig,
    cover_problem,
    field_bounds,
    mask_cover,
    refused_names,
    resolve_config,
    shape_problem,
)
from app.errors import ApiError
from app.multipart import ReceivedForm, StoredPart
from app.schemas import JobCreate
from app.settings import Settings, non_public_reason

_EXIF_ORIENTATION = 0x0112
_PIL_FORMATS = {"jpg": "JPEG", "png": "PNG", "webp": "WEBP", "heic": "HEIF", "heif": "HEIF",
                "avif": "AVIF"}
PHOTO_TYPES = frozenset({"jpg", "png", "webp", "heic", "heif"}
                        | ({"avif"} if features.check("avif") else set()))
"""Photo types accepted (AVIF where this Pillow was built to read it)."""
MASK_TYPES = frozenset({"jpg", "png", "webp"})
"""Mask types accepted: a mask is drawn and saved by a tool, never a phone's camera."""
_TYPE_NAMES = {"jpg": "JPEG", "png": "PNG", "webp": "WebP", "heic": "HEIC", "avif": "AVIF"}
# ISO base media file brands (ftyp box): HEVC still images, the generic HEIF brand, AV1 images.
_HEIC_BRANDS = frozenset({b"heic", b"heix", b"heim", b"heis"})
_HEIF_BRANDS = frozenset({b"mif1"})
_AVIF_BRANDS = frozenset({b"avif"})
_URL = TypeAdapter(AnyHttpUrl)

# Thumbnails and depth maps are never used: skip reading them.
pillow_heif.register_heif_opener(thumbnails=False, depth_images=False)


@dataclass(frozen=True)
class ImageInfo:
    """What the header of an image says."""

    ext: str
    width: int
    height: int
    oriented: tuple[int, int]  # (width, height) after the EXIF rotation


@dataclass(frozen=True)
class JobSpec:
    """A validated upload, laid out in its staging folder."""

    names: list[str]
    config: PipelineConfig
    webhook_url: str | None

    @property
    def preset(self) -> str:
        """The preset the config was resolved from."""
        return self.config.preset


def sniff_type(head: bytes) -> str | None:
    """The image type from the first bytes (32 or more) of a file: "jpg", "png", "webp",
    "heic", "heif", "avif" or None."""
    if head.startswith(b"\xff\xd8\xff"):
        return "jpg"
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if len(head) >= 12 and head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "webp"
    if len(head) >= 12 and head[4:8] == b"ftyp":
        return _sniff_heif(head)
    return None


def _sniff_heif(head: bytes) -> str | None:
    """The type of an ISO media file from its ftyp box: the major brand, else (for the generic
    ``mif1``) the compatible brands that name the codec."""
    box_end = min(len(head), int.from_bytes(head[:4], "big"))
    brands = [head[8:12]] + [head[i:i + 4] for i in range(16, box_end - 3, 4)]
    for brand in brands:
        if brand in _HEIC_BRANDS:
            return "heic"
        if brand in _AVIF_BRANDS:
            return "avif"
    return "heif" if brands[0] in _HEIF_BRANDS else None


def inspect_image(part: StoredPart, settings: Settings,
                  types: frozenset[str] = PHOTO_TYPES) -> ImageInfo:
    """Check one uploaded image by content and header.

    Args:
        part: the file on disk.
        settings: size limits.
        types: the accepted types (``PHOTO_TYPES`` or ``MASK_TYPES``).

    Returns:
        Its type and size.

    Raises:
        ApiError: 415 for a type not in ``types``, 422 for an unreadable, too small or too
            large (megapixels) image.
    """
    with part.path.open("rb") as handle:
        ext = sniff_type(handle.read(64))
    if ext not in types:
        names = _type_names(types)
        raise ApiError(415, "unsupported_image_type", f"not a {names} image",
                       photo=part.filename, field=part.field,
                       hint=f"save it as {names} (the type is read from the content)")
    width, height, orientation = _read_header(part, ext)
    megapixels = width * height / 1e6
    if megapixels > settings.max_megapixels:
        raise ApiError(422, "image_too_large",
                       f"{width}x{height} is {megapixels:.1f} megapixels; the limit is "
                       f"{settings.max_megapixels:g}", photo=part.filename, field=part.field,
                       hint="downscale it (a few megapixels is plenty)")
    _decode_fully(part, ext)  # bounded now that the pixel count is known
    if min(width, height) < settings.min_side_px:
        raise ApiError(422, "image_too_small",
                       f"{width}x{height} pixels; each side needs {settings.min_side_px} or more",
                       photo=part.filename, field=part.field, hint="use a larger photo")
    problem = shape_problem(width, height) if types is PHOTO_TYPES else None
    if problem is not None:  # the core's own rule (a strip fails background removal)
        raise ApiError(422, "image_shape", problem[0], photo=part.filename, field=part.field,
                       hint=problem[1])
    oriented = (height, width) if orientation in (5, 6, 7, 8) else (width, height)
    return ImageInfo(ext, width, height, oriented)


def _read_header(part: StoredPart, ext: str) -> tuple[int, int, int]:
    unreadable = ApiError(422, "unreadable_image", "the image header cannot be read",
                          photo=part.filename, field=part.field,
                          hint="the file may be truncated or damaged; export it again")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(part.path) as image:  # lazy: reads the header only
                if image.format != _PIL_FORMATS[ext]:
                    raise unreadable
                width, height, orientation = _stored_size(image)
    except Image.DecompressionBombError:
        raise ApiError(422, "image_too_large", "the image has far too many pixels",
                       photo=part.filename, field=part.field, hint="downscale it") from None
    except ApiError:
        raise
    except Exception:  # Pillow raises many types on damaged headers
        raise unreadable from None
    return width, height, orientation


def _stored_size(image: Image.Image) -> tuple[int, int, int]:
    """Width and height of the stored pixels and the EXIF orientation of an opened image."""
    width, height = image.size
    if image.format == "HEIF":
        # pillow-heif gives the upright size and resets the tag to 1 (it rotates on decode):
        # undo both, so a HEIC is checked (masks included) exactly as a JPEG.
        orientation = int(image.info.get("original_orientation") or 1)
        return (height, width, orientation) if orientation in (5, 6, 7, 8) else \
            (width, height, orientation)
    if image.format == "PNG":
        # PNG's getexif() decodes the whole image to find a trailing eXIf chunk: only JPEG,
        # WebP and AVIF carry the orientation in the header already read.
        return width, height, 1
    return width, height, int(image.getexif().get(_EXIF_ORIENTATION, 1) or 1)


def _decode_fully(part: StoredPart, ext: str) -> None:
    """Decode the whole image once, so a file cut off after its header is refused here.

    Call only after the megapixel check. JPEGs are decoded at 1/8 scale (every byte of the scan
    data is still read, which is what finds a truncated file).

    Raises:
        ApiError: 422 ``unreadable_image`` naming the photo when the data cannot be decoded.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(part.path) as image:
                if ext == "jpg":
                    image.draft("RGB", (max(1, image.width // 8), max(1, image.height // 8)))
                image.load()
    except Exception:  # Pillow raises OSError, SyntaxError, ValueError... on bad data
        raise ApiError(422, "unreadable_image", "the image data is truncated or damaged",
                       photo=part.filename, field=part.field,
                       hint="the file is truncated or damaged; export it again") from None


def _type_names(types: frozenset[str]) -> str:
    """"JPEG, PNG or WebP"-style list of accepted types (HEIF is said as HEIC)."""
    names = [name for ext, name in _TYPE_NAMES.items() if ext in types]
    return ", ".join(names[:-1]) + " or " + names[-1]


def check_counts(form: ReceivedForm, settings: Settings) -> None:
    """The number of photos and masks."""
    images, masks = form.files["images"], form.files["masks"]
    lo, hi = settings.min_photos, settings.max_photos
    if not lo <= len(images) <= hi:
        raise ApiError(422, "photo_count", f"{len(images)} photos sent; {lo} to {hi} are needed",
                       field="images", hint=f"upload {lo} to {hi} photos taken walking around "
                       "the object, in walking order")
    if masks and len(masks) != len(images):
        raise ApiError(422, "mask_count", f"{len(masks)} masks for {len(images)} photos",
                       field="masks", hint="send one mask per photo in the same order, or none")


def check_mask(mask: StoredPart, photo: StoredPart, photo_info: ImageInfo,
               settings: Settings) -> ImageInfo:
    """A mask must be an image the size of its photo (stored or EXIF-rotated)."""
    info = inspect_image(mask, settings, MASK_TYPES)
    sizes = {(photo_info.width, photo_info.height), photo_info.oriented}
    if (info.width, info.height) not in sizes:
        raise ApiError(422, "mask_size", f"the mask is {info.width}x{info.height} pixels but "
                       f"the photo is {photo_info.oriented[0]}x{photo_info.oriented[1]}",
                       photo=photo.filename, field="masks",
                       hint="give each mask the size of its photo, in the same order")
    problem = cover_problem(_mask_cover(mask))
    if problem is not None:
        raise ApiError(422, "mask_unusable", problem[0], photo=photo.filename, field="masks",
                       hint=problem[1])
    return info


def _mask_cover(part: StoredPart) -> float:
    """The fraction of its photo an uploaded mask marks as object (size already checked, so
    decoding is bounded; a JPEG is decoded at a reduced scale)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(part.path) as image:
                image.draft(None, (COVER_SIDE, COVER_SIDE))  # type: ignore[arg-type]
                return mask_cover(image)
    except Exception:  # a damaged body behind a good header; Pillow raises many types
        raise ApiError(422, "unreadable_image", "the mask cannot be decoded", photo=part.filename,
                       field="masks", hint="export the mask again as PNG") from None


UNKNOWN_SETTING = ("not a setting a client may send (the settings: `overrides` in GET /docs, "
                   "or `cadnerf config --schema`)")


def parse_config(raw: str | None, preset_default: Callable[[], str]) -> PipelineConfig:
    """Resolve the `config` JSON field (preset and overrides) into the job's one config.

    Args:
        raw: the field's JSON text (absent: the default preset, no overrides).
        preset_default: gives the preset of a config that names none (asked only then: it may
            read the workers' device from Redis).

    Returns:
        The resolved configuration, written to the job folder as it is.
    """
    try:
        create = JobCreate.model_validate_json(raw or "{}")
    except ValidationError as exc:
        raise _config_error(exc) from None
    preset = create.preset or preset_default()
    try:
        return resolve_config(preset, create.overrides)
    except ValidationError as exc:
        raise _config_error(exc) from None
    except (ValueError, TypeError) as exc:
        raise ApiError(422, "invalid_config", str(exc)[:300], field="config",
                       hint='send JSON like {"preset": "preview", "overrides": {}}') from None


def _config_error(exc: ValidationError, most: int = 4) -> ApiError:
    """422 ``invalid_config`` naming each wrong field (up to ``most``) and its allowed range."""
    errors = exc.errors()
    if errors and errors[0].get("type") == "json_invalid":
        message = "`config` is not valid JSON"
    else:
        message = "; ".join(_error_text(err)[:300] for err in errors[:most])
        if len(errors) > most:
            message += f"; and {len(errors) - most} more"
    return ApiError(422, "invalid_config", message[:1200], field="config",
                    hint='send JSON like {"preset": "preview", "overrides": {"phase2.steps": 300}}')


def _error_text(err: Any) -> str:
    """One validation error: the field, pydantic's message, and the field's allowed range (a
    setting is named by its path in ``overrides``)."""
    loc = tuple(err.get("loc", ()))
    if loc[:1] == ("overrides",) and len(loc) > 1:
        loc = loc[1:]
    where = ".".join(str(p) for p in loc)
    text = str(err.get("msg")).removeprefix("Value error, ")
    if err.get("type") == "extra_forbidden":
        where, text = refused_names(loc, err.get("input")), UNKNOWN_SETTING
    message = f"{where}: {text}" if where else text
    bounds = field_bounds(loc)
    if bounds:  # name the bound whatever pydantic's wording (a huge number fails to parse)
        message = f"{message} (allowed: {bounds})"
    return message


def parse_webhook(raw: str | None, allow_private: bool = False) -> str | None:
    """An http(s) URL or None; a host that is plainly not public is refused (SSRF).

    Only IP literals and ``localhost`` names are judged here; the worker checks what a host name
    resolves to just before it sends.

    Args:
        raw: the `webhook_url` form field.
        allow_private: accept private, loopback and link-local hosts
            (``CADNERF_WEBHOOK_ALLOW_PRIVATE``).

    Returns:
        The normalised URL, or None when the field is empty.

    Raises:
        ApiError: 422 ``invalid_webhook_url`` for a URL that is not http(s),
            422 ``webhook_url_not_public`` for a loopback, private, link-local... host.
    """
    if not raw:
        return None
    try:
        url = _URL.validate_python(raw.strip())
    except ValidationError:
        raise ApiError(422, "invalid_webhook_url", "`webhook_url` is not an http(s) URL",
                       field="webhook_url", hint="send a full URL like https://host/path") from None
    host = (url.host or "").strip("[]").lower()
    reason = None if allow_private else _host_refusal(host)
    if reason:
        raise ApiError(422, "webhook_url_not_public",
                       f"`webhook_url` host {host} is {reason}; the service does not call "
                       "internal addresses", field="webhook_url",
                       hint="use a host reachable from the internet (an operator can allow "
                       "private addresses with CADNERF_WEBHOOK_ALLOW_PRIVATE=true)")
    return str(url)[:2048]


def _host_refusal(host: str) -> str | None:
    """Why a URL host (without brackets) is not public; None for public IPs and other names."""
    name = host.rstrip(".")
    if name == "localhost" or name.endswith(".localhost"):  # RFC 6761: always loopback
        return "a loopback name"
    try:
        return non_public_reason(host)
    except ValueError:  # a host name: resolved and checked by the worker at delivery
        return None


def lay_out(form: ReceivedForm, staging: Path, settings: Settings,
            preset_default: Callable[[], str]) -> JobSpec:
    """Validate a received form and move its files into the job-folder layout in ``staging``.

    Args:
        form: the streamed parts (in ``staging``).
        staging: the staging folder that becomes the job folder.
        settings: limits.
        preset_default: gives the preset of a job whose config names none.

    Returns:
        The job's names, resolved config and webhook URL; ``staging`` now holds the photos,
        their masks (each stored under its photo's name) and the resolved config.
    """
    check_counts(form, settings)
    config = parse_config(form.texts.get("config"), preset_default)
    webhook = parse_webhook(form.texts.get("webhook_url"), settings.webhook_allow_private)
    images, masks = form.files["images"], form.files["masks"]
    infos = [inspect_image(part, settings) for part in images]
    for mask, photo, info in zip(masks, images, infos, strict=False):
        check_mask(mask, photo, info, settings)
    folder = JobFolder(staging)
    stored = [folder.add_photo(index, part.path, part.filename, info.ext, move=True)
              for index, (part, info) in enumerate(zip(images, infos, strict=True))]
    for mask_part, stored_photo in zip(masks, stored, strict=False):
        _store_mask(folder, mask_part, stored_photo)
    folder.write_config(config)
    return JobSpec([p.filename for p in images], config, webhook)


def _store_mask(folder: JobFolder, part: StoredPart, photo: Path) -> None:
    """Store an uploaded mask under its photo's name (size already checked: decoding is bounded)."""
    try:
        folder.add_mask(photo, part.path, move=True)
    except Exception:  # a damaged body behind a good header; Pillow raises many types
        raise ApiError(422, "unreadable_image", "the mask cannot be decoded", photo=part.filename,
                       field="masks", hint="export the mask again as PNG") from None

"""Photo intake: read photos and optional masks, with clear errors naming the photo.

Photos are JPEG, PNG, WebP, HEIC/HEIF (a phone's own format, through pillow-heif) or AVIF (where
Pillow was built to read it). The orientation is applied once, so a photo comes out the way a
viewer shows it: Pillow leaves it to the EXIF tag, pillow-heif applies the HEIF container's
rotation on decode and resets the tag. A photo with real transparency (an alpha channel not fully
opaque) gives its mask (alpha > one half) and is composited on white. The size is checked from
the header before any pixel is decoded, so a huge photo costs nothing to refuse, and a photo is
worked on at most ``limits.WORKING_PIXELS`` (a JPEG decoded at a reduced scale), so a 40 MP photo
costs what a 12 MP one does. The EXIF focal length is kept as its 35 mm equivalent (a phone's
own tag, or a camera's focal length over its sensor size): it tells the camera's field of view,
which the silhouettes alone cannot.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pillow_heif
from PIL import Image, ImageOps, UnidentifiedImageError, features

from cadnerf_core.errors import InputError
from cadnerf_core.intake.crop import DEFAULT_MARGIN, CropBox, apply_crop, canonical_box
from cadnerf_core.intake.limits import (
    MAX_PIXELS,
    has_transparency,
    mask_array,
    shape_problem,
    working_size,
)

# MPO: phone JPEGs with a depth map; HEIF: HEIC and HEIF; AVIF only where Pillow reads it.
PHOTO_FORMATS = frozenset({"JPEG", "MPO", "PNG", "WEBP", "HEIF"}
                          | ({"AVIF"} if features.check("avif") else set()))
_FORMATS_HINT = ("use JPEG, PNG, WebP or HEIC" + (" or AVIF" if "AVIF" in PHOTO_FORMATS else ""))

# Thumbnails and depth maps are never used: skip reading them.
pillow_heif.register_heif_opener(thumbnails=False, depth_images=False)

# A photo given as a path, raw bytes, or (name, bytes).
PhotoSource = str | Path | bytes | tuple[str, bytes]


@dataclass
class Photo:
    """One input photo, at its working size (``limits.working_size``).

    ``rgb``: [H, W, 3] float32 in [0, 1]; ``mask``: [H, W] bool from the photo's alpha or the
    user's mask, ``None`` when the photo brings none (background removal then makes one).
    """

    name: str
    rgb: np.ndarray
    mask: np.ndarray | None = None
    focal_35mm: float | None = None
    """The EXIF focal length in 35 mm film terms (``FocalLengthIn35mmFilm``), None if absent."""
    mask_source: Literal["uploaded", "alpha"] | None = None
    """Where ``mask`` came from: a mask the user gave, or the photo's own alpha."""
    uploaded_size: tuple[int, int] | None = None
    """(width, height) of the photo as uploaded, upright; None: the size of ``rgb``. Photos
    over ``limits.WORKING_PIXELS`` are worked on scaled down; exports scale back to this."""

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the photo as uploaded (upright)."""
        return self.uploaded_size or (self.rgb.shape[1], self.rgb.shape[0])

    @property
    def scale(self) -> float:
        """Pixels of the photo as uploaded per pixel of ``rgb`` (1 at or under working size)."""
        return self.size[0] / self.rgb.shape[1]

    @property
    def focal_pixels(self) -> float | None:
        """Focal length in this photo's pixels from ``focal_35mm`` (35 mm equivalent focal
        lengths are defined on the 43.27 mm diagonal of a 36 x 24 mm frame), None without it."""
        if self.focal_35mm is None:
            return None
        height, width = self.rgb.shape[:2]
        return self.focal_35mm * math.hypot(width, height) / FULL_FRAME_DIAGONAL_MM


def with_focal(photos: Sequence[Photo], focal_35mm: float | None) -> list[Photo]:
    """The photos, those without an EXIF focal length given ``focal_35mm`` (35 mm equivalent;
    None: unchanged). A photo's own EXIF value wins."""
    if focal_35mm is None:
        return list(photos)
    return [p if p.focal_35mm is not None else replace(p, focal_35mm=focal_35mm)
            for p in photos]


def _read_source(source: PhotoSource, index: int) -> tuple[str, bytes]:
    """Name and raw bytes of a source; InputError if a path cannot be read."""
    if isinstance(source, tuple):
        return source[0], source[1]
    if isinstance(source, bytes):
        return f"photo {index + 1}", source
    path = Path(source)
    try:
        return path.name, path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror or exc})", item=path.name,
                         hint="check the path") from exc


def _open_image(name: str, data: bytes, what: str, formats: frozenset[str] | None) -> Image.Image:
    """Open (lazily: header only) and check size limits. InputError names ``name``."""
    if not data:
        raise InputError(f"the {what} file is empty (0 bytes)", item=name,
                         hint="upload the file again")
    try:
        image = Image.open(io.BytesIO(data))
    except Image.DecompressionBombError as exc:
        raise InputError(f"the {what} is far over {MAX_PIXELS // 1_000_000} megapixels",
                         item=name, hint="downscale it before uploading") from exc
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        raise InputError(f"the {what} is not an image that can be read", item=name,
                         hint=_FORMATS_HINT) from exc
    if formats is not None and image.format not in formats:
        raise InputError(f"the {what} is in {image.format} format", item=name,
                         hint=_FORMATS_HINT)
    width, height = image.size
    if width * height > MAX_PIXELS:
        raise InputError(f"the {what} is {width}x{height} pixels, over "
                         f"{MAX_PIXELS // 1_000_000} megapixels", item=name,
                         hint="downscale it before uploading")
    problem = shape_problem(width, height)
    if problem is not None:
        message, hint = problem
        raise InputError(message.replace("the photo", f"the {what}", 1), item=name, hint=hint)
    return image


# EXIF orientation tag value -> the transpose that shows the image upright.
_ORIENTATION = {2: Image.Transpose.FLIP_LEFT_RIGHT, 3: Image.Transpose.ROTATE_180,
                4: Image.Transpose.FLIP_TOP_BOTTOM, 5: Image.Transpose.TRANSPOSE,
                6: Image.Transpose.ROTATE_270, 7: Image.Transpose.TRANSVERSE,
                8: Image.Transpose.ROTATE_90}
_EXIF_ORIENTATION_TAG = 0x0112
_EXIF_IFD = 0x8769
_EXIF_FOCAL_35MM_TAG = 0xA405  # FocalLengthIn35mmFilm
_EXIF_FOCAL_TAG = 0x920A  # FocalLength, mm
_EXIF_PIXEL_X, _EXIF_PIXEL_Y = 0xA002, 0xA003  # PixelXDimension, PixelYDimension
_EXIF_PLANE_X, _EXIF_PLANE_Y, _EXIF_PLANE_UNIT = 0xA20E, 0xA20F, 0xA210  # FocalPlane*Resolution
_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # inch, cm, and EXIF 2.3's mm, um
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
FOCAL_35MM_RANGE = (8.0, 1200.0)  # mm: outside it the tag is taken to be wrong


def exif_focal_35mm(image: Image.Image) -> float | None:
    """The photo's focal length in 35 mm film terms, None when unknown.

    ``FocalLengthIn35mmFilm`` where present and not zero (unknown, in the EXIF standard), as
    phones write it; else, as cameras write it, ``FocalLength`` in mm over the sensor's
    diagonal, the sensor's size being the pixel dimensions over ``FocalPlaneX/YResolution``
    (pixels per ``FocalPlaneResolutionUnit``). None outside ``FOCAL_35MM_RANGE``.
    """
    try:
        tags = image.getexif().get_ifd(_EXIF_IFD)
        value = tags.get(_EXIF_FOCAL_35MM_TAG)
        focal = float(value) if value else None
        if focal is None:
            focal = _focal_35mm_from_focal_plane(tags, image.size)
    except (TypeError, ValueError, OSError, SyntaxError, ZeroDivisionError):
        return None
    if focal is None or not FOCAL_35MM_RANGE[0] <= focal <= FOCAL_35MM_RANGE[1]:
        return None
    return focal


def _focal_35mm_from_focal_plane(tags: Any, size: tuple[int, int]) -> float | None:
    """35 mm equivalent of ``FocalLength`` from the focal plane resolution, None if a tag is
    missing. ``size``: the stored image's (width, height), used where PixelX/YDimension are
    absent."""
    focal_mm, x_res, y_res = (tags.get(t) for t in (_EXIF_FOCAL_TAG, _EXIF_PLANE_X,
                                                     _EXIF_PLANE_Y))
    unit = _PLANE_UNIT_MM.get(int(tags.get(_EXIF_PLANE_UNIT, 2)))
    if not focal_mm or not x_res or not y_res or unit is None:
        return None
    width = float(tags.get(_EXIF_PIXEL_X) or size[0])
    height = float(tags.get(_EXIF_PIXEL_Y) or size[1])
    sensor_diagonal = math.hypot(width / float(x_res), height / float(y_res)) * unit
    return float(focal_mm) * FULL_FRAME_DIAGONAL_MM / sensor_diagonal


def stored_orientation(image: Image.Image) -> tuple[int, tuple[int, int]]:
    """The EXIF orientation of an opened photo and the (width, height) of its stored pixels.

    pillow-heif decodes a HEIF already upright (its size is the upright one) and resets the
    EXIF tag to 1, keeping the original in ``info["original_orientation"]``: both are undone
    here, so a mask drawn on the stored pixels is recognised as for a JPEG.
    """
    if image.format == "HEIF":
        orientation = int(image.info.get("original_orientation") or 1)
        width, height = image.size
        return orientation, (height, width) if orientation in (5, 6, 7, 8) else (width, height)
    return int(image.getexif().get(_EXIF_ORIENTATION_TAG, 1) or 1), image.size


def _decode(image: Image.Image, name: str, what: str) -> Image.Image:
    """Decode all pixels and apply the EXIF orientation. InputError if the data is damaged."""
    try:
        image.load()
        return ImageOps.exif_transpose(image)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise InputError(f"the {what} is damaged or truncated", item=name,
                         hint="export or upload it again") from exc


def _to_array(image: Image.Image) -> tuple[np.ndarray, np.ndarray | None]:
    """RGB [H, W, 3] float32 in [0, 1] and the alpha mask (None without real transparency)."""
    if image.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
        gray = np.asarray(image, dtype=np.float32)
        gray = gray / (65535.0 if gray.max() > 255 else 255.0)
        return np.repeat(np.clip(gray, 0, 1)[..., None], 3, axis=2), None
    if not has_transparency(image):
        return np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0, None
    rgba = np.asarray(image.convert("RGBA"), dtype=np.float32) / 255.0
    alpha = rgba[..., 3:]
    mask = alpha[..., 0] > 0.5
    if mask.all():
        return rgba[..., :3].copy(), None
    return rgba[..., :3] * alpha + (1.0 - alpha), mask


def _working_image(raw: Image.Image, name: str, orientation: int,
                   raw_size: tuple[int, int]) -> Image.Image:
    """Decode a photo upright at its working size (``limits.working_size``).

    A JPEG is decoded at a reduced scale by its decoder (no full-size copy is ever made); any
    photo still over ``WORKING_PIXELS`` is then scaled down with its aspect kept.
    """
    if raw.format in ("JPEG", "MPO"):
        raw.draft(None, working_size(*raw_size))  # type: ignore[arg-type]
    image = _decode(raw, name, "photo")
    upright = _upright(raw_size, orientation)
    target = working_size(*upright)
    if image.size == target:
        return image
    if image.mode not in ("L", "LA", "RGB", "RGBA", "I", "F"):
        image = image.convert("I" if image.mode.startswith("I;16") else
                              "RGBA" if has_transparency(image) else "RGB")
    return image.resize(target, Image.Resampling.LANCZOS, reducing_gap=3.0)


def _upright(size: tuple[int, int], orientation: int) -> tuple[int, int]:
    """(width, height) of stored pixels ``size`` once the EXIF ``orientation`` is applied."""
    return (size[1], size[0]) if orientation in (5, 6, 7, 8) else size


def load_photo(source: PhotoSource, index: int = 0, mask: PhotoSource | None = None) -> Photo:
    """Read one photo (and its mask). See ``load_photos``."""
    name, data = _read_source(source, index)
    raw = _open_image(name, data, "photo", PHOTO_FORMATS)
    orientation, raw_size = stored_orientation(raw)
    focal = exif_focal_35mm(raw)
    upright = _upright(raw_size, orientation)
    rgb, alpha_mask = _to_array(_working_image(raw, name, orientation, raw_size))
    if mask is None:
        return Photo(name, rgb, alpha_mask, focal, "alpha" if alpha_mask is not None else None,
                     upright)
    mask_name, mask_data = _read_source(mask, index)
    mask_image = _decode(_open_image(name, mask_data, f"mask ({mask_name})", None), name, "mask")
    if mask_image.size == raw_size != upright and orientation in _ORIENTATION:
        # A mask drawn on the photo's stored pixels (before its EXIF rotation): rotate it alike.
        mask_image = mask_image.transpose(_ORIENTATION[orientation])
    if mask_image.size != upright:
        (w, h), (mw, mh) = upright, mask_image.size
        raise InputError(f"the mask is {mw}x{mh} pixels but the photo is {w}x{h}", item=name,
                         hint="give a mask of the same size as its photo, in the same order")
    if mask_image.size != (rgb.shape[1], rgb.shape[0]):  # the photo's working size
        mask_image = mask_image.resize((rgb.shape[1], rgb.shape[0]), Image.Resampling.NEAREST)
    return Photo(name, rgb, mask_array(mask_image), focal, "uploaded", upright)


def load_photos(paths: Sequence[PhotoSource],
                mask_paths: Sequence[PhotoSource] | None = None) -> list[Photo]:
    """Read ordered photos and, optionally, one mask per photo in the same order.

    Args:
        paths: photo files (path, raw bytes, or (name, bytes)); JPEG, PNG, WebP, HEIC/HEIF,
            AVIF (where Pillow reads it).
        mask_paths: masks in the same order, any image format; nonzero (or opaque) = object.
            A mask the size of the photo's stored pixels, where the photo's EXIF orientation
            rotates it to another size, gets the same rotation.
    Returns:
        One ``Photo`` per input, in order.
    Raises:
        InputError: naming the photo, for an unreadable, empty, damaged, tiny (< 64 px a side),
            strip-shaped (one side over 4 times the other) or huge (> 40 MP) file, or a mask
            whose size differs from its photo's.
    """
    if mask_paths is not None and len(mask_paths) != len(paths):
        raise InputError(f"{len(mask_paths)} masks for {len(paths)} photos", item="masks",
                         hint="give one mask per photo, in the same order, or none")
    masks: Sequence[PhotoSource | None] = mask_paths or [None] * len(paths)
    return [load_photo(src, i, m) for i, (src, m) in enumerate(zip(paths, masks, strict=True))]


def canonical_masks(masks: Sequence[np.ndarray], size: int,
                    margin: float = DEFAULT_MARGIN) -> tuple[np.ndarray, list[CropBox]]:
    """Canonical crops of full-photo masks.

    Args:
        masks: N masks [H_i, W_i] bool (sizes may differ).
        size: output side S in pixels.
        margin: free fraction of the crop on each side.
    Returns:
        crops [N, S, S] bool and each photo's CropBox (photo pixels -> crop pixels).
    """
    boxes = [canonical_box(mask, size, margin) for mask in masks]
    crops = np.stack([apply_crop(mask, box) for mask, box in zip(masks, boxes, strict=True)])
    return crops, boxes


def canonical_views(photos: Sequence[Photo], masks: Sequence[np.ndarray], size: int,
                    margin: float = DEFAULT_MARGIN,
                    ) -> tuple[np.ndarray, np.ndarray, list[CropBox]]:
    """Canonical crops of photos (composited on white) and their masks, for training.

    Args:
        photos: N photos.
        masks: N masks [H_i, W_i] bool, one per photo.
        size: output side S in pixels.
        margin: free fraction of the crop on each side.
    Returns:
        rgb [N, S, S, 3] float32 on white, mask [N, S, S] bool, and the N CropBoxes.
    """
    crops, boxes = canonical_masks(masks, size, margin)
    rgbs = []
    for photo, mask, box in zip(photos, masks, boxes, strict=True):
        alpha = apply_crop(mask.astype(np.float32), box)[..., None]
        rgb = apply_crop(photo.rgb.astype(np.float32), box, fill=1.0)
        rgbs.append(np.clip(rgb * alpha + (1.0 - alpha), 0.0, 1.0))
    return np.stack(rgbs).astype(np.float32), crops, boxes


def doubt_weights(doubts: Sequence[np.ndarray | None], shapes: Sequence[tuple[int, ...]],
                  boxes: Sequence[CropBox], level: float = 0.0) -> np.ndarray | None:
    """Per-pixel loss weights of canonical crops: ``level`` where a mask is in doubt, else 1.

    Args:
        doubts: N maps [h_i, w_i] bool over whole photos at any size of the photo's aspect
            ratio (``MaskResult.doubt``), or None where a mask is not in doubt anywhere.
        shapes: the N photos' (H_i, W_i, ...) shapes, the pixels ``boxes`` refer to.
        boxes: the N canonical crop boxes.
        level: a doubtful pixel's weight (``MasksConfig.doubt_weight``).
    Returns:
        [N, S, S] float32 in [0, 1] (partly doubtful pixels weigh in between), or None when
        no photo has a doubt map or a doubtful pixel weighs as much as any.
    """
    if level >= 1.0 or all(doubt is None for doubt in doubts):
        return None
    size = boxes[0].size
    out = np.ones((len(boxes), size, size), np.float32)
    for i, (doubt, shape, box) in enumerate(zip(doubts, shapes, boxes, strict=True)):
        if doubt is None:
            continue
        scale = doubt.shape[1] / shape[1]  # doubt-map pixels per photo pixel
        small = CropBox(box.x0 * scale, box.y0 * scale, box.side * scale, size)
        out[i] -= (1.0 - level) * apply_crop(doubt.astype(np.float32), small)
    return np.clip(out, 0.0, 1.0)

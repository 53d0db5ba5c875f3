"""Stage 1-2: photos (EXIF, HEIC, orientation), background removal and the canonical crop.

The names below are the package's public face; each loads its module on first use, so
importing the package costs nothing (torch loads only with what needs it).
"""

from typing import TYPE_CHECKING

from cadnerf_core.facade import lazy_exports

EXPORTS = {
    "photos": ("Photo", "load_photo", "load_photos", "with_focal", "canonical_views"),
    "masks": ("photo_masks", "mask_overlay"),
    "crop": ("CropBox", "apply_crop", "canonical_box"),
    "resize": ("downscaled", "shrunk_mask"),
}
"""Module -> the public names it holds."""
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
__all__ = ["CropBox", "Photo", "apply_crop", "canonical_box", "canonical_views", "downscaled",
    "load_photo", "load_photos", "mask_overlay", "photo_masks", "shrunk_mask", "with_focal"]

if TYPE_CHECKING:
    from cadnerf_core.intake.crop import CropBox, apply_crop, canonical_box
    from cadnerf_core.intake.masks import mask_overlay, photo_masks
    from cadnerf_core.intake.photos import (
        Photo,
        canonical_views,
        load_photo,
        load_photos,
        with_focal,
    )
    from cadnerf_core.intake.resize import downscaled, shrunk_mask

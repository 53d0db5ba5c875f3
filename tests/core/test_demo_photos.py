"""The demo's photos are like a user's: JPEGs whose EXIF gives the lens, the object large enough
to be matched and textured, each with the object's exact mask."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from cadnerf_cli.demo_photos import FOCAL_35MM, HEIGHT, WIDTH, demo_focal_px, render_demo_photos
from cadnerf_core.config_matches import MIN_SEARCH_SIDE
from cadnerf_core.intake.photos import load_photo


def test_the_demo_photos_carry_their_lens_a_large_textured_object_and_its_mask(
        tmp_path: Path) -> None:
    photos, masks = render_demo_photos(tmp_path, views=3)
    assert [p.name for p in photos] == ["000.jpg", "001.jpg", "002.jpg"]
    for index, (path, mask_path) in enumerate(zip(photos, masks, strict=True)):
        photo = load_photo(path, index, None)
        assert photo.size == (WIDTH, HEIGHT) and photo.focal_35mm == FOCAL_35MM
        assert photo.focal_pixels is not None
        assert abs(photo.focal_pixels - demo_focal_px()) < 0.01 * demo_focal_px()
        with Image.open(mask_path) as image:
            mask = np.asarray(image) > 127
        rows, cols = np.nonzero(mask)
        assert max(np.ptp(rows), np.ptp(cols)) >= 1.5 * MIN_SEARCH_SIDE  # matched, not too small
        assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
        grey = photo.rgb.astype(np.float32).mean(axis=-1)
        assert grey[mask].std() > 0.05 * grey[mask].mean()  # grain to match, not flat paint
        assert grey[~mask].std() > 0.05 * grey[~mask].mean()  # a floor, not a blank backdrop

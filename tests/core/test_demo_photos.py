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


def test_every_photo_of_the_demo_walk_shares_points_with_a_neighbour(tmp_path: Path) -> None:
    """The first run shows no camera resting on its outline alone: at the demo's ten photos
    each has a neighbour (or next-but-one) whose matches give a rotation."""
    from cadnerf_cli.demo_cmd import VIEWS
    from cadnerf_core.cameras.learned import close_pairs
    from cadnerf_core.cameras.matches import match_photos
    from cadnerf_core.config import MatchesConfig

    photos, masks = render_demo_photos(tmp_path, views=VIEWS)
    images = [load_photo(path, k, None).rgb for k, path in enumerate(photos)]
    silhouettes = []
    for path in masks:
        with Image.open(path) as image:
            silhouettes.append(np.asarray(image) > 127)
    focal = demo_focal_px()
    K = np.array([[focal, 0.0, WIDTH / 2.0], [0.0, focal, HEIGHT / 2.0], [0.0, 0.0, 1.0]])
    pairs = match_photos(images, silhouettes, [K] * VIEWS, MatchesConfig())
    close = close_pairs(VIEWS)
    placed = {k for p in pairs if p.rotation is not None and (p.i, p.j) in close
              for k in (p.i, p.j)}
    assert placed == set(range(VIEWS))

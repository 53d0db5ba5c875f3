"""Background removal on synthetic photos, and its refusals."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cadnerf_core.errors import InputError
from cadnerf_core.intake.masks import largest_component, photo_masks, remove_background
from cadnerf_core.intake.photos import Photo


def _synthetic_photo(height: int = 96, width: int = 128) -> tuple[Photo, np.ndarray]:
    """An orange blob on a textured blue-grey gradient, and its true mask."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    background = np.stack([0.3 + 0.2 * x, 0.35 + 0.2 * y, 0.55 + 0.1 * x], -1)
    background += rng.normal(0, 0.03, background.shape)  # texture
    truth = np.zeros((height, width), np.uint8)
    cv2.ellipse(truth, (width // 2 + 6, height // 2), (30, 22), 20, 0, 360, 1, -1)
    cv2.rectangle(truth, (width // 2 - 30, height // 2 - 4), (width // 2, height // 2 + 30), 1, -1)
    mask = truth.astype(bool)
    rgb = background.copy()
    rgb[mask] = [0.9, 0.5, 0.1] + rng.normal(0, 0.03, (int(mask.sum()), 3))
    return Photo("synthetic.png", np.clip(rgb, 0, 1).astype(np.float32)), mask


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_grabcut_finds_a_shape_on_a_textured_gradient() -> None:
    photo, truth = _synthetic_photo()
    mask = remove_background(photo)
    assert mask.shape == truth.shape and mask.dtype == bool
    assert _iou(mask, truth) > 0.9


def test_grabcut_works_on_a_large_photo_through_a_downscaled_copy() -> None:
    photo, truth = _synthetic_photo()
    big = Photo("big.png", cv2.resize(photo.rgb, (640, 480), interpolation=cv2.INTER_NEAREST))
    big_truth = cv2.resize(truth.astype(np.uint8), (640, 480),
                           interpolation=cv2.INTER_NEAREST).astype(bool)
    assert _iou(remove_background(big), big_truth) > 0.9


def test_empty_scene_is_refused_naming_the_photo() -> None:
    flat = Photo("blank.jpg", np.full((80, 80, 3), 0.5, np.float32))
    with pytest.raises(InputError) as info:
        remove_background(flat)
    assert info.value.item == "blank.jpg" and "mask" in (info.value.hint or "")


def test_learned_remover_never_downloads(tmp_path: Path) -> None:
    photo, _ = _synthetic_photo()
    with pytest.raises(InputError, match="no weights"):
        remove_background(photo, method="learned", weights=tmp_path / "u2net.onnx")
    with pytest.raises(InputError, match="no weights"):
        remove_background(photo, method="learned")


def test_photo_masks_prefers_the_photo_own_mask() -> None:
    photo, truth = _synthetic_photo()
    given = np.zeros_like(truth)
    given[10:40, 10:40] = True
    found = photo_masks([Photo("own.png", photo.rgb, given, mask_source="uploaded"), photo],
                        "grabcut")
    assert np.array_equal(found[0].mask, given) and found[0].source == "uploaded"
    assert _iou(found[1].mask, truth) > 0.9 and found[1].source == "grabcut"
    with pytest.raises(InputError) as info:
        photo_masks([Photo("void.png", photo.rgb, np.zeros_like(truth))])
    assert info.value.item == "void.png"


def test_largest_component_fills_holes_and_drops_specks() -> None:
    mask = np.zeros((40, 40), bool)
    mask[5:30, 5:30] = True
    mask[10:15, 10:15] = False  # a hole
    mask[35:38, 35:38] = True  # a speck
    clean = largest_component(mask)
    assert clean[5:30, 5:30].all() and not clean[35:, 35:].any()
    # With a weight, the component with the most weight wins even when smaller.
    weight = np.zeros((40, 40))
    weight[36, 36] = 1.0
    assert largest_component(mask, weight)[36, 36] and not largest_component(mask, weight)[6, 6]

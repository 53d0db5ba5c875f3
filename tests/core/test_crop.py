"""The canonical crop: placement, resampling, and exact composition with intrinsics."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose, project
from cadnerf_core.intake.crop import (
    CropBox,
    apply_crop,
    canonical_box,
    crop_intrinsics,
    mask_bbox,
    uncrop_intrinsics,
)
from cadnerf_core.mesh.renderer import MeshRenderer


def _rect_mask(height: int, width: int, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
    mask = np.zeros((height, width), dtype=bool)
    mask[y0:y1, x0:x1] = True
    return mask


def test_canonical_box_centres_and_sizes_the_mask() -> None:
    mask = _rect_mask(80, 100, 10, 20, 50, 40)  # 40 wide, 20 tall, centre (30, 30)
    box = canonical_box(mask, size=32, margin=0.1)
    assert box.side == pytest.approx(40 / 0.8)
    assert box.x0 + box.side / 2 == pytest.approx(30.0)
    assert box.y0 + box.side / 2 == pytest.approx(30.0)
    assert box.size == 32


def test_apply_crop_of_a_bool_mask_centres_it_with_the_margin() -> None:
    mask = _rect_mask(80, 100, 10, 20, 50, 40)
    box = canonical_box(mask, size=40, margin=0.1)
    crop = apply_crop(mask, box)
    assert crop.dtype == bool and crop.shape == (40, 40)
    x0, y0, x1, y1 = mask_bbox(crop)
    assert (x0, x1) == (4, 36)  # 0.1 * 40 free on each side of the wider extent
    assert (y0 + y1) / 2 == pytest.approx(20.0, abs=0.5)
    assert y1 - y0 == 16


def test_apply_crop_pads_outside_the_image_with_fill() -> None:
    image = np.ones((20, 20, 3), dtype=np.float32)
    crop = apply_crop(image, CropBox(-10.0, -10.0, 40.0, 40), fill=0.0)
    assert crop.shape == (40, 40, 3)
    assert crop[0, 0].max() == 0.0 and crop[20, 20].min() == 1.0


def test_crop_intrinsics_project_points_into_the_crop() -> None:
    K = intrinsics_from_fov(40.0, 200, 150)
    c2w = orbit_pose(35.0, 25.0, 4.0)
    box = CropBox(40.0, 12.5, 90.0, 64)
    points = np.random.default_rng(0).uniform(-1, 1, size=(20, 3))
    uv = project(points, K, c2w)
    uv_cropped = np.c_[uv, np.ones(len(uv))] @ box.affine().T
    np.testing.assert_allclose(project(points, crop_intrinsics(K, box), c2w), uv_cropped[:, :2],
                               atol=1e-9)
    np.testing.assert_allclose(uncrop_intrinsics(crop_intrinsics(K, box), box), K, atol=1e-9)


@pytest.mark.parametrize("size", [32, 96])  # shrinking and enlarging
def test_cropped_render_matches_a_render_with_cropped_intrinsics(size: int) -> None:
    mesh = trimesh.creation.box((1.2, 0.6, 0.8))
    renderer = MeshRenderer(mesh)
    K = intrinsics_from_fov(40.0, 96, 80)
    c2w = orbit_pose(30.0, 20.0, 3.0)
    mask = renderer.silhouette(K, c2w, 96, 80)
    box = canonical_box(mask, size=size)
    cropped = apply_crop(mask, box)
    direct = renderer.silhouette(crop_intrinsics(K, box), c2w, size, size)
    iou = (cropped & direct).sum() / (cropped | direct).sum()
    assert iou > 0.96

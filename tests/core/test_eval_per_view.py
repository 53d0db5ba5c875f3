"""The fidelity protocol's cameras (``evaluate_dataset(align="per-view")``): the frame fit
from the better of two starts, and each held-out camera refined on its own photo."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cadnerf_core.cameras import intrinsics_from_fov, look_at, rotation_angle_deg
from cadnerf_core.evaluation.dataset import Dataset
from cadnerf_core.evaluation.frame import (
    Similarity,
    frame_mapping,
    photo_loss,
    refine_view,
)
from cadnerf_core.evaluation.jobio import JobCameras
from tests.core.test_evaluation import _Ball, _gt_poses

SIZE = 32


def _nudged(c2w: np.ndarray, degrees: float, shift: float) -> np.ndarray:
    """c2w moved in its own frame by a turn about a slanted axis and a shift."""
    out = c2w.copy()
    axis = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    turn = Rotation.from_rotvec(np.radians(degrees) * axis).as_matrix()
    out[:3, :3] = c2w[:3, :3] @ turn
    out[:3, 3] = c2w[:3, 3] + c2w[:3, :3] @ np.array([shift, -shift, 0.0])
    return out


def test_a_held_out_camera_is_refined_onto_its_photo() -> None:
    ball = _Ball()
    K = intrinsics_from_fov(40.0, SIZE)
    truth = _gt_poses(1, seed=3)[0]
    photo = ball.render(truth, K, SIZE)
    mask = photo.min(-1) < 0.99
    start = _nudged(truth, 4.0, 0.08)
    refined = refine_view(ball, start, K, photo, mask, steps=150, rays=512)  # type: ignore[arg-type]

    def turn(c2w: np.ndarray) -> float:
        return float(rotation_angle_deg((c2w[:3, :3] @ truth[:3, :3].T)[None])[0])

    def shift(c2w: np.ndarray) -> float:
        return float(np.linalg.norm(c2w[:3, 3] - truth[:3, 3]))

    # A smooth ball lets a turn and a shift stand in for each other a little; the photo does
    # not (measured: 1.5 deg, 0.04 and the loss 2000x lower).
    assert turn(refined) < 0.6 * turn(start)
    assert shift(refined) < 0.6 * shift(start)
    assert (photo_loss(ball, refined[None], K[None], photo[None])  # type: ignore[arg-type]
            < 0.01 * photo_loss(ball, start[None], K[None], photo[None]))  # type: ignore[arg-type]
    assert ball.state.fields.dummy.requires_grad  # the fields' flags are restored
    np.testing.assert_array_equal(refine_view(ball, start, K, photo, steps=0), start)  # type: ignore[arg-type]


def test_a_camera_that_sees_nothing_stays_where_it_is() -> None:
    ball = _Ball()
    away = look_at(np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, 9.0]))
    K = intrinsics_from_fov(40.0, 16)
    kept = refine_view(ball, away, K, np.ones((16, 16, 3), np.float32), steps=5, rays=64)  # type: ignore[arg-type]
    np.testing.assert_array_equal(kept, away)


def test_the_frame_starts_free_where_the_object_sits_off_the_origin() -> None:
    """The job's cameras agree with the references exactly, but the object stands off the
    NeRF's origin: the centred start misplaces every camera, the free one does not, and the
    photos say which is right."""
    ball = _Ball(centre=(0.45, -0.3, 0.2))
    gt = np.stack([look_at(position, np.array([0.45, -0.3, 0.2]))
                   for position in _gt_poses(5, seed=2)[:, :3, 3]])
    K = np.stack([intrinsics_from_fov(40.0, SIZE)] * len(gt))
    images = np.stack([ball.render(c2w, K[0], SIZE) for c2w in gt])
    data = Dataset(images=images, masks=images.min(-1) < 0.99, c2w=gt, K=K,
                   names=[f"{i:03d}" for i in range(len(gt))], root=Path("."))
    cams = JobCameras(model_id="ball", category="ball", kept=list(range(len(gt))),
                      discarded=[], retrieved=gt, refined=gt, K_photo=K, K_retrieved=K)

    def miss(sim: Similarity) -> float:
        return float(np.abs(sim.apply_to_poses(gt)[:, :3, 3] - gt[:, :3, 3]).max())

    centred = frame_mapping(ball, data, cams, "centred", "gt")  # type: ignore[arg-type]
    assert miss(centred) > 0.3  # the axes' meeting point was put on the origin
    # Fitted from the centred start alone it stays off (measured 0.20).
    assert miss(frame_mapping(ball, data, cams, "photometric", "gt")) > 0.1  # type: ignore[arg-type]
    chosen = frame_mapping(ball, data, cams, "per-view", "gt")  # type: ignore[arg-type]
    assert miss(chosen) < 0.02
    with pytest.raises(ValueError, match="per-view"):
        frame_mapping(ball, data, cams, "sideways", "gt")  # type: ignore[arg-type]

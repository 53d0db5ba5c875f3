"""Camera conventions: poses, intrinsics, transforms.json, pose corrections and alignment."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from cadnerf_core.cameras.conventions import (
    from_transforms_json,
    intrinsics_from_fov,
    library_poses,
    look_at,
    orbit_pose,
    pose_errors,
    project,
    se3_exp,
    spherical_position,
    to_transforms_json,
    umeyama,
)


@pytest.mark.parametrize("eye", [(0.0, 0.0, 4.0), (1.0, 2.0, -3.0), (0.0, 5.0, 0.0),
                                 (0.0, -3.0, 0.0)])
def test_look_at_axes_orthonormal_and_camera_looks_at_target(eye: tuple[float, ...]) -> None:
    target = np.array([0.2, -0.1, 0.3])
    c2w = look_at(np.array(eye), target)
    R = c2w[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    forward = (target - np.array(eye)) / np.linalg.norm(target - np.array(eye))
    np.testing.assert_allclose(R[:, 2], forward, atol=1e-12)
    K = intrinsics_from_fov(40.0, 64)
    np.testing.assert_allclose(project(target[None], K, c2w)[0], [32.0, 32.0], atol=1e-9)


def test_look_at_keeps_world_up_at_the_top_of_the_image() -> None:
    c2w = orbit_pose(30.0, 20.0, 4.0)
    K = intrinsics_from_fov(40.0, 64)
    above, below = project(np.array([[0.0, 0.5, 0.0], [0.0, -0.5, 0.0]]), K, c2w)
    assert above[1] < below[1]  # image y grows downward


def test_azimuth_zero_is_on_plus_z_and_grows_toward_plus_x() -> None:
    np.testing.assert_allclose(spherical_position(0.0, 0.0, 2.0), [0.0, 0.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(spherical_position(90.0, 0.0, 2.0), [2.0, 0.0, 0.0], atol=1e-12)
    assert spherical_position(0.0, 30.0, 2.0)[1] == pytest.approx(1.0)


def test_library_poses_order_and_count() -> None:
    elevations = (0, 15, 30, 45, 60)
    c2w, az_el = library_poses(20, elevations, 4.0)
    assert c2w.shape == (100, 4, 4) and az_el.shape == (100, 2)
    a, e = 7, 3
    i = a * len(elevations) + e
    np.testing.assert_allclose(az_el[i], [7 * 18.0, 45.0])
    np.testing.assert_allclose(c2w[i], orbit_pose(126.0, 45.0, 4.0), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(c2w[:, :3, 3], axis=1), 4.0)


def test_intrinsics_from_fov() -> None:
    K = intrinsics_from_fov(90.0, 100, 60)
    np.testing.assert_allclose(K, [[50.0, 0.0, 50.0], [0.0, 50.0, 30.0], [0.0, 0.0, 1.0]],
                               atol=1e-12)
    # A point on the edge of the field of view lands on the image border.
    K40 = intrinsics_from_fov(40.0, 64)
    edge = np.array([[math.tan(math.radians(20.0)), 0.0, 1.0]])
    np.testing.assert_allclose(project(edge, K40, np.eye(4))[0], [64.0, 32.0], atol=1e-9)


def test_transforms_json_round_trip_is_exact() -> None:
    c2w, _ = library_poses(5, (0, 30), 3.0)
    K = np.stack([intrinsics_from_fov(40.0 + i, 48, 32) for i in range(len(c2w))])
    data = to_transforms_json(c2w, K, 48, 32, [f"images/{i:03d}" for i in range(len(c2w))])
    back_c2w, back_K = from_transforms_json(json.loads(json.dumps(data)), 48, 32)
    assert np.array_equal(back_c2w, c2w)
    assert np.array_equal(back_K, K)
    # OpenGL axes on disk: the camera looks along -z of its transform_matrix.
    gl = np.asarray(data["frames"][0]["transform_matrix"])
    np.testing.assert_allclose(gl[:3, 2], -c2w[0, :3, 2])


def test_se3_exp_at_zero_is_identity_with_finite_gradient() -> None:
    xi = torch.zeros(2, 6, dtype=torch.float64, requires_grad=True)
    T = se3_exp(xi)
    assert torch.equal(T.detach(), torch.eye(4, dtype=torch.float64).expand(2, 4, 4))
    (T * torch.randn_like(T)).sum().backward()
    assert xi.grad is not None and torch.isfinite(xi.grad).all()
    assert xi.grad.abs().sum() > 0


def test_se3_exp_matches_scipy_rotation() -> None:
    rng = np.random.default_rng(0)
    rotvecs = rng.normal(size=(5, 3)) * np.array([[1.0], [0.1], [1e-5], [2.0], [3.0]])
    xi = torch.tensor(np.concatenate([rotvecs, rng.normal(size=(5, 3))], 1))
    T = se3_exp(xi).numpy()
    np.testing.assert_allclose(T[:, :3, :3], Rotation.from_rotvec(rotvecs).as_matrix(),
                               atol=1e-9)
    np.testing.assert_allclose(T[:, :3, 3], xi[:, 3:].numpy())
    np.testing.assert_allclose(T[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)))


def test_umeyama_recovers_a_known_similarity() -> None:
    rng = np.random.default_rng(1)
    src = rng.normal(size=(10, 3))
    R = Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix()
    t = np.array([0.5, -2.0, 3.0])
    dst = 2.5 * src @ R.T + t
    scale, R_est, t_est = umeyama(src, dst)
    assert scale == pytest.approx(2.5)
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-9)


def _similarity(c2w: np.ndarray, scale: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    out = c2w.copy()
    out[:, :3, :3] = R @ c2w[:, :3, :3]
    out[:, :3, 3] = scale * c2w[:, :3, 3] @ R.T + t
    return out


def test_pose_errors_zero_for_a_similarity_transformed_copy() -> None:
    gt, _ = library_poses(6, (10, 40), 4.0)
    R = Rotation.from_euler("zyx", [20, 75, -40], degrees=True).as_matrix()
    pred = _similarity(gt, 0.3, R, np.array([1.0, 2.0, -1.0]))
    rot, trans = pose_errors(pred, gt)
    np.testing.assert_allclose(rot, 0.0, atol=1e-5)
    np.testing.assert_allclose(trans, 0.0, atol=1e-9)


def test_pose_errors_report_a_known_rotation_error() -> None:
    gt, _ = library_poses(6, (10, 40), 4.0)
    pred = gt.copy()
    delta = Rotation.from_rotvec(np.radians(5.0) * np.array([0.0, 0.6, 0.8])).as_matrix()
    pred[:, :3, :3] = gt[:, :3, :3] @ delta  # same centres: alignment is the identity
    rot, trans = pose_errors(pred, gt)
    np.testing.assert_allclose(rot, 5.0, atol=1e-6)
    np.testing.assert_allclose(trans, 0.0, atol=1e-9)


def test_scaling_the_focal_length_keeps_the_principal_point() -> None:
    from cadnerf_core.cameras.conventions import scale_focal

    K = np.array([[100.0, 0.0, 64.0], [0.0, 110.0, 48.0], [0.0, 0.0, 1.0]])
    scaled = scale_focal(K, 1.5)
    assert np.allclose(scaled, [[150.0, 0.0, 64.0], [0.0, 165.0, 48.0], [0.0, 0.0, 1.0]])
    assert K[0, 0] == 100.0  # a copy

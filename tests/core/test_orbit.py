"""The orbit check: a relative pose must show both cameras looking at one object."""

from __future__ import annotations

import numpy as np
import pytest

from cadnerf_core.cameras.orbit import object_centre, orbit_consistent

K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])


def _look_at(azimuth_deg: float, distance: float = 4.0, elevation_deg: float = 20.0,
             roll_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t), OpenCV axes, a camera on a sphere looking at the origin."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    centre = distance * np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
    forward = -centre / np.linalg.norm(centre)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    roll = np.radians(roll_deg)
    spin = np.array([[np.cos(roll), -np.sin(roll), 0], [np.sin(roll), np.cos(roll), 0],
                     [0, 0, 1.0]])
    R = spin @ R
    return R, -R @ centre


def _relative(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]
              ) -> tuple[np.ndarray, np.ndarray]:
    R = b[0] @ a[0].T
    return R, b[1] - R @ a[1]


def _centre(camera: tuple[np.ndarray, np.ndarray], point: np.ndarray) -> np.ndarray:
    x = K @ (camera[0] @ point + camera[1])
    return x[:2] / x[2]


@pytest.mark.parametrize(("step", "far", "roll"), [(10, 1.0, 0), (45, 1.0, 0), (45, 1.4, 4),
                                                   (90, 0.8, 0), (30, 1.0, -5)])
def test_two_cameras_round_one_object_pass(step: float, far: float, roll: float) -> None:
    a, b = _look_at(0.0), _look_at(step, 4.0 * far, 30.0, roll)
    R, t = _relative(a, b)
    origin = np.zeros(3)
    assert orbit_consistent(R, t * 0.37, _centre(a, origin), _centre(b, origin), K, K)


def test_the_wrong_turn_or_a_camera_facing_away_fails() -> None:
    a, b = _look_at(0.0), _look_at(45.0)
    R, t = _relative(a, b)
    ca, cb = _centre(a, np.zeros(3)), _centre(b, np.zeros(3))
    assert not orbit_consistent(R, -t, ca, cb, K, K)  # the baseline the other way
    # Twice the turn with the same baseline: the rays no longer meet.
    R2, _ = _relative(a, _look_at(90.0))
    assert not orbit_consistent(R2, t, ca, cb, K, K)
    # A turn about the line joining the cameras (a spin seen from the side).
    axis = t / np.linalg.norm(t)
    angle = np.radians(45.0)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    spin = np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross
    assert not orbit_consistent(spin, t, ca, cb, K, K)
    assert not orbit_consistent(R, np.zeros(3), ca, cb, K, K)


def test_the_object_centre_is_the_masks_centroid() -> None:
    mask = np.zeros((40, 60), bool)
    mask[10:20, 30:50] = True
    assert object_centre(mask) == pytest.approx([39.5, 14.5])

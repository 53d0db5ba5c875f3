"""Whether a pair's relative pose is one of two cameras looking at the same object.

Every photo of a job shows one object, framed whole: the ray through the centre of its mask
passes near the object's centre. Two photos' centre rays must therefore meet (nearly) in front
of both cameras, the turn between the cameras is about an axis square to the line joining
them (the cameras swing round a common point), and the distance to that point fits the turn
(two cameras at like distances d turned by an angle a stand 2 d sin(a / 2) apart). An
essential matrix that RANSAC fitted to matches on repeated print, or to background that stays
put while the object turns, fails one of these, though its inliers may be many.
"""

from __future__ import annotations

import math

import numpy as np

MAX_GAP_DEG = 6.0
"""Largest angle, seen from the first camera, by which the two centre rays may miss each
other."""
MAX_AXIS_TILT_DEG = 20.0
"""Largest angle between the turn's axis and the plane square to the baseline (a phone rolled
between photos tilts it a few degrees)."""
MIN_TURN_DEG = 15.0
"""Turns smaller than this leave the axis and the distance check undefined: not judged."""
DISTANCE_FIT = (0.4, 2.5)
"""Range of the distance to the meeting point over the one two cameras at equal distances
turned by the pair's angle would have (photos taken nearer and farther spread it)."""


def object_centre(mask: np.ndarray) -> np.ndarray:
    """The centroid [x, y] of a mask's pixels, in pixel centres (at integers)."""
    rows, cols = np.nonzero(mask)
    return np.array([cols.mean(), rows.mean()], dtype=np.float64)


def _ray(centre: np.ndarray, K: np.ndarray) -> np.ndarray:
    ray = np.linalg.solve(K, np.array([centre[0], centre[1], 1.0]))
    return ray / np.linalg.norm(ray)


def orbit_consistent(R: np.ndarray, t: np.ndarray, centre_a: np.ndarray,
                     centre_b: np.ndarray, K_a: np.ndarray, K_b: np.ndarray) -> bool:
    """Whether a relative pose (``x_b = R @ x_a + t``, OpenCV axes, ``t`` up to scale) puts two
    photos' object centres (``object_centre``, photo pixels; ``K_a``, ``K_b`` their
    intrinsics) on rays that meet in front of both cameras, with the turn's axis square to
    the baseline and the meeting point at a distance that fits the turn."""
    t = np.asarray(t, dtype=np.float64).ravel()
    if np.linalg.norm(t) < 1e-12:
        return False
    ray_a = _ray(centre_a, K_a)
    origin_b = -R.T @ t / np.linalg.norm(t)  # camera b's centre in a's frame, unit baseline
    ray_b = R.T @ _ray(centre_b, K_b)
    # Closest approach of origin + s ray_a and origin_b + u ray_b.
    system = np.array([[1.0, -(ray_a @ ray_b)], [ray_a @ ray_b, -1.0]])
    if abs(np.linalg.det(system)) < 1e-9:  # parallel rays meet nowhere near
        return False
    s, u = np.linalg.solve(system, np.array([origin_b @ ray_a, origin_b @ ray_b]))
    if s <= 0 or u <= 0:
        return False
    gap = np.linalg.norm(s * ray_a - (origin_b + u * ray_b))
    if math.degrees(math.asin(min(1.0, gap / s))) > MAX_GAP_DEG:
        return False
    turn = math.acos(float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    if math.degrees(turn) < MIN_TURN_DEG:
        return True
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    axis /= np.linalg.norm(axis)
    if math.degrees(math.asin(min(1.0, abs(float(axis @ origin_b))))) > MAX_AXIS_TILT_DEG:
        return False
    fit = s * 2.0 * math.sin(turn / 2.0)
    return DISTANCE_FIT[0] <= fit <= DISTANCE_FIT[1]

"""Where a capture's cameras stand round its object, and photos chosen as users take them.

A user walks round the object and takes 6 to 10 photos, 30 to 60 degrees apart. A capture
made for photogrammetry has tens or hundreds of frames a few degrees apart; its reference
cameras (COLMAP over all of them) say where each frame stands. Here: the object's centre
(the point nearest every optical axis), the vertical (the normal of the ring of camera
centres), each frame's azimuth and elevation about them, the angle between two photos as
seen from the object, the walk chosen from the frames (``choose_walk``), and a photo pair's
relative rotation scored against the reference (``score_pairs``).

Cameras are OpenCV camera-to-world 4x4 matrices (x right, y down, z forward).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cadnerf_core.cameras import rotation_angle_deg


@dataclass(frozen=True)
class WalkSpec:
    """What a walk at the users' spacing is."""

    low_deg: float = 30.0
    """Smallest angle between neighbouring photos."""
    high_deg: float = 60.0
    """Largest angle between neighbouring photos."""
    target_deg: float = 45.0
    """The spacing a walk aims for: a full ring gets ``360 / target_deg`` photos."""
    fewest: int = 3
    """Fewest photos of a walk (the product takes 3 to 10)."""
    most: int = 10
    """Most photos of a walk."""
    band_deg: float = 15.0
    """Frames whose elevation is further than this from the median are left out where enough
    frames remain (a user walks at one height)."""


RING_FLATNESS = 0.6
"""Camera centres spread over a ring when their smallest spread is under this share of the
next (``up_axis``)."""
RING_STEEPEST_DEG = 60.0
"""...and when the cameras look at most this far from the ring's plane (median): an arc of
photos facing the object is a plane too, but the cameras look along its normal."""

USERS = WalkSpec()
"""The users' spacing (issue: a walk round the object, 6-10 photos, 30-60 degrees apart)."""


def object_centre(c2w: np.ndarray) -> np.ndarray:
    """The point nearest every camera's optical axis (least squares). c2w [N, 4, 4] -> [3]."""
    centres, axes = c2w[:, :3, 3], c2w[:, :3, 2]
    projector = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]  # [N, 3, 3]
    A = projector.sum(axis=0)
    b = np.einsum("nij,nj->i", projector, centres)
    return np.asarray(np.linalg.lstsq(A, b, rcond=None)[0])


def up_axis(c2w: np.ndarray) -> np.ndarray:
    """The capture's vertical [3]: the normal of the plane of the camera centres where they
    spread over a ring (its smallest spread under ``RING_FLATNESS`` of the next, and the
    cameras looking across it rather than along it), turned toward the cameras' mean up (-y)
    or, where that mean is no guide (photos taken sideways), toward the side most cameras
    stand on (a camera looks down on an object on a table); the cameras' mean up itself
    elsewhere (an arc facing the object, or centres at many heights)."""
    mean_up = -c2w[:, :3, 1].mean(axis=0)
    mean_up /= max(float(np.linalg.norm(mean_up)), 1e-12)
    centres = c2w[:, :3, 3]
    if len(centres) < 3:
        return np.asarray(mean_up)
    spread_from = centres - centres.mean(axis=0)
    _, spread, vt = np.linalg.svd(spread_from)
    normal = vt[2]
    along = float(np.median(np.abs(c2w[:, :3, 2] @ normal)))
    if spread[2] >= RING_FLATNESS * spread[1] or along > np.sin(np.radians(RING_STEEPEST_DEG)):
        return np.asarray(mean_up)
    agreement = float(normal @ mean_up)
    if abs(agreement) > 0.3:
        return np.asarray(normal * np.sign(agreement))
    heights = (centres - object_centre(c2w)) @ normal
    return np.asarray(normal if np.median(heights) >= 0 else -normal)


def ring_angles(c2w: np.ndarray, centre: np.ndarray,
                up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each camera's azimuth (degrees, counter-clockwise seen from above, in [0, 360)) and
    elevation (degrees above the centre's horizontal plane). c2w [N, 4, 4] -> ([N], [N])."""
    up = up / np.linalg.norm(up)
    seed = np.eye(3)[int(np.argmin(np.abs(up)))]
    x = np.cross(up, seed)
    x /= np.linalg.norm(x)
    y = np.cross(up, x)
    offsets = c2w[:, :3, 3] - centre
    height = offsets @ up
    flat = np.hypot(offsets @ x, offsets @ y)
    azimuth = np.degrees(np.arctan2(offsets @ y, offsets @ x)) % 360.0
    return azimuth, np.degrees(np.arctan2(height, flat))


def rays_from(c2w: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Unit vectors from the object's centre [3] to each camera. c2w [N, 4, 4] -> [N, 3]."""
    rays = c2w[:, :3, 3] - centre
    return np.asarray(rays / np.linalg.norm(rays, axis=1, keepdims=True))


def view_angles(c2w: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The angle (degrees) at the object's centre between each photo and the next in the
    order given (not round the loop). c2w [N, 4, 4] -> [N - 1]."""
    rays = rays_from(c2w, centre)
    cos = np.clip(np.sum(rays[:-1] * rays[1:], axis=1), -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def spacing_deg(c2w: np.ndarray) -> float:
    """A walk's spacing: the median angle between neighbouring photos, seen from the object's
    centre (``object_centre``). c2w [N, 4, 4], N >= 2."""
    return float(np.median(view_angles(c2w, object_centre(c2w))))


def _steps(positions: np.ndarray, rays: np.ndarray | None) -> np.ndarray:
    """Angles (degrees) from every frame to every later one by azimuth [M, M] (inf where not
    later): the view angle between their rays from the object where ``rays`` [M, 3] (unit)
    are given, else the azimuth difference."""
    later = positions[None, :] - positions[:, None] > 0
    if rays is None:
        angles = positions[None, :] - positions[:, None]
    else:
        angles = np.degrees(np.arccos(np.clip(rays @ rays.T, -1.0, 1.0)))
    return np.where(later, angles, np.inf)


def _best_chain(positions: np.ndarray, penalty: np.ndarray, count: int, spec: WalkSpec,
                even: float, first: int | None = None, closing: float | None = None,
                rays: np.ndarray | None = None) -> tuple[float, list[int]] | None:
    """The cheapest chain of ``count`` increasing azimuths ``positions`` whose steps lie within
    the spec (``_steps``), starting at ``first`` if given, and, where ``closing`` (the full
    turn) is given, whose step from its last back round to its first lies within it too.
    Cost: each azimuth step's squared distance from ``even`` (degrees), plus ``penalty`` per
    frame."""
    gaps = _steps(positions, rays)
    azimuth_steps = positions[None, :] - positions[:, None]
    step = np.where((gaps >= spec.low_deg) & (gaps <= spec.high_deg),
                    (azimuth_steps - even) ** 2, np.inf)
    cost = penalty.copy() if first is None else np.where(
        np.arange(len(positions)) == first, penalty, np.inf)
    back = []
    for _ in range(count - 1):
        total = cost[:, None] + step + penalty[None, :]  # [from, to]
        back.append(np.argmin(total, axis=0))
        cost = np.min(total, axis=0)
    if closing is not None and first is not None:
        wrap = closing - (positions - positions[first])
        angle = wrap if rays is None else np.degrees(
            np.arccos(np.clip(rays @ rays[first], -1.0, 1.0)))
        ok = (angle >= spec.low_deg) & (angle <= spec.high_deg)
        cost = np.where(ok, cost + (wrap - even) ** 2, np.inf)
    end = int(np.argmin(cost))
    if not np.isfinite(cost[end]):
        return None
    chain = [end]
    for pointers in reversed(back):
        chain.append(int(pointers[chain[-1]]))
    return float(cost[end]), chain[::-1]


def _counts(span: float, ring: bool, spec: WalkSpec) -> list[int]:
    """Photo counts to try, nearest the target spacing's first."""
    aim = round(span / spec.target_deg) + (0 if ring else 1)
    counts = range(spec.fewest, spec.most + 1)
    return sorted(counts, key=lambda n: (abs(n - aim), -n))


def choose_walk(azimuth: np.ndarray, elevation: np.ndarray, spec: WalkSpec = USERS,
                rays: np.ndarray | None = None, bins_deg: float = 3.0) -> list[int]:
    """The frames of a walk at ``spec``'s spacing, in walking order.

    A full ring (no gap over ``spec.high_deg``) gets about ``360 / target_deg`` photos, an arc
    about ``span / target_deg + 1``; every neighbouring pair (and, on a ring, the last and
    the first) lies ``low_deg`` to ``high_deg`` apart (the angle between them seen from the
    object where ``rays`` are given, else their azimuths' difference), their azimuths as
    evenly spread as the frames allow, at elevations near the median. The walk goes the way
    the frames were taken (their index order) and, on a ring, starts at the earliest frame
    chosen.

    Args:
        azimuth, elevation: [N] degrees (``ring_angles``), frames in capture order.
        spec: the spacing.
        rays: [N, 3] unit vectors from the object's centre to each camera, or None.
        bins_deg: frames are thinned to the one nearest the median elevation per bin of this
            many degrees of azimuth first (the search is quadratic in the frames).
    Returns:
        Frame indices, walking order; empty when no walk of ``spec.fewest`` photos fits.
    """
    azimuth, elevation = np.asarray(azimuth, float) % 360.0, np.asarray(elevation, float)
    deviation = np.abs(elevation - np.median(elevation))
    pool = np.flatnonzero(deviation <= spec.band_deg)
    if len(pool) < spec.fewest:
        pool = np.arange(len(azimuth))
    keep: dict[int, int] = {}
    for k in pool:
        slot = int(azimuth[k] // bins_deg)
        if slot not in keep or deviation[k] < deviation[keep[slot]]:
            keep[slot] = int(k)
    frames = np.array(sorted(keep.values(), key=lambda k: azimuth[k]))
    positions = azimuth[frames]
    circular = np.diff(np.append(positions, positions[0] + 360.0))
    ring = bool(circular.max() <= spec.high_deg)
    if not ring:  # unroll the arc so it starts after its widest gap
        start = (int(np.argmax(circular)) + 1) % len(frames)
        frames = np.roll(frames, -start)
        positions = (azimuth[frames] - azimuth[frames[0]]) % 360.0
    penalty = deviation[frames] ** 2  # a degree off the median height weighs as one of azimuth
    span = 360.0 if ring else float(positions[-1] - positions[0])
    for count in _counts(span, ring, spec):
        found = _search(positions, penalty, count, spec, ring,
                        None if rays is None else np.asarray(rays, float)[frames])
        if found is not None:
            return _walking_order([int(frames[k]) for k in found], ring)
    return []


def _search(positions: np.ndarray, penalty: np.ndarray, count: int, spec: WalkSpec,
            ring: bool, rays: np.ndarray | None) -> list[int] | None:
    """The cheapest chain of ``count`` (``_best_chain``): on a ring, over every first frame."""
    if not ring:
        even = float(positions[-1] - positions[0]) / max(count - 1, 1)
        best = _best_chain(positions, penalty, count, spec, even, rays=rays)
        return None if best is None else best[1]
    found: tuple[float, list[int]] | None = None
    for first in range(len(positions)):
        rolled = np.roll(np.arange(len(positions)), -first)
        unrolled = (positions[rolled] - positions[first]) % 360.0
        best = _best_chain(unrolled, penalty[rolled], count, spec, 360.0 / count, 0, 360.0,
                           None if rays is None else rays[rolled])
        if best is not None and (found is None or best[0] < found[0]):
            found = (best[0], [int(rolled[k]) for k in best[1]])
    return None if found is None else found[1]


def _walking_order(chain: list[int], ring: bool) -> list[int]:
    """``chain`` (by increasing azimuth) turned the way the frames were taken and, on a ring,
    started at its earliest frame."""
    if ring:
        first = chain.index(min(chain))
        chain = chain[first:] + chain[:first]
        ahead = sum(b > a for a, b in zip(chain[1:], chain[2:], strict=False))
        behind = sum(b < a for a, b in zip(chain[1:], chain[2:], strict=False))
        return chain[:1] + chain[1:][::-1] if behind > ahead else chain
    rising = sum(b > a for a, b in zip(chain, chain[1:], strict=False))
    return chain if 2 * rising >= len(chain) - 1 else chain[::-1]


def relative_rotation(c2w_i: np.ndarray, c2w_j: np.ndarray) -> np.ndarray:
    """Camera i's axes to camera j's (``x_j = R @ x_i + t``) from two c2w [4, 4]. -> [3, 3]."""
    return np.asarray(c2w_j[:3, :3].T @ c2w_i[:3, :3])


@dataclass(frozen=True)
class PairScore:
    """Photo pairs with a rotation from their matches, against the reference cameras."""

    right: int
    """Pairs whose rotation is within the tolerance of the reference's."""
    wrong: int
    """The others."""
    errors_deg: tuple[float, ...]
    """Each pair's rotation error, in the order given."""


def score_pairs(pairs: Sequence[tuple[int, int, np.ndarray]], c2w: np.ndarray,
                tolerance_deg: float = 10.0) -> PairScore:
    """Score the pairs' relative rotations against the reference.

    Args:
        pairs: (i, j, R [3, 3]): photos i and j (as given) and the rotation from camera i's
            axes to camera j's that their matches gave.
        c2w: [N, 4, 4] the reference cameras of the photos as given.
        tolerance_deg: largest error of a pair counted right.
    Returns:
        The score.
    """
    errors = [float(rotation_angle_deg(np.asarray(R).T @ relative_rotation(c2w[i], c2w[j])))
              for i, j, R in pairs]
    right = sum(e <= tolerance_deg for e in errors)
    return PairScore(right, len(errors) - right, tuple(errors))

"""Which way round the photos walk, from their texture.

Silhouettes cannot tell the walking direction of an object whose silhouette is (nearly) the
same from every side, such as a bottle, a mug or a lamp: walking round it either way gives the
same masks, and the pose solver picks a direction by noise. Its texture can (compared by
chromaticity, so that shading that stays with the camera, as a flash's or our renderer's
light does, is not mistaken for it). Between two
consecutive photos the surface turns by about one walking step, and which way it turns gives
the direction.

The test, per consecutive pair (i, i + 1) of canonical crops: model the object as a body of
revolution about the image's vertical axis, each row a circle whose radius is the row's mask
half-width (exact for bottles and mugs, rough for the rest). A pixel of photo i + 1 at
normalised column ``u = sin(theta)`` shows the surface point at angle ``theta``; if the walk
turned by ``delta``, photo i showed that point at ``theta + s * delta``. Warping photo i both
ways (s = +1 and -1, for a few step sizes around ``360 / n``) and correlating each warp with
photo i + 1 (normalised cross-correlation over pixels visible in both) scores the two
directions; the evidence is the sum over pairs of the score difference. Photos whose rows do
not line up (very different elevations) or have no texture give differences near zero.

Sign: with the library's azimuth convention, a walk with increasing azimuth (solver direction
+1) turns the surface toward s = +1 here (checked on rendered walks in
``tests/core/test_direction.py``).
"""

from __future__ import annotations

import cv2
import numpy as np

STEP_FACTORS = (0.6, 1.0, 1.4)
"""Step sizes tried, as multiples of ``360 / n`` (a walk's steps are rarely even)."""
MAX_ANGLE_DEG = 75.0
"""Surface points seen more obliquely than this (near the silhouette's edge) are not used."""
MIN_PIXELS = 50
"""Fewest pixels visible in both photos for a pair to count."""


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    """Colour without its brightness: ``rgb / (r + g + b)``. Shading by white light scales the
    three channels alike, so it cancels; a surface's colour pattern stays.

    Args:
        rgb: [S, S, 3] float in [0, 1].
    Returns:
        [S, S, 3] float32, each pixel summing to 1 (grey where the pixel is black).
    """
    total = rgb.sum(axis=-1, keepdims=True)
    out = np.where(total > 1e-3, rgb / np.maximum(total, 1e-3), 1.0 / 3.0)
    return out.astype(np.float32)


def _row_extents(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: whether it holds the object, its centre column and half-width (pixels)."""
    width = mask.shape[1]
    has = np.asarray(mask.any(axis=1), dtype=bool)
    left = mask.argmax(axis=1).astype(np.float64)
    right = width - mask[:, ::-1].argmax(axis=1).astype(np.float64)
    return has, (left + right) / 2.0, np.maximum((right - left) / 2.0, 1.0)


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised cross-correlation of two [N, C] pixel sets."""
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    denom = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / denom) if denom > 1e-9 else 0.0


def turn_score(rgb_a: np.ndarray, mask_a: np.ndarray, rgb_b: np.ndarray, mask_b: np.ndarray,
               turn_deg: float) -> float | None:
    """How well photo b is photo a with its surface turned by ``turn_deg`` (body of revolution).

    Args:
        rgb_a, rgb_b: [S, S, 3] float canonical crops; mask_a, mask_b: [S, S] bool.
        turn_deg: the turn, signed (see the module docstring).
    Returns:
        Normalised cross-correlation in [-1, 1], or None when too few pixels are seen by both.
    """
    size_y, size_x = mask_b.shape
    has_a, centre_a, half_a = _row_extents(mask_a)
    _, centre_b, half_b = _row_extents(mask_b)
    ys, xs = np.mgrid[0:size_y, 0:size_x].astype(np.float64)
    u = np.clip((xs + 0.5 - centre_b[:, None]) / half_b[:, None], -1.0, 1.0)
    theta_b = np.arcsin(u)
    theta_a = theta_b + np.radians(turn_deg)
    limit = np.radians(MAX_ANGLE_DEG)
    ok = mask_b & has_a[:, None] & (np.abs(theta_b) < limit) & (np.abs(theta_a) < limit)
    map_x = (centre_a[:, None] + half_a[:, None] * np.sin(theta_a) - 0.5).astype(np.float32)
    map_y = ys.astype(np.float32)
    warped = cv2.remap(rgb_a.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR)
    seen = cv2.remap(mask_a.astype(np.uint8), map_x, map_y, cv2.INTER_NEAREST) > 0
    ok &= seen
    if int(ok.sum()) < MIN_PIXELS:
        return None
    return _ncc(warped[ok].reshape(-1, 3), rgb_b[ok].reshape(-1, 3))


def walk_direction_evidence(rgb: np.ndarray, masks: np.ndarray) -> float:
    """Texture evidence for the walking direction of photos in order.

    Args:
        rgb: [N, S, S, 3] float canonical crops of the photos, in walking order.
        masks: [N, S, S] bool, their masks.
    Returns:
        Evidence e: > 0 favours azimuth increasing along the photos (solver direction +1),
        < 0 decreasing; the sum over consecutive pairs of the difference between the best
        correlations of the two turning directions (each in [-2, 2]). 0 for fewer than 2
        photos or no usable pair.
    """
    n = len(rgb)
    if n < 2:
        return 0.0
    colour = [chromaticity(rgb[i]) for i in range(n)]
    step = 360.0 / n
    evidence = 0.0
    for i in range(n - 1):
        best: dict[int, float] = {}
        for sign in (1, -1):
            scores = [turn_score(colour[i], masks[i], colour[i + 1], masks[i + 1],
                                 sign * factor * step) for factor in STEP_FACTORS]
            found = [s for s in scores if s is not None]
            if found:
                best[sign] = max(found)
        if len(best) == 2:
            evidence += best[1] - best[-1]
    return evidence

"""The photos' shared points as a loss on the cameras: the Sampson epipolar error.

Retrieval's matches (``retrieval.matches``) are points two photos see of the same spot on
the object. Two cameras explain a match when the point in one photo lies on the epipolar line
the other photo's point draws through it. The Sampson error is the first-order distance (in
pixels) of a match from satisfying that; unlike a reprojection through rendered depth (SPARF),
it needs no rendering and reads only the poses and the shared focal length, so it costs
microseconds a step and no memory. Silhouettes pin elevation and scale but cannot tell
azimuth on objects that look alike from several sides; where the object has texture, the
matches can.

Each match weighs as much as its pair's other matches share; a pair weighs
``min(1, inliers / (2 * min_inliers))`` (few matches count less), and pairs under
``min_inliers`` are left out: a texture-less object has no term and trains exactly as without.
The error is robust (pseudo-Huber, ``HUBER_PX`` pixels of the training crops), so a wrong match
pulls no harder than a small residual.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from cadnerf_core.cameras.conventions import rotation_angle_deg, skew
from cadnerf_core.cameras.matches import PairMatch
from cadnerf_core.intake.crop import CropBox

log = logging.getLogger(__name__)

HUBER_PX = 1.0
"""Scale of the pseudo-Huber penalty in training-crop pixels: quadratic below, linear above."""
PRIOR_DEG = 30.0
"""Most a pair's relative rotation (from its essential matrix) may differ from that of the
cameras training starts from. A pair further off is mostly a whole set of consistent wrong
matches (the mirrored side of a symmetric object, a repeated print), which a robust loss
cannot reject, since its matches agree with each other."""


@dataclass(frozen=True)
class MatchTerms:
    """The matches between the training photos, in their crops' pixels.

    ``a``, ``b`` [M] long: the training cameras of each match; ``x_a``, ``x_b`` [M, 2]: the
    pixel in each crop; ``weight`` [M]: the match's share of the loss (a pair's matches share
    its weight, ``min(1, inliers / (2 * min_inliers))``, equally)."""

    a: torch.Tensor
    b: torch.Tensor
    x_a: torch.Tensor
    x_b: torch.Tensor
    weight: torch.Tensor

    @property
    def n_matches(self) -> int:
        """Number of matches."""
        return int(self.a.shape[0])


def match_terms(pairs: Sequence[PairMatch], photo_index: Sequence[int],
                boxes: Sequence[CropBox], min_inliers: int, device: torch.device,
                c2w: np.ndarray | None = None) -> MatchTerms | None:
    """The matches of the training photos as ``MatchTerms``, or None when no pair has enough.

    Args:
        pairs: the photos' verified matches (photos numbered as given, points in photo pixels).
        photo_index: [N] the photo each training camera shows (its index as given).
        boxes: N crop boxes, photo pixels -> each training crop's pixels.
        min_inliers: fewest inliers a pair needs to count.
        device: where the tensors live.
        c2w: [N, 4, 4] the cameras training starts from: a pair whose relative rotation
            differs from theirs by over ``PRIOR_DEG`` is left out (None: none is).
    """
    camera = {photo: k for k, photo in enumerate(photo_index)}
    a, b, x_a, x_b, weight = [], [], [], [], []
    enough, disagree = 0, []
    for pair in pairs:
        if pair.i not in camera or pair.j not in camera or pair.inliers < min_inliers:
            continue
        enough += 1
        i, j = camera[pair.i], camera[pair.j]
        if c2w is not None:
            off = disagreement_deg(pair, c2w[i], c2w[j])
            if off > PRIOR_DEG:
                disagree.append(f"{pair.i}-{pair.j} {off:.0f} deg")
                continue
        points = np.asarray(pair.points, dtype=np.float64)
        count = len(points)
        a.append(np.full(count, i))
        b.append(np.full(count, j))
        x_a.append(_to_crop(points[:, 0], boxes[i]))
        x_b.append(_to_crop(points[:, 1], boxes[j]))
        weight.append(np.full(count, min(1.0, pair.inliers / (2.0 * min_inliers)) / count))
    if enough:
        log.info("epipolar loss: %d matches, from %d of %d matched pairs%s",
                 sum(len(part) for part in a), len(a), enough,
                 f"; left out, turn unlike the starting cameras': {', '.join(disagree)}"
                 if disagree else "")
    if not a:
        return None

    def tensor(parts: list[np.ndarray], dtype: torch.dtype) -> torch.Tensor:
        return torch.from_numpy(np.concatenate(parts)).to(device=device, dtype=dtype)

    return MatchTerms(tensor(a, torch.long), tensor(b, torch.long), tensor(x_a, torch.float32),
                      tensor(x_b, torch.float32), tensor(weight, torch.float32))


def disagreement_deg(pair: PairMatch, c2w_i: np.ndarray, c2w_j: np.ndarray) -> float:
    """Angle (degrees) between a pair's measured relative rotation (camera i to camera j) and
    that of two camera poses; 180 when the pair has none."""
    if pair.rotation is None:
        return 180.0
    posed = np.asarray(c2w_j)[:3, :3].T @ np.asarray(c2w_i)[:3, :3]
    return float(rotation_angle_deg(np.asarray(pair.rotation).T @ posed))


def _to_crop(points: np.ndarray, box: CropBox) -> np.ndarray:
    """Photo pixels [K, 2] (pixel centres at integers) -> crop coordinates [K, 2] in
    the intrinsics' convention (pixel centres at +0.5, ``rays.pixel_rays``)."""
    return (points + 0.5 - np.array([box.x0, box.y0])) * box.scale


def fundamental(c2w_a: torch.Tensor, c2w_b: torch.Tensor, K_a: torch.Tensor,
                K_b: torch.Tensor) -> torch.Tensor:
    """Fundamental matrices of camera pairs (OpenCV axes), ``x_b^T F x_a = 0``.

    Args:
        c2w_a, c2w_b: [M, 4, 4] camera-to-world poses; K_a, K_b: [M, 3, 3] intrinsics.
    Returns:
        F: [M, 3, 3].
    """
    R_a, R_b = c2w_a[:, :3, :3], c2w_b[:, :3, :3]
    # Camera a's frame to camera b's: x_b = R x_a + t.
    R = R_b.transpose(1, 2) @ R_a
    t = (R_b.transpose(1, 2) @ (c2w_a[:, :3, 3] - c2w_b[:, :3, 3])[..., None])[..., 0]
    E = skew(t) @ R
    return torch.linalg.inv(K_b).transpose(1, 2) @ E @ torch.linalg.inv(K_a)


def sampson_px(F: torch.Tensor, x_a: torch.Tensor, x_b: torch.Tensor) -> torch.Tensor:
    """Sampson distance in pixels of matches under fundamental matrices.

    Args:
        F: [M, 3, 3]; x_a, x_b: [M, 2] pixels.
    Returns:
        [M] distances (the square root of the Sampson error).
    """
    ones = torch.ones_like(x_a[:, :1])
    h_a = torch.cat([x_a, ones], -1)[..., None]
    h_b = torch.cat([x_b, ones], -1)[..., None]
    Fx_a = (F @ h_a)[..., 0]
    Ftx_b = (F.transpose(1, 2) @ h_b)[..., 0]
    algebraic = (h_b[..., 0] * Fx_a).sum(-1)
    norm = Fx_a[:, 0] ** 2 + Fx_a[:, 1] ** 2 + Ftx_b[:, 0] ** 2 + Ftx_b[:, 1] ** 2
    return algebraic.abs() / torch.sqrt(norm + 1e-12)


def epipolar_loss(c2w: torch.Tensor, K: torch.Tensor, terms: MatchTerms) -> torch.Tensor:
    """The matches' robust Sampson distance (pseudo-Huber, ``HUBER_PX``), weighted, per
    camera.

    Args:
        c2w: [N, 4, 4] the training cameras' current poses; K: [N, 3, 3] their intrinsics.
        terms: the matches (``match_terms``).
    Returns:
        [] the weighted sum over matches, over the number of cameras.
    """
    F = fundamental(c2w[terms.a], c2w[terms.b], K[terms.a], K[terms.b])
    distance = sampson_px(F, terms.x_a, terms.x_b)
    penalty = HUBER_PX**2 * (torch.sqrt(1.0 + (distance / HUBER_PX) ** 2) - 1.0)
    return (terms.weight * penalty).sum() / c2w.shape[0]


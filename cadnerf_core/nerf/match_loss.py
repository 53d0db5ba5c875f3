"""The photos' matches as a loss on the poses, inside a phase's pose window.

Two forms (``Phase2Config.matches_loss``), both robust (pseudo-Huber, ``epipolar.HUBER_PX``)
and weighted per pair as ``epipolar.match_terms`` says:

- ``epipolar``: the Sampson distance of each match under the two cameras. Free of the shape,
  but on an object far from the camera (a near-affine view) a turn about the object moves
  points mostly along their epipolar lines, so it pins azimuth only weakly.
- ``reprojection``: each match's point in one photo lifted onto the NeRF's surface (its
  rendered depth, held fixed and re-rendered every ``REFRESH`` steps) and projected into the
  other photo, both ways (SPARF's multi-view correspondence loss). The shape fixes the depth,
  so a turn moves the projected point by the full parallax. Matches whose rays miss the
  object (rendered opacity under ``HIT``) are left out until the next refresh.
"""

from __future__ import annotations

import torch

from cadnerf_core.nerf.epipolar import (
    HUBER_PX,
    MatchTerms,
    epipolar_loss,
    rays_through,
    reprojection_px,
)
from cadnerf_core.nerf.state import TrainData, TrainState
from cadnerf_core.nerf.volrend import ray_sphere, render_rays

REFRESH = 20
"""Steps between two renders of the matches' depths (``reprojection``)."""
HIT = 0.9
"""Rendered opacity from which a match's ray counts as on the object (its depth then mostly
the surface's, not the far bound's)."""


def _robust(distance: torch.Tensor) -> torch.Tensor:
    return HUBER_PX**2 * (torch.sqrt(1.0 + (distance / HUBER_PX) ** 2) - 1.0)


class MatchLoss:
    """The matches' loss of one phase: ``weight`` times the robust distance, per camera."""

    def __init__(self, data: TrainData, weight: float, form: str) -> None:
        """Args: data: the training photos (``data.matches``: None gives no loss);
        weight: the loss's weight (0: none); form: "epipolar" or "reprojection"."""
        self.terms: MatchTerms | None = data.matches if weight > 0 else None
        self.weight = weight
        self.form = form
        self._depths: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        self._age = 0

    def __call__(self, state: TrainState, data: TrainData) -> torch.Tensor | None:
        """The loss at the current poses (None without matches or weight)."""
        terms = self.terms
        if terms is None:
            return None
        c2w = state.poses()
        K = state.poses.intrinsics(data.K)
        if self.form == "epipolar":
            return self.weight * epipolar_loss(c2w, K, terms)
        if self._depths is None or self._age >= REFRESH:
            self._depths = self._render(state, c2w.detach(), K.detach(), terms)
            self._age = 0
        self._age += 1
        depth_a, depth_b, valid = self._depths
        if not bool(valid.any()):
            return None
        a, b = terms.a[valid], terms.b[valid]
        forward = reprojection_px(c2w[a], c2w[b], K[a], K[b], terms.x_a[valid],
                                  terms.x_b[valid], depth_a[valid])
        backward = reprojection_px(c2w[b], c2w[a], K[b], K[a], terms.x_b[valid],
                                   terms.x_a[valid], depth_b[valid])
        penalty = 0.5 * (_robust(forward) + _robust(backward))
        return self.weight * (terms.weight[valid] * penalty).sum() / c2w.shape[0]

    @staticmethod
    def _render(state: TrainState, c2w: torch.Tensor, K: torch.Tensor,
                terms: MatchTerms) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Depths along the rays of both ends of every match, and where both hit the object."""
        rcfg = state.config.render
        depths, hits = [], []
        with torch.no_grad():
            for cam, uv in ((terms.a, terms.x_a), (terms.b, terms.x_b)):
                origin, direction = rays_through(c2w[cam], K[cam], uv)
                out = render_rays(lambda p, d: state.fields.query(p, None), origin, direction,
                                  rcfg.samples_per_ray, rcfg.bound,
                                  state.grid if rcfg.use_grid else None, False, False)
                # ``depth`` counts the missing opacity at the far bound: the surface's alone.
                _, far, _ = ray_sphere(origin, direction, rcfg.bound)
                acc = out.acc.clamp(min=1e-6)
                depths.append((out.depth - (1.0 - out.acc) * far) / acc)
                hits.append(out.acc > HIT)
        return depths[0], depths[1], hits[0] & hits[1]

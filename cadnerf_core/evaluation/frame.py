"""The ground truth's frame and the NeRF's: similarities between camera sets, and the mapping
of ground-truth cameras into a trained NeRF's frame (by camera centres, then photometrically).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cadnerf_core.cameras.conventions import umeyama
from cadnerf_core.evaluation.dataset import Dataset
from cadnerf_core.evaluation.jobio import JobCameras, eval_intrinsics

if TYPE_CHECKING:
    from cadnerf_core.nerf.model import TrainedModel

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Similarity:
    """x -> scale * R @ x + t."""

    scale: float
    R: np.ndarray  # [3, 3]
    t: np.ndarray  # [3]

    def apply_to_poses(self, c2w: np.ndarray) -> np.ndarray:
        """Move camera-to-world poses [N, 4, 4]; orientations rotate, centres move.

        Returns:
            [N, 4, 4] float64 (the scale acts on positions only).
        """
        out = np.array(c2w, dtype=np.float64, copy=True)
        out[:, :3, :3] = self.R @ out[:, :3, :3]
        out[:, :3, 3] = self.scale * out[:, :3, 3] @ self.R.T + self.t
        return out

    def then(self, scale: float, R: np.ndarray, t: np.ndarray) -> Similarity:
        """This similarity followed by ``x -> R @ (scale * x) + t``."""
        R = np.asarray(R, dtype=np.float64)
        return Similarity(scale * self.scale, R @ self.R,
                          scale * R @ self.t + np.asarray(t, dtype=np.float64))


MEETING_MIN = 1e-3
"""Least eigenvalue (per camera) of the optical axes' normal equations below which they are
taken as parallel (``object_centre``): axes within about 2 degrees of each other."""


def object_centre(c2w: np.ndarray) -> np.ndarray:
    """The point nearest every camera's optical axis, in least squares: where cameras that
    each frame the object look, so its centre (a synthetic walk's origin, a capture's
    object in a world of its own). The cameras' mean centre where the axes are parallel.

    Args:
        c2w: [N, 4, 4] OpenCV camera-to-world poses.
    Returns:
        [3] float64.
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    axes = c2w[:, :3, 2] / np.linalg.norm(c2w[:, :3, 2], axis=1, keepdims=True)
    across = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]  # [N, 3, 3] projectors
    A = across.sum(0)
    if np.linalg.eigvalsh(A)[0] < MEETING_MIN * len(c2w):
        return c2w[:, :3, 3].mean(0)
    return np.linalg.solve(A, np.einsum("nij,nj->i", across, c2w[:, :3, 3]))


def centre_similarity(c2w_src: np.ndarray, c2w_dst: np.ndarray,
                      fix_origin: bool = False,
                      src_centre: np.ndarray | None = None) -> Similarity:
    """The similarity that best maps the source camera centres onto the destination's.

    Args:
        c2w_src, c2w_dst: [N, 4, 4] corresponding cameras (N >= 3 for a unique rotation).
        fix_origin: map ``src_centre`` onto the origin: the best rotation about it, and the
            scale that matches the cameras' RMS distances from the two. The NeRF's frame
            holds the object centred at its origin, so this keeps the object centred and in
            view when the cameras are uncertain (a free translation absorbs pose errors as
            an offset).
        src_centre: [3] the object's centre in the source frame (``object_centre``); None:
            the origin (a synthetic walk's frame, centred as ours).
    Returns:
        Similarity with ``dst_centre ~ scale * R @ src_centre + t`` (Umeyama, least squares).
    """
    src = np.asarray(c2w_src, dtype=np.float64)[:, :3, 3]
    dst = np.asarray(c2w_dst, dtype=np.float64)[:, :3, 3]
    if not fix_origin:
        scale, R, t = umeyama(src, dst)
        return Similarity(scale, R, t)
    centre = np.zeros(3) if src_centre is None else np.asarray(src_centre, dtype=np.float64)
    src = src - centre
    U, _, Vt = np.linalg.svd(dst.T @ src)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    # Scale from the cameras' distances alone: a poor rotation fit must not pull the
    # cameras into the object (the least-squares scale shrinks with the fit).
    norm = float((src**2).sum())
    scale = math.sqrt(float((dst**2).sum()) / norm) if norm > 0 else 1.0
    return Similarity(scale, R, -scale * R @ centre)


FRAME_FIT_STEPS = 200
"""Adam steps of ``fit_frame`` (at 2e-3: 100 and 400 steps move the score by <= 0.07 dB on
the training benchmark's two meshes)."""
FRAME_FIT_RAYS = 2048
"""Rays per ``fit_frame`` step, drawn from all training photos."""


def fit_frame(model: TrainedModel, start: Similarity, c2w_gt: np.ndarray, K: np.ndarray,
              images: np.ndarray, steps: int = FRAME_FIT_STEPS, rays: int = FRAME_FIT_RAYS,
              seed: int = 0) -> Similarity:
    """Refine the ground-truth-to-NeRF similarity on the training photos' pixels.

    A pose-free NeRF's frame is known only through its training photos. Fitting the mapping on
    six camera centres (``centre_similarity``) leaves it off by the cameras' residual errors
    and assumes the reconstruction is centred where the CAD model was; here one correction
    shared by every camera (a rotation, a translation and a scale of the positions, 7 numbers)
    is fitted so that the NeRF, seen from the mapped ground-truth training cameras, reproduces
    the training photos. Held-out images play no part (unlike BARF's test-time pose
    refinement, which fits 6 numbers per held-out view on that view).

    Args:
        model: the trained model (its fields are frozen here).
        start: the initial mapping (``centre_similarity``).
        c2w_gt: [N, 4, 4] ground-truth training cameras of the kept photos.
        K: [N, 3, 3] their intrinsics (the NeRF's focal length).
        images: [N, H, W, 3] float in [0, 1], the photos composited on white.
        steps, rays: Adam steps (lr 2e-3) and rays per step; seed: the rays drawn.
    Returns:
        The refined Similarity (``start`` when ``steps`` is 0, or when no ray of the mapped
        cameras meets the field: their loss has no gradient).
    """
    import torch

    from cadnerf_core.cameras.conventions import se3_exp
    from cadnerf_core.nerf.rays import pixel_rays
    from cadnerf_core.nerf.volrend import render_rays

    if steps <= 0:
        return start
    st = model.state
    dev = st.device
    c2w = torch.as_tensor(start.apply_to_poses(c2w_gt), dtype=torch.float32, device=dev)
    Ks = torch.as_tensor(np.asarray(K), dtype=torch.float32, device=dev)
    target = torch.as_tensor(np.asarray(images), dtype=torch.float32, device=dev)
    n, height, width = target.shape[:3]
    xi = torch.zeros(6, device=dev, requires_grad=True)  # world-frame SE(3), as PoseCorrection
    log_scale = torch.zeros(1, device=dev, requires_grad=True)  # of the camera positions
    optimizer = torch.optim.Adam([xi, log_scale], lr=2e-3)
    gen = torch.Generator().manual_seed(seed)
    rcfg = st.config.render
    was = [p.requires_grad for p in st.fields.parameters()]
    st.fields.requires_grad_(False)
    seen = 0  # steps with a gradient
    try:
        for _ in range(steps):
            cam = torch.randint(0, n, (rays,), generator=gen).to(dev)
            flat = torch.randint(0, height * width, (rays,), generator=gen).to(dev)
            x, y = flat % width, flat // width
            column = torch.cat([torch.exp(log_scale).expand(3), torch.ones(1, device=dev)])
            scaled = c2w * torch.cat([torch.ones(4, 3, device=dev), column[:, None]], dim=1)
            moved = se3_exp(xi[None]) @ scaled[cam]
            rays_o, rays_d = pixel_rays(moved, Ks[cam], x, y)
            out = render_rays(lambda p, d: st.fields.query(p, d), rays_o, rays_d,
                              rcfg.samples_per_ray, rcfg.bound, st.grid, True, False)
            assert out.rgb is not None
            loss = torch.nn.functional.mse_loss(out.rgb, target[cam, y, x])
            if not loss.requires_grad:  # no ray met the field: nothing to learn from here
                continue
            seen += 1
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    finally:
        for param, flag in zip(st.fields.parameters(), was, strict=True):
            param.requires_grad_(flag)
    if seen == 0:
        log.warning("frame fit: no ray of the mapped cameras meets the field; the centred "
                    "mapping is kept")
        return start
    with torch.no_grad():
        E = se3_exp(xi.detach()[None])[0].double().cpu().numpy()
        scale = float(torch.exp(log_scale.detach()).item())
    return start.then(scale, E[:3, :3], E[:3, 3])


def frame_mapping(model: TrainedModel, data: Dataset, cams: JobCameras, align: str,
                  intrinsics: str) -> Similarity:
    """The mapping of ground-truth cameras into the NeRF frame named by ``align``
    ("photometric", "centred" or "umeyama"; see ``evaluate_dataset``)."""
    gt_kept = data.c2w[cams.kept]
    if align not in ("photometric", "centred", "umeyama"):
        raise ValueError(f"align must be 'photometric', 'centred' or 'umeyama', not {align!r}")
    sim = centre_similarity(gt_kept, cams.refined, fix_origin=align != "umeyama",
                            src_centre=object_centre(gt_kept))
    if align != "photometric":
        return sim
    K = np.stack([eval_intrinsics(data.K[i], cams, intrinsics) for i in cams.kept])
    return fit_frame(model, sim, gt_kept, K, data.images[cams.kept])

"""The ground truth's frame and the NeRF's: similarities between camera sets, and the mapping
of ground-truth cameras into a trained NeRF's frame (by camera centres, then photometrically).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

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
SCORE_RAYS = 8192
"""Rays of the fixed set on which ``photo_loss`` compares mappings or poses (one draw per call
seed, the same for every candidate)."""
VIEW_STEPS = 200
"""Adam steps of ``refine_view`` (one held-out camera on its own photo)."""
VIEW_RAYS = 1024
"""Rays per ``refine_view`` step: half inside the object's mask, half anywhere."""
VIEW_LR = 5e-3
"""Adam's step size in ``refine_view`` (radians, and the NeRF's length unit), cosine-decayed
to a tenth (on a test ball, 4 degrees and 0.11 off: loss down 2000x in 150 steps, 2e-3 250x)."""


def _render_rgb(model: TrainedModel, c2w: Any, K: Any, x: Any, y: Any) -> Any:
    """Colour of pixels (x, y) [R] seen by cameras c2w [R, 4, 4] with K [R, 3, 3] (torch), on
    white, through the frozen model's fields (samples at bin centres)."""
    from cadnerf_core.nerf.rays import pixel_rays
    from cadnerf_core.nerf.volrend import render_rays

    st = model.state
    rays_o, rays_d = pixel_rays(c2w, K, x, y)
    out = render_rays(lambda p, d: st.fields.query(p, d), rays_o, rays_d,
                      st.config.render.samples_per_ray, st.config.render.bound, st.grid,
                      True, False)
    assert out.rgb is not None
    return out.rgb


def photo_loss(model: TrainedModel, c2w: np.ndarray, K: np.ndarray, images: np.ndarray,
               rays: int = SCORE_RAYS, seed: int = 0) -> float:
    """Mean squared error between the photos and the model seen from ``c2w``, on a fixed set of
    ``rays`` pixels drawn by ``seed`` (the same pixels for any cameras of the same photos):
    the score by which mappings and poses are compared.

    Args:
        c2w: [N, 4, 4] cameras in the NeRF's frame; K: [N, 3, 3]; images: [N, H, W, 3] on white.
    Returns:
        The loss (lower is better).
    """
    import torch

    dev = model.state.device
    n, height, width = np.asarray(images).shape[:3]
    gen = torch.Generator().manual_seed(seed)
    cam = torch.randint(0, n, (rays,), generator=gen)
    flat = torch.randint(0, height * width, (rays,), generator=gen)
    x, y = flat % width, flat // width
    target = torch.as_tensor(np.asarray(images)[cam.numpy(), y.numpy(), x.numpy()],
                             dtype=torch.float32, device=dev)
    c2w_t = torch.as_tensor(np.asarray(c2w), dtype=torch.float32, device=dev)[cam.to(dev)]
    K_t = torch.as_tensor(np.asarray(K), dtype=torch.float32, device=dev)[cam.to(dev)]
    total = 0.0
    with torch.no_grad():
        for lo in range(0, rays, FRAME_FIT_RAYS):
            part = slice(lo, lo + FRAME_FIT_RAYS)
            rgb = _render_rgb(model, c2w_t[part], K_t[part], x[part].to(dev), y[part].to(dev))
            total += float(((rgb - target[part]) ** 2).sum())
    return total / (rays * 3)


def fit_frame(model: TrainedModel, start: Similarity, c2w_gt: np.ndarray, K: np.ndarray,
              images: np.ndarray, steps: int = FRAME_FIT_STEPS, rays: int = FRAME_FIT_RAYS,
              seed: int = 0) -> Similarity:
    """Refine the ground-truth-to-NeRF similarity on the training photos' pixels.

    A pose-free NeRF's frame is known only through its training photos. Fitting the mapping on
    six camera centres (``centre_similarity``) leaves it off by the cameras' residual errors
    and assumes the reconstruction is centred where the CAD model was; here one correction
    shared by every camera (a rotation, a translation and a scale of the positions, 7 numbers)
    is fitted so that the NeRF, seen from the mapped ground-truth training cameras, reproduces
    the training photos. Held-out images play no part here (``refine_view`` then fits each
    held-out camera on its own photo, as BARF evaluates).

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
    seen = 0  # steps with a gradient
    with _frozen(model):
        for _ in range(steps):
            cam = torch.randint(0, n, (rays,), generator=gen).to(dev)
            flat = torch.randint(0, height * width, (rays,), generator=gen).to(dev)
            x, y = flat % width, flat // width
            column = torch.cat([torch.exp(log_scale).expand(3), torch.ones(1, device=dev)])
            scaled = c2w * torch.cat([torch.ones(4, 3, device=dev), column[:, None]], dim=1)
            moved = se3_exp(xi[None]) @ scaled[cam]
            rgb = _render_rgb(model, moved, Ks[cam], x, y)
            loss = torch.nn.functional.mse_loss(rgb, target[cam, y, x])
            if not loss.requires_grad:  # no ray met the field: nothing to learn from here
                continue
            seen += 1
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    if seen == 0:
        log.warning("frame fit: no ray of the mapped cameras meets the field; the start "
                    "mapping is kept")
        return start
    with torch.no_grad():
        E = se3_exp(xi.detach()[None])[0].double().cpu().numpy()
        scale = float(torch.exp(log_scale.detach()).item())
    return start.then(scale, E[:3, :3], E[:3, 3])


@contextmanager
def _frozen(model: TrainedModel) -> Iterator[None]:
    """The model's fields take no gradient inside; their flags are restored after."""
    fields = model.state.fields
    was = [p.requires_grad for p in fields.parameters()]
    fields.requires_grad_(False)
    try:
        yield
    finally:
        for param, flag in zip(fields.parameters(), was, strict=True):
            param.requires_grad_(flag)


def refine_view(model: TrainedModel, c2w: np.ndarray, K: np.ndarray, image: np.ndarray,
                mask: np.ndarray | None = None, steps: int = VIEW_STEPS, rays: int = VIEW_RAYS,
                seed: int = 0) -> np.ndarray:
    """Test-time pose refinement of one held-out camera on its own photo, as BARF and SPARF
    evaluate a pose-free NeRF: the fields frozen, 6 numbers (a rotation and a translation in
    the camera's frame) fitted so that the render matches the photo, so that a held-out
    view's score is about rendering rather than about where the mapping put its camera.

    Args:
        model: the trained model (frozen here).
        c2w: [4, 4] the camera in the NeRF's frame (the frame mapping's).
        K: [3, 3] its intrinsics at the photo's size.
        image: [H, W, 3] the held-out photo on white, at the size it is scored.
        mask: [H, W] bool, the object (half the rays are drawn on it); None: everywhere.
        steps, rays: Adam steps and rays per step; seed: the rays drawn.
    Returns:
        [4, 4] float64: the refined camera, or ``c2w`` itself where the refinement does not
        lower the loss on a fixed set of pixels (``photo_loss``) or no ray meets the field.
    """
    import torch

    from cadnerf_core.cameras.conventions import se3_exp

    c2w = np.asarray(c2w, dtype=np.float64)
    if steps <= 0:
        return c2w
    dev = model.state.device
    height, width = image.shape[:2]
    target = torch.as_tensor(np.asarray(image), dtype=torch.float32, device=dev)
    base = torch.as_tensor(c2w, dtype=torch.float32, device=dev)[None]
    K_t = torch.as_tensor(np.asarray(K), dtype=torch.float32, device=dev)[None].expand(rays,
                                                                                        3, 3)
    on = np.flatnonzero(mask.reshape(-1)) if mask is not None else np.zeros(0, dtype=np.int64)
    on_t = torch.as_tensor(on, dtype=torch.long)
    xi = torch.zeros(6, device=dev, requires_grad=True)  # camera-frame SE(3)
    optimizer = torch.optim.Adam([xi], lr=VIEW_LR)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, steps, VIEW_LR / 10)
    gen = torch.Generator().manual_seed(seed)
    n_on = rays // 2 if len(on) else 0
    with _frozen(model):
        for _ in range(steps):
            flat = torch.randint(0, height * width, (rays - n_on,), generator=gen)
            if n_on:
                flat = torch.cat([flat, on_t[torch.randint(0, len(on), (n_on,), generator=gen)]])
            x, y = (flat % width).to(dev), (flat // width).to(dev)
            moved = (base @ se3_exp(xi[None])).expand(rays, 4, 4)
            loss = torch.nn.functional.mse_loss(_render_rgb(model, moved, K_t, x, y),
                                                target[y, x])
            if loss.requires_grad:  # rays that meet the field
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                schedule.step()
    with torch.no_grad():
        refined = c2w @ se3_exp(xi.detach()[None])[0].double().cpu().numpy()
    before = photo_loss(model, c2w[None], K[None], image[None], seed=seed + 1)
    after = photo_loss(model, refined[None], K[None], image[None], seed=seed + 1)
    log.info("held-out view refined: loss %.5f -> %.5f", before, after)
    return refined if after < before else c2w


ALIGNS = ("photometric", "per-view", "centred", "umeyama")
"""The mappings of ground-truth cameras into a NeRF's frame (``evaluate_dataset``)."""


def frame_mapping(model: TrainedModel, data: Dataset, cams: JobCameras, align: str,
                  intrinsics: str) -> Similarity:
    """The mapping of ground-truth cameras into the NeRF frame named by ``align`` (one of
    ``ALIGNS``; see ``evaluate_dataset``).

    "photometric" fits the frame (``fit_frame``) from the centred similarity of the camera
    centres. "per-view" fits it from both the centred and the free (Umeyama) similarity and
    keeps the one whose kept photos the model then reproduces best (``photo_loss``): the
    centred start holds where the job's cameras are uncertain, the free one where they agree
    with the references but the object sits off the origin (each held-out camera is then
    refined on its own photo by the caller, ``refine_view``)."""
    gt_kept = data.c2w[cams.kept]
    if align not in ALIGNS:
        raise ValueError(f"align must be one of {', '.join(ALIGNS)}, not {align!r}")
    centred = centre_similarity(gt_kept, cams.refined, fix_origin=align != "umeyama",
                                src_centre=object_centre(gt_kept))
    if align in ("centred", "umeyama"):
        return centred
    K = np.stack([eval_intrinsics(data.K[i], cams, intrinsics) for i in cams.kept])
    images = data.images[cams.kept]
    if align == "photometric":
        return fit_frame(model, centred, gt_kept, K, images)
    best: tuple[float, Similarity] | None = None
    for name, start in (("centred", centred),
                        ("free", centre_similarity(gt_kept, cams.refined))):
        fitted = fit_frame(model, start, gt_kept, K, images)
        loss = photo_loss(model, fitted.apply_to_poses(gt_kept), K, images)
        log.info("frame fit from the %s start: loss %.5f", name, loss)
        if best is None or loss < best[0]:
            best = (loss, fitted)
    assert best is not None
    return best[1]

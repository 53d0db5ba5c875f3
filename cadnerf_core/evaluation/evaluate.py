"""Evaluate the whole method on a dataset with ground-truth cameras.

The first N training views (in walking order) become a job's photos: RGBA PNGs whose alpha is
the mask. The job runs with a preset and overrides. The held-out views' ground-truth cameras are
then brought into the NeRF's frame (the retrieved library model's) by the similarity between
the ground-truth and the refined camera centres of the training photos (one that keeps the
object's centre fixed, see ``evaluate_dataset``), by default refined photometrically on the
training photos themselves (``fit_frame``), rendered with the trained model, and compared with
the held-out images. Pose errors of the retrieved and of the refined
cameras are measured against the ground truth after a free similarity (Umeyama) alignment of
camera centres, as BARF and the paper do.

The NeRF's intrinsics are its own estimate (from the canonical crop and the library camera), so
by default the held-out views are rendered with the estimated focal length of the training
photos, which is the one consistent with the NeRF's scale; ``intrinsics="gt"`` uses the
dataset's own.
"""

from __future__ import annotations

import json
import logging
import math
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from PIL import Image

from cadnerf_core.cameras import align_poses, umeyama
from cadnerf_core.evaluation.dataset import Dataset, load_dataset
from cadnerf_core.evaluation.metrics import (
    LPIPS_MISSING,
    ImageMetrics,
    LpipsNet,
    PoseMetrics,
    image_metrics,
    mean_image_metrics,
    pose_metrics,
)
from cadnerf_core.library.format import Library
from cadnerf_core.progress import Progress

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


def centre_similarity(c2w_src: np.ndarray, c2w_dst: np.ndarray,
                      fix_origin: bool = False) -> Similarity:
    """The similarity that best maps the source camera centres onto the destination's.

    Args:
        c2w_src, c2w_dst: [N, 4, 4] corresponding cameras (N >= 3 for a unique rotation).
        fix_origin: keep the origin fixed (``t = 0``): the best rotation, and the scale that
            matches the cameras' RMS distances from the origin. Both our frames hold the
            object centred at the origin, so this keeps the object centred and in view when
            the cameras are uncertain (a free translation absorbs pose errors as an offset).
    Returns:
        Similarity with ``dst_centre ~ scale * R @ src_centre + t`` (Umeyama, least squares).
    """
    src = np.asarray(c2w_src, dtype=np.float64)[:, :3, 3]
    dst = np.asarray(c2w_dst, dtype=np.float64)[:, :3, 3]
    if not fix_origin:
        scale, R, t = umeyama(src, dst)
        return Similarity(scale, R, t)
    U, _, Vt = np.linalg.svd(dst.T @ src)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    # Scale from the cameras' distances alone: a poor rotation fit must not pull the
    # cameras into the object (the least-squares scale shrinks with the fit).
    norm = float((src**2).sum())
    scale = math.sqrt(float((dst**2).sum()) / norm) if norm > 0 else 1.0
    return Similarity(scale, R, np.zeros(3))


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
        The refined Similarity (``start`` when ``steps`` is 0).
    """
    import torch

    from cadnerf_core.cameras import se3_exp
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
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    finally:
        for param, flag in zip(st.fields.parameters(), was, strict=True):
            param.requires_grad_(flag)
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
    sim = centre_similarity(gt_kept, cams.refined, fix_origin=align != "umeyama")
    if align != "photometric":
        return sim
    K = np.stack([eval_intrinsics(data.K[i], cams, intrinsics) for i in cams.kept])
    return fit_frame(model, sim, gt_kept, K, data.images[cams.kept])


@dataclass
class EvalReport:
    """Everything one evaluation measured (all JSON-able through ``to_json``)."""

    dataset: str
    n_views: int
    preset: str
    overrides: dict[str, Any]
    seed: int
    model_id: str
    category: str
    image: ImageMetrics  # mean over held-out views
    per_view: list[ImageMetrics]
    lpips_note: str | None  # why LPIPS and Average are missing, when they are
    pose_refined: PoseMetrics  # refined cameras of the kept photos vs ground truth
    pose_retrieved: PoseMetrics  # retrieved cameras (before refinement) vs ground truth
    kept: list[str]
    discarded: list[str]
    phases: dict[str, dict[str, float]]  # per phase: seconds, peak memory (MiB)
    seconds: float  # wall time of the job and the evaluation
    render_seconds: float  # wall time of rendering and scoring the held-out views
    job_dir: str
    eval_size: int  # side in pixels of the scored held-out views
    intrinsics: str  # "estimated" or "gt" focal length for the held-out renders
    align: str  # "photometric", "centred" or "umeyama" mapping of GT cameras for rendering
    focal_used: float
    focal_gt: float
    test_names: list[str]
    renders: list[str]  # saved held-out renders, in test order
    cameras: dict[str, list[Any]] = field(default_factory=dict)  # poses in the GT frame

    def to_json(self) -> dict[str, Any]:
        """Plain, JSON-serialisable dict (infinite PSNR becomes ``null``)."""
        return _finite_or_none(asdict(self))


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite_or_none(value.tolist())
    return value


def first_views(dataset: Dataset, n_views: int) -> Dataset:
    """The first ``n_views`` training views in walking order (the test split is kept).

    Raises:
        ValueError: fewer views than asked for, or no held-out split.
    """
    if n_views < 1 or n_views > len(dataset.names):
        raise ValueError(f"asked for {n_views} views, the dataset has {len(dataset.names)}")
    if dataset.test is None or not dataset.test.names:
        raise ValueError(f"{dataset.root} has no test split (transforms_test.json)")
    sl = slice(0, n_views)
    return Dataset(images=dataset.images[sl], masks=dataset.masks[sl], c2w=dataset.c2w[sl],
                   K=dataset.K[sl], names=dataset.names[sl], root=dataset.root,
                   test=dataset.test)


def exif_with_focal(K: np.ndarray, width: int, height: int) -> bytes:
    """EXIF bytes whose ``FocalLengthIn35mmFilm`` is the focal length of ``K`` [3, 3] for a
    photo of ``width`` x ``height`` pixels (rounded to whole mm, as the tag stores it)."""
    from cadnerf_core.intake.photos import FULL_FRAME_DIAGONAL_MM

    exif = Image.Exif()
    focal_35mm = float(K[0, 0]) * FULL_FRAME_DIAGONAL_MM / float(np.hypot(width, height))
    exif.get_ifd(0x8769)[0xA405] = round(focal_35mm)
    return exif.tobytes()


def write_job(job_dir: Path, train: Dataset, preset: str, overrides: dict[str, Any],
              exif_focal: bool = False) -> None:
    """Create a job folder: ``inputs/NNN_<name>.png`` (RGBA, alpha = mask) and ``config.json``.

    Args:
        job_dir: the folder (created; must not hold an earlier job).
        train: the views to use as photos, in order.
        preset, overrides: the job's configuration.
        exif_focal: write each view's true focal length into its EXIF, as a phone does.
    """
    inputs = job_dir / "inputs"
    inputs.mkdir(parents=True, exist_ok=False)
    for i, (rgb, mask, name) in enumerate(zip(train.images, train.masks, train.names,
                                              strict=True)):
        rgba = np.dstack([np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8),
                          mask.astype(np.uint8) * 255])
        height, width = mask.shape
        exif = exif_with_focal(train.K[i], width, height) if exif_focal else b""
        Image.fromarray(rgba, "RGBA").save(inputs / f"{i:03d}_{name}.png", exif=exif)
    config = {"preset": preset, "overrides": overrides}
    (job_dir / "config.json").write_text(json.dumps(config, indent=2))


@dataclass
class JobCameras:
    """A finished job's cameras, read back from its folder."""

    model_id: str
    category: str
    kept: list[int]  # photo indices that were not discarded, in order
    discarded: list[int]
    retrieved: np.ndarray  # [K, 4, 4] retrieved c2w of the kept photos (NeRF frame)
    refined: np.ndarray  # [K, 4, 4] refined c2w of the kept photos (NeRF frame)
    K_photo: np.ndarray  # [K, 3, 3] estimated intrinsics in photo pixels


def read_job_cameras(job_dir: Path, model: TrainedModel) -> JobCameras:
    """Retrieved poses from ``retrieval.json``, refined poses from the trained model.

    Args:
        job_dir: a finished job folder.
        model: its trained model (refined poses of the kept photos, in photo order).
    Returns:
        JobCameras.
    Raises:
        ValueError: the model's poses do not match the kept photos, or are not finite.
    """
    data = json.loads((job_dir / "retrieval.json").read_text())
    matches = sorted(data["matches"], key=lambda m: int(m["index"]))
    kept = [m for m in matches if not m["discarded"]]
    refined = np.asarray(model.c2w, dtype=np.float64)
    if len(refined) != len(kept):
        raise ValueError(f"the model has {len(refined)} poses for {len(kept)} kept photos")
    bad = [str(m["name"]) for m, pose in zip(kept, refined, strict=True)
           if not np.isfinite(pose).all()]
    if bad:
        raise ValueError(f"refined poses are not finite (training diverged) for {bad}")
    return JobCameras(
        model_id=str(data["model_id"]), category=str(data["category"]),
        kept=[int(m["index"]) for m in kept],
        discarded=[int(m["index"]) for m in matches if m["discarded"]],
        retrieved=np.array([m["c2w"] for m in kept], dtype=np.float64),
        refined=refined, K_photo=np.array([m["K_photo"] for m in kept], dtype=np.float64))


def _numbers(values: Any) -> dict[str, float]:
    if not isinstance(values, dict):
        return {}
    return {str(k): float(v) for k, v in values.items()
            if isinstance(v, int | float) and not isinstance(v, bool)}


def phase_costs(*sources: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Seconds and peak memory per phase, from job metadata (later sources win).

    A source may hold ``timings`` or ``timings_s`` (``{"phase1_s": 1.2, "intake_s": 0.3}``)
    and ``memory`` or ``peak_memory_mb`` (``{"phase1": {"rss_peak_mb": 812.0}}``): the
    checkpoint's metadata and ``metrics.json`` use these names.

    Returns:
        phase -> {"seconds": ..., "<memory key>": ...}.
    """
    out: dict[str, dict[str, float]] = {}
    for source in sources:
        for key in ("timings", "timings_s"):
            for name, secs in _numbers(source.get(key)).items():
                out.setdefault(name.removesuffix("_s"), {})["seconds"] = secs
        for key in ("memory", "peak_memory_mb"):
            memory = source.get(key)
            for name, values in (memory.items() if isinstance(memory, dict) else []):
                out.setdefault(str(name), {}).update(_numbers(values))
    return out


def eval_intrinsics(test_K: np.ndarray, cams: JobCameras, mode: str) -> np.ndarray:
    """Intrinsics to render the held-out views with.

    Args:
        test_K: [3, 3] ground-truth intrinsics of the held-out views.
        cams: the job's cameras (estimated intrinsics of the kept photos).
        mode: "estimated" (the NeRF's median focal length, ground-truth principal point) or
            "gt".
    Returns:
        K [3, 3].
    """
    K = np.array(test_K, dtype=np.float64, copy=True)
    if mode == "estimated":
        focal = float(np.median(np.concatenate([cams.K_photo[:, 0, 0], cams.K_photo[:, 1, 1]])))
        K[0, 0] = K[1, 1] = focal
    elif mode != "gt":
        raise ValueError(f"intrinsics must be 'estimated' or 'gt', not {mode!r}")
    return K


def resize_view(image: np.ndarray, K: np.ndarray, size: int | None,
                ) -> tuple[np.ndarray, np.ndarray]:
    """A square view and its intrinsics at ``size`` px (area-averaged; unchanged for None).

    Args:
        image: [H, W, 3] float in [0, 1] with H == W; K: [3, 3] for it.
    Returns:
        image [size, size, 3] float32, K [3, 3] scaled to the new size.
    """
    side = image.shape[1]
    if size is None or size == side:
        return image.astype(np.float32), K
    import cv2

    scaled = np.array(K, dtype=np.float64, copy=True)
    scaled[:2] *= size / side  # pixel-edge convention: (u + 0.5) scales with the image
    resized = cv2.resize(image.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA)
    return np.clip(resized, 0.0, 1.0), scaled


def _render_held_out(model: TrainedModel, test: Dataset, c2w_nerf: np.ndarray, K: np.ndarray,
                     out_dir: Path, lpips_net: LpipsNet | None, size: int | None,
                     ) -> tuple[list[ImageMetrics], list[str]]:
    """Render every held-out view, save it, and score it against the ground truth."""
    from cadnerf_core.export.artifacts import write_png

    out_dir.mkdir(parents=True, exist_ok=True)
    scores, paths = [], []
    for i, (c2w, full_gt) in enumerate(zip(c2w_nerf, test.images, strict=True)):
        gt, K_eval = resize_view(full_gt, K, size)
        height, width = gt.shape[:2]
        rgb, _ = model.render_image(c2w, K_eval, width, height, background=1.0)
        path = out_dir / f"test_{i:03d}.png"
        write_png(path, rgb)
        scores.append(image_metrics(rgb, gt, lpips_net))
        paths.append(str(path))
    return scores, paths


def _cameras_in_gt_frame(train: Dataset, cams: JobCameras) -> dict[str, list[Any]]:
    """Ground-truth, retrieved and refined training cameras, all in the ground truth's frame."""
    gt_kept = train.c2w[cams.kept]
    return {"gt": train.c2w.tolist(),
            "retrieved": align_poses(cams.retrieved, gt_kept).tolist(),
            "refined": align_poses(cams.refined, gt_kept).tolist()}


def evaluate_dataset(dataset_dir: Path, n_views: int, library: Library, preset: str = "preview",
                     overrides: dict[str, Any] | None = None, job_dir: Path | None = None,
                     lpips_net: LpipsNet | None = None, device: str = "auto",
                     intrinsics: Literal["estimated", "gt"] = "estimated",
                     align: Literal["photometric", "centred", "umeyama"] = "photometric",
                     eval_size: int | None = None, progress: Progress | None = None,
                     exif_focal: bool = False) -> EvalReport:
    """Run the method on the first ``n_views`` views of a dataset and score it.

    Args:
        dataset_dir: dataset with a test split (``load_dataset``).
        n_views: input views (the first ones in walking order).
        library: the CAD library.
        preset, overrides: the job's configuration (``seed`` may be an override).
        job_dir: the job folder to create (must not exist or be empty); default: a new
            temporary folder, kept.
        lpips_net: from ``metrics.load_lpips``; ``None`` leaves LPIPS and Average out.
        device: training and rendering device ("auto", "cpu", "cuda").
        intrinsics: focal length of the held-out renders (see ``eval_intrinsics``).
        align: how ground-truth cameras are mapped into the NeRF's frame for rendering:
            "photometric" (the centred mapping, then refined on the training photos by
            ``fit_frame``: one 7-number correction for all cameras, no held-out image used),
            "centred" (rotation and scale about the object's centre, fitted on the training
            cameras' centres) or "umeyama" (free similarity of camera centres; its translation
            absorbs pose errors and moves the object off-centre). Pose errors always use
            Umeyama.
        eval_size: side in pixels at which held-out views are rendered and scored (ground
            truth area-averaged to it); None = the dataset's own size.
        progress: forwarded to the pipeline.
        exif_focal: the photos carry their true focal length in EXIF, as a phone's do.
    Returns:
        EvalReport.
    Raises:
        ValueError: too few views, no test split, or a non-empty job folder.
    """
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.pipeline import run_job

    start = time.perf_counter()
    overrides = dict(overrides or {})
    data = first_views(load_dataset(dataset_dir), n_views)
    assert data.test is not None
    job = Path(job_dir) if job_dir is not None else Path(tempfile.mkdtemp(prefix="cadnerf-eval-"))
    if job.exists() and any(job.iterdir()):
        raise ValueError(f"job folder {job} is not empty")
    write_job(job, data, preset, overrides, exif_focal)
    run_job(job, library, progress, device)
    model = TrainedModel.load(job, device)
    cams = read_job_cameras(job, model)
    gt_kept = data.c2w[cams.kept]
    to_nerf = frame_mapping(model, data, cams, align, intrinsics)
    K = eval_intrinsics(data.test.K[0], cams, intrinsics)
    render_start = time.perf_counter()
    scores, renders = _render_held_out(model, data.test, to_nerf.apply_to_poses(data.test.c2w),
                                       K, job / "eval", lpips_net, eval_size)
    render_s = time.perf_counter() - render_start
    metrics_path = job / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
    names = data.names
    return EvalReport(
        dataset=str(dataset_dir), n_views=n_views, preset=preset, overrides=overrides,
        seed=int(json.loads((job / "config.json").read_text()).get("seed", 0)),
        model_id=cams.model_id, category=cams.category,
        image=mean_image_metrics(scores), per_view=scores,
        lpips_note=None if lpips_net is not None else LPIPS_MISSING,
        pose_refined=pose_metrics(cams.refined, gt_kept),
        pose_retrieved=pose_metrics(cams.retrieved, gt_kept),
        kept=[names[i] for i in cams.kept], discarded=[names[i] for i in cams.discarded],
        phases=phase_costs(model.extra, metrics), seconds=time.perf_counter() - start,
        job_dir=str(job), eval_size=int(eval_size or data.test.images.shape[1]),
        intrinsics=intrinsics, align=align, focal_used=float(K[0, 0]),
        focal_gt=float(data.test.K[0][0, 0]), render_seconds=render_s,
        test_names=data.test.names, renders=renders,
        cameras=_cameras_in_gt_frame(data, cams))

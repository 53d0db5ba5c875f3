"""Evaluate the whole method on a dataset with ground-truth cameras.

The first N training views (in walking order) become a job's photos: RGBA PNGs whose alpha is
the mask. The job runs with a preset and overrides. The held-out views' ground-truth cameras are
then brought into the NeRF's frame (the retrieved library model's) by the similarity between
the ground-truth and the refined camera centres of the training photos (one that keeps the
object's centre fixed, see ``evaluate_dataset``), by default refined photometrically on the
training photos themselves (``frame.fit_frame``), rendered with the trained model, and compared
with the held-out images. Pose errors of the retrieved and of the refined cameras are measured
against the ground truth after a free similarity (Umeyama) alignment of camera centres, as BARF
and the paper do.

The NeRF's intrinsics are its own estimate (from the canonical crop and the library camera), so
by default the held-out views are rendered with the estimated focal length of the training
photos, which is the one consistent with the NeRF's scale; ``intrinsics="gt"`` uses the
dataset's own. The job folder's side (writing the job, reading its cameras) is in ``jobio``.
"""

from __future__ import annotations

import logging
import math
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cadnerf_core.cameras.conventions import align_poses
from cadnerf_core.evaluation.dataset import Dataset, load_dataset
from cadnerf_core.evaluation.frame import frame_mapping
from cadnerf_core.evaluation.jobio import (
    JobCameras,
    eval_intrinsics,
    first_views,
    phase_costs,
    read_job_cameras,
    write_job,
)
from cadnerf_core.evaluation.metrics import (
    LPIPS_MISSING,
    ImageMetrics,
    LpipsNet,
    PoseMetrics,
    image_metrics,
    mean_image_metrics,
    pose_metrics,
)
from cadnerf_core.jobfolder import JobFolder
from cadnerf_core.library.format import Library
from cadnerf_core.progress import Progress

if TYPE_CHECKING:
    from cadnerf_core.nerf.model import TrainedModel

log = logging.getLogger(__name__)


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
    focal_error: float  # focal_used / focal_gt - 1: the job's (refined) focal length's error
    focal_error_retrieved: float  # the same for retrieval's estimate, before any refinement
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
    from cadnerf_core.export.media import write_png

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
    folder = JobFolder(job)
    model = TrainedModel.load(job, device)
    cams = read_job_cameras(job, model)
    gt_kept = data.c2w[cams.kept]
    to_nerf = frame_mapping(model, data, cams, align, intrinsics)
    K = eval_intrinsics(data.test.K[0], cams, intrinsics)
    focal_gt = float(data.test.K[0][0, 0])
    retrieved = float(np.median(cams.K_retrieved[:, 0, 0]))
    render_start = time.perf_counter()
    scores, renders = _render_held_out(model, data.test, to_nerf.apply_to_poses(data.test.c2w),
                                       K, folder.eval_dir, lpips_net, eval_size)
    render_s = time.perf_counter() - render_start
    metrics = folder.read_metrics() or {}
    names = data.names
    return EvalReport(
        dataset=str(dataset_dir), n_views=n_views, preset=preset, overrides=overrides,
        seed=folder.read_config().seed,
        model_id=cams.model_id, category=cams.category,
        image=mean_image_metrics(scores), per_view=scores,
        lpips_note=None if lpips_net is not None else LPIPS_MISSING,
        pose_refined=pose_metrics(cams.refined, gt_kept),
        pose_retrieved=pose_metrics(cams.retrieved, gt_kept),
        kept=[names[i] for i in cams.kept], discarded=[names[i] for i in cams.discarded],
        phases=phase_costs(model.extra, metrics), seconds=time.perf_counter() - start,
        job_dir=str(job), eval_size=int(eval_size or data.test.images.shape[1]),
        intrinsics=intrinsics, align=align, focal_used=float(K[0, 0]), focal_gt=focal_gt,
        focal_error=float(K[0, 0]) / focal_gt - 1.0,
        focal_error_retrieved=retrieved / focal_gt - 1.0, render_seconds=render_s,
        test_names=data.test.names, renders=renders,
        cameras=_cameras_in_gt_frame(data, cams))

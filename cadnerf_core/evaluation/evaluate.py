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
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cadnerf_core.cameras.conventions import align_poses
from cadnerf_core.evaluation.capture import with_found_masks
from cadnerf_core.evaluation.dataset import Dataset, load_dataset
from cadnerf_core.evaluation.frame import frame_mapping, refine_view
from cadnerf_core.evaluation.jobio import (
    JobCameras,
    eval_intrinsics,
    first_views,
    phase_costs,
    read_job_cameras,
    with_job_masks,
    write_job,
)
from cadnerf_core.evaluation.metrics import (
    LPIPS_MISSING,
    ImageMetrics,
    LpipsNet,
    PoseMetrics,
    image_metrics,
    masked_image_metrics,
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
    image_masked: ImageMetrics  # mean over held-out views, inside the object's mask
    per_view_masked: list[ImageMetrics]
    test_masks: str  # "dataset" (the frames' own) or "found" (background removal's)
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
    align: str  # mapping of GT cameras for rendering (``frame.ALIGNS``)
    focal_used: float
    focal_gt: float
    focal_error: float  # focal_used / focal_gt - 1: the job's (refined) focal length's error
    focal_error_retrieved: float  # the same for retrieval's estimate, before any refinement
    test_names: list[str]
    renders: list[str]  # saved held-out renders, in test order
    cameras: dict[str, list[Any]] = field(default_factory=dict)  # poses in the GT frame
    # The held-out cameras in the NeRF's frame ("c2w"; "c2w_centred": by the centred mapping,
    # before the photometric fit; "c2w_frame": by the frame mapping, before any refinement on
    # the view itself) and their intrinsics "K" in the dataset's pixels.
    held_out: dict[str, list[Any]] = field(default_factory=dict)
    # The same views rendered from the exported textured mesh (``mesh=True``), in the mask.
    image_mesh: ImageMetrics | None = None
    per_view_mesh: list[ImageMetrics] = field(default_factory=list)
    renders_mesh: list[str] = field(default_factory=list)

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
    """A view and its intrinsics at ``size`` px on its longer side (area-averaged; unchanged
    for None).

    Args:
        image: [H, W, C] float in [0, 1]; K: [3, 3] for it.
    Returns:
        image [h, w, C] float32 (the aspect kept, sides rounded), K [3, 3] scaled to it.
    """
    height, width = image.shape[:2]
    if size is None or size == max(height, width):
        return image.astype(np.float32), K
    import cv2

    new_width = max(1, round(width * size / max(height, width)))
    new_height = max(1, round(height * size / max(height, width)))
    scaled = np.array(K, dtype=np.float64, copy=True)
    # Pixel-edge convention: (u + 0.5) scales with the image, so K's rows scale as its sides.
    scaled[0] *= new_width / width
    scaled[1] *= new_height / height
    resized = cv2.resize(image.astype(np.float32), (new_width, new_height),
                         interpolation=cv2.INTER_AREA)
    return np.clip(resized.reshape(new_height, new_width, *image.shape[2:]), 0.0, 1.0), scaled


def resize_mask(mask: np.ndarray, K: np.ndarray, size: int | None) -> np.ndarray:
    """A mask [H, W] bool at the size ``resize_view`` gives its view (area-averaged, then
    half-covered pixels kept). Returns [h, w] bool."""
    return resize_view(mask.astype(np.float32)[..., None], K, size)[0][..., 0] > 0.5


@dataclass(frozen=True)
class HeldOutScores:
    """The held-out views' scores and renders."""

    whole: list[ImageMetrics]  # over the whole frame
    masked: list[ImageMetrics]  # inside the object's mask
    renders: list[str]  # saved renders, in test order


# (c2w [4, 4], K [3, 3], width, height) -> rgb [H, W, 3] on white
Renderer = Callable[[np.ndarray, np.ndarray, int, int], np.ndarray]


def _render_held_out(render: Renderer, test: Dataset, c2w_nerf: np.ndarray, Ks: np.ndarray,
                     out_dir: Path, lpips_net: LpipsNet | None, size: int | None,
                     prefix: str = "test") -> HeldOutScores:
    """Render every held-out view (c2w_nerf [T, 4, 4], Ks [T, 3, 3] in the dataset's pixels),
    save it as ``{prefix}_NNN.png``, and score it against the ground truth."""
    from cadnerf_core.export.media import write_png

    out_dir.mkdir(parents=True, exist_ok=True)
    scores = HeldOutScores([], [], [])
    for i, (c2w, K, full_gt, full_mask) in enumerate(zip(c2w_nerf, Ks, test.images, test.masks,
                                                         strict=True)):
        gt, K_eval = resize_view(full_gt, K, size)
        mask = resize_mask(full_mask, K, size)
        height, width = gt.shape[:2]
        rgb = render(c2w, K_eval, width, height)
        path = out_dir / f"{prefix}_{i:03d}.png"
        write_png(path, rgb)
        scores.whole.append(image_metrics(rgb, gt, lpips_net))
        scores.masked.append(masked_image_metrics(rgb, gt, mask, lpips_net) if mask.any()
                             else scores.whole[-1])
        scores.renders.append(str(path))
    return scores


def _mesh_renderer(job: Path) -> Renderer:
    """The job's textured mesh as a ``Renderer`` (``views.job_renderer``)."""
    from cadnerf_core.evaluation.views import View, job_renderer

    render = job_renderer(job, "mesh")

    def mesh_view(c2w: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
        return render(View("", c2w, K, width, height))[0]

    return mesh_view


def _score_held_out(model: TrainedModel, job: Path, test: Dataset, c2w_nerf: np.ndarray,
                    Ks: np.ndarray, lpips_net: LpipsNet | None, size: int | None, mesh: bool,
                    ) -> tuple[HeldOutScores, HeldOutScores | None]:
    """The held-out views rendered from the field and, where ``mesh``, from the job's mesh,
    saved in the job's eval folder and scored."""
    def field_view(c2w: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
        return model.render_image(c2w, K, width, height, background=1.0)[0]

    out_dir = JobFolder(job).eval_dir
    scores = _render_held_out(field_view, test, c2w_nerf, Ks, out_dir, lpips_net, size)
    on_mesh = _render_held_out(_mesh_renderer(job), test, c2w_nerf, Ks, out_dir, lpips_net,
                               size, "mesh") if mesh else None
    return scores, on_mesh


def _refined_views(model: TrainedModel, test: Dataset, c2w_nerf: np.ndarray, Ks: np.ndarray,
                   size: int | None) -> np.ndarray:
    """Each held-out camera [T, 4, 4] refined on its own photo at the size it is scored
    (``frame.refine_view``)."""
    out = []
    for c2w, K, image, mask in zip(c2w_nerf, Ks, test.images, test.masks, strict=True):
        small, K_small = resize_view(image, K, size)
        out.append(refine_view(model, c2w, K_small, small, resize_mask(mask, K, size)))
    return np.stack(out)


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
                     align: Literal["photometric", "per-view", "centred",
                                    "umeyama"] = "photometric",
                     eval_size: int | None = None, progress: Progress | None = None,
                     exif_focal: bool = False, hold_out: Sequence[int] = (),
                     mesh: bool = False) -> EvalReport:
    """Run the method on the first ``n_views`` views of a dataset and score it.

    Args:
        dataset_dir: dataset with a test split, or a capture and ``hold_out``
            (``load_dataset``). A dataset without masks is given to the job without them
            (it makes its own); its held-out views are masked as a job masks its photos.
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
            absorbs pose errors and moves the object off-centre), or "per-view" (the frame
            fitted from the centred and the free start, the better kept; then each held-out
            camera refined on its own photo at ``eval_size``, the fields frozen, as BARF and
            SPARF evaluate: ``frame.refine_view``). Pose errors always use Umeyama.
        eval_size: longer side in pixels at which held-out views are rendered and scored
            (ground truth area-averaged to it); None = the dataset's own size.
        progress: forwarded to the pipeline.
        exif_focal: the photos carry their true focal length in EXIF, as a phone's do.
        hold_out: frames moved to the test split first (a capture has none of its own;
            ``load_dataset``).
        mesh: also render the held-out views from the job's textured ``mesh.glb`` and score
            them inside the mask.
    Returns:
        EvalReport.
    Raises:
        ValueError: too few views, no test split, or a non-empty job folder.
        InputError: a broken dataset.
    """
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.pipeline import run_job

    start = time.perf_counter()
    overrides = dict(overrides or {})
    data = first_views(load_dataset(dataset_dir, hold_out), n_views)
    assert data.test is not None
    test = data.test if data.test.masked else with_found_masks(data.test)
    job = Path(job_dir) if job_dir is not None else Path(tempfile.mkdtemp(prefix="cadnerf-eval-"))
    if job.exists() and any(job.iterdir()):
        raise ValueError(f"job folder {job} is not empty")
    write_job(job, data, preset, overrides, exif_focal)
    run_job(job, library, progress, device)
    folder = JobFolder(job)
    model = TrainedModel.load(job, device)
    cams = read_job_cameras(job, model)
    if not data.masked:  # the frame fit compares the photos on white, as the NeRF renders
        data = with_job_masks(job, data)
    gt_kept = data.c2w[cams.kept]
    centred = frame_mapping(model, data, cams, "centred", intrinsics)
    to_nerf = frame_mapping(model, data, cams, align, intrinsics)
    Ks = np.stack([eval_intrinsics(k, cams, intrinsics) for k in test.K])
    c2w_frame = to_nerf.apply_to_poses(test.c2w)
    c2w_nerf = _refined_views(model, test, c2w_frame, Ks, eval_size) if align == "per-view" \
        else c2w_frame
    render_start = time.perf_counter()
    scores, on_mesh = _score_held_out(model, job, test, c2w_nerf, Ks, lpips_net, eval_size,
                                      mesh)
    render_s = time.perf_counter() - render_start
    metrics = folder.read_metrics() or {}
    names = data.names
    focal_gt = float(test.K[0][0, 0])
    return EvalReport(
        dataset=str(dataset_dir), n_views=n_views, preset=preset, overrides=overrides,
        seed=folder.read_config().seed,
        model_id=cams.model_id, category=cams.category,
        image=mean_image_metrics(scores.whole), per_view=scores.whole,
        image_masked=mean_image_metrics(scores.masked), per_view_masked=scores.masked,
        test_masks="found" if test is not data.test else "dataset",
        lpips_note=None if lpips_net is not None else LPIPS_MISSING,
        pose_refined=pose_metrics(cams.refined, gt_kept),
        pose_retrieved=pose_metrics(cams.retrieved, gt_kept),
        kept=[names[i] for i in cams.kept], discarded=[names[i] for i in cams.discarded],
        phases=phase_costs(model.extra, metrics), seconds=time.perf_counter() - start,
        job_dir=str(job), eval_size=int(eval_size or max(test.images.shape[1:3])),
        intrinsics=intrinsics, align=align, focal_used=float(Ks[0, 0, 0]), focal_gt=focal_gt,
        focal_error=float(Ks[0, 0, 0]) / focal_gt - 1.0,
        focal_error_retrieved=float(np.median(cams.K_retrieved[:, 0, 0])) / focal_gt - 1.0,
        render_seconds=render_s, test_names=test.names, renders=scores.renders,
        cameras=_cameras_in_gt_frame(data, cams),
        held_out={"c2w": c2w_nerf.tolist(), "c2w_centred": centred.apply_to_poses(test.c2w)
                  .tolist(), "c2w_frame": c2w_frame.tolist(), "K": Ks.tolist()},
        image_mesh=mean_image_metrics(on_mesh.masked) if on_mesh else None,
        per_view_mesh=on_mesh.masked if on_mesh else [],
        renders_mesh=on_mesh.renders if on_mesh else [])

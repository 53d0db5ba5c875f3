"""An evaluation's job folder: the dataset views it starts from, written as a job through
``JobFolder``, and the cameras and costs read back from it once the job has run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from cadnerf_core.config import internal_config
from cadnerf_core.evaluation.dataset import Dataset
from cadnerf_core.jobfolder import JobFolder

if TYPE_CHECKING:
    from cadnerf_core.nerf.model import TrainedModel


def first_views(dataset: Dataset, n_views: int) -> Dataset:
    """The first ``n_views`` training views in walking order (the test split is kept).

    Raises:
        ValueError: fewer views than asked for, or no held-out split.
    """
    if n_views < 1 or n_views > len(dataset.names):
        raise ValueError(f"asked for {n_views} views, the dataset has {len(dataset.names)}")
    if dataset.test is None or not dataset.test.names:
        raise ValueError(f"{dataset.root} has no test split (transforms_test.json): name the "
                         "frames to hold out (--hold-out)")
    sl = slice(0, n_views)
    return Dataset(images=dataset.images[sl], masks=dataset.masks[sl], c2w=dataset.c2w[sl],
                   K=dataset.K[sl], names=dataset.names[sl], root=dataset.root,
                   test=dataset.test, masked=dataset.masked)


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
    """Create a job folder: the views as RGBA PNG photos (alpha = mask; RGB where the dataset
    has no masks, for the job to make its own) and the resolved config.

    Args:
        job_dir: the folder (created; must not hold an earlier job).
        train: the views to use as photos, in order.
        preset, overrides: the job's configuration.
        exif_focal: write each view's true focal length into its EXIF, as a phone does.
    Raises:
        ValueError: an invalid configuration, or ``job_dir`` already has photos.
    """
    config = internal_config(preset, overrides)
    folder = JobFolder(job_dir)
    if folder.photos():
        raise ValueError(f"{job_dir} already holds a job")
    for i, (rgb, mask, name) in enumerate(zip(train.images, train.masks, train.names,
                                              strict=True)):
        pixels = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
        if train.masked:
            pixels = np.dstack([pixels, mask.astype(np.uint8) * 255])
        height, width = mask.shape
        exif = exif_with_focal(train.K[i], width, height) if exif_focal else b""
        Image.fromarray(pixels).save(folder.new_photo_path(i, name, "png"), exif=exif)
    folder.write_config(config)


def with_job_masks(job_dir: Path, data: Dataset) -> Dataset:
    """The views a job was given without masks, composited on white by the masks the job
    made (``masks/NNN.png``, scaled to the view; a view without one keeps its frame).

    Args:
        job_dir: a job written by ``write_job`` from ``data`` and run.
        data: its views (``masked`` False).
    Returns:
        The views on white with the job's masks; ``masked`` True.
    """
    import cv2

    folder = JobFolder(job_dir)
    images, masks = data.images.copy(), data.masks.copy()
    height, width = data.masks.shape[1:]
    for i in range(len(data.names)):
        try:
            mask = folder.read_mask(i)
        except FileNotFoundError:
            continue
        if mask.shape != (height, width):
            mask = cv2.resize(mask.astype(np.uint8), (width, height),
                              interpolation=cv2.INTER_NEAREST) > 0
        masks[i] = mask
        images[i][~mask] = 1.0
    return replace(data, images=images, masks=masks, masked=True)


@dataclass
class JobCameras:
    """A finished job's cameras, read back from its folder."""

    model_id: str
    category: str
    kept: list[int]  # photo indices that were not discarded, in order
    discarded: list[int]
    retrieved: np.ndarray  # [K, 4, 4] retrieved c2w of the kept photos (NeRF frame)
    refined: np.ndarray  # [K, 4, 4] refined c2w of the kept photos (NeRF frame)
    K_photo: np.ndarray  # [K, 3, 3] estimated intrinsics in photo pixels (refined, if learned)
    K_retrieved: np.ndarray  # [K, 3, 3] the retrieval's estimate, before any refinement


def read_job_cameras(job_dir: Path, model: TrainedModel) -> JobCameras:
    """Retrieved poses from the job's retrieval, refined poses from the trained model, and
    the intrinsics the job exported (``poses.json``: the refined focal length where it was
    learned; the retrieval's before export).

    Args:
        job_dir: a finished job folder.
        model: its trained model (refined poses of the kept photos, in photo order).
    Returns:
        JobCameras.
    Raises:
        ValueError: no retrieval, or the model's poses do not match the kept photos, or are
            not finite.
    """
    folder = JobFolder(job_dir)
    data = folder.read_retrieval()
    if data is None:
        raise ValueError(f"{job_dir} has no retrieval: the job did not run")
    matches = sorted(data["matches"], key=lambda m: int(m["index"]))
    kept = [m for m in matches if not m["discarded"]]
    refined = np.asarray(model.c2w, dtype=np.float64)
    if len(refined) != len(kept):
        raise ValueError(f"the model has {len(refined)} poses for {len(kept)} kept photos")
    bad = [str(m["name"]) for m, pose in zip(kept, refined, strict=True)
           if not np.isfinite(pose).all()]
    if bad:
        raise ValueError(f"refined poses are not finite (training diverged) for {bad}")
    exported = {int(p["index"]): p for p in (folder.read_poses() or {}).get("photos", [])}
    K_photo = [exported.get(int(m["index"]), m)["K_photo"] for m in kept]
    return JobCameras(
        model_id=str(data["model_id"]), category=str(data["category"]),
        kept=[int(m["index"]) for m in kept],
        discarded=[int(m["index"]) for m in matches if m["discarded"]],
        retrieved=np.array([m["c2w"] for m in kept], dtype=np.float64),
        refined=refined, K_photo=np.array(K_photo, dtype=np.float64),
        K_retrieved=np.array([m["K_photo"] for m in kept], dtype=np.float64))


def _numbers(values: Any) -> dict[str, float]:
    if not isinstance(values, dict):
        return {}
    return {str(k): float(v) for k, v in values.items()
            if isinstance(v, int | float) and not isinstance(v, bool)}


def phase_costs(*sources: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Seconds and peak memory per phase, from job metadata (later sources win).

    A source may hold ``timings`` or ``timings_s`` (``{"phase1_s": 1.2, "intake_s": 0.3}``)
    and ``memory`` or ``peak_memory_mb`` (``{"phase1": {"rss_peak_mb": 812.0}}``): the
    checkpoint's metadata and the job's metrics use these names.

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

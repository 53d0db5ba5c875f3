"""The training benchmark's scores: the true-cameras oracle, BARF-style test-time pose
refinement, and one evaluated job's row of numbers (``benchmarks.bench_training``)."""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from benchmarks.harness import DEVICE
from benchmarks.training_plan import TTA_STEPS

if TYPE_CHECKING:
    from cadnerf_core.evaluation.evaluate import EvalReport


@contextlib.contextmanager
def true_cameras(dataset_dir: Path) -> Iterator[None]:
    """Inside this context every job's retrieval is followed by an oracle step: each kept
    photo's camera becomes the dataset's ground truth, the pose mapped into the retrieved
    (CAD model's) frame by the centred similarity fitted between the true and the retrieved
    camera centres, the intrinsics the true ones cropped by the photo's canonical box. The
    retrieved model and its occupancy (phase one) stay; ``retrieval.json`` is rewritten, so
    the evaluation reads the true cameras back as the job's."""
    import cadnerf_core.pipeline as pipeline
    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.evaluation.frame import centre_similarity
    from cadnerf_core.intake.crop import crop_intrinsics
    from cadnerf_core.jobfolder import JobFolder

    truth = load_dataset(dataset_dir)
    original = pipeline.run_intake

    def oracle_intake(job_dir: Path, *args: Any, **kwargs: Any) -> Any:
        intake = original(job_dir, *args, **kwargs)
        kept = intake.retrieval.kept
        index = [m.index for m in kept]
        to_cad = centre_similarity(truth.c2w[index], np.stack([m.c2w for m in kept]),
                                   fix_origin=True)
        poses = dict(zip(index, to_cad.apply_to_poses(truth.c2w[index]), strict=True))
        intake.retrieval.matches = [
            m if m.discarded else dataclasses.replace(
                m, c2w=poses[m.index], K_photo=truth.K[m.index].copy(),
                K_canon=crop_intrinsics(truth.K[m.index], m.box))
            for m in intake.retrieval.matches]
        JobFolder(job_dir).write_retrieval(intake.retrieval.to_json())
        return intake

    pipeline.run_intake = oracle_intake
    try:
        yield
    finally:
        pipeline.run_intake = original


def refine_test_pose(model: Any, c2w: np.ndarray, K: np.ndarray, image: np.ndarray,
                     steps: int) -> np.ndarray:
    """BARF-style test-time pose refinement: the NeRF frozen, one camera's SE(3) optimised."""
    import torch

    from cadnerf_core.nerf.poses import PoseCorrection
    from cadnerf_core.nerf.rays import pixel_rays
    from cadnerf_core.nerf.volrend import render_rays

    st = model.state
    dev = st.device
    pose = PoseCorrection(torch.as_tensor(c2w, dtype=torch.float32, device=dev)[None])
    optimizer = torch.optim.Adam(pose.parameters(), lr=2e-3)
    target = torch.as_tensor(image, dtype=torch.float32, device=dev)
    Kt = torch.as_tensor(K, dtype=torch.float32, device=dev)
    height, width = image.shape[:2]
    rcfg = st.config.render
    st.fields.requires_grad_(False)
    gen = torch.Generator().manual_seed(0)
    for _ in range(steps):
        flat = torch.randint(0, height * width, (1024,), generator=gen).to(dev)
        x, y = flat % width, flat // width
        idx = torch.zeros_like(flat)
        rays_o, rays_d = pixel_rays(pose(idx), Kt.expand(len(flat), 3, 3), x, y)
        out = render_rays(lambda p, d: st.fields.query(p, d), rays_o, rays_d,
                          rcfg.samples_per_ray, rcfg.bound, st.grid, True, True)
        assert out.rgb is not None
        loss = torch.nn.functional.mse_loss(out.rgb, target[y, x])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    st.fields.requires_grad_(True)
    with torch.no_grad():
        return pose().double().cpu().numpy()[0]


def refined_test_psnr(report: EvalReport, steps: int, align: str | None = None,
                      device: str = DEVICE) -> float:
    """Mean held-out PSNR after ``refine_test_pose``, started from the cameras and intrinsics
    ``evaluate_dataset`` rendered the report's test PSNR with (same mapping, same focal
    length, same size and background), so only the refinement differs. ``align``: the
    mapping (``evaluation.frame_mapping``), when not the report's; ``steps`` 0: no
    refinement; ``device``: where the model is loaded (the job's own)."""
    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.evaluation.evaluate import resize_view
    from cadnerf_core.evaluation.frame import frame_mapping
    from cadnerf_core.evaluation.jobio import eval_intrinsics, first_views, read_job_cameras
    from cadnerf_core.evaluation.metrics import image_metrics
    from cadnerf_core.nerf.model import TrainedModel

    if (align or report.align) == "per-view":
        raise ValueError("refined_test_psnr refines held-out cameras itself: give a report "
                         "mapped without per-view refinement")
    job = Path(report.job_dir)
    model = TrainedModel.load(job, device)
    data = first_views(load_dataset(report.dataset), report.n_views)
    assert data.test is not None
    cams = read_job_cameras(job, model)
    to_nerf = frame_mapping(model, data, cams, align or report.align, report.intrinsics)
    K = eval_intrinsics(data.test.K[0], cams, report.intrinsics)
    if not math.isclose(float(K[0, 0]), report.focal_used, rel_tol=1e-9):
        raise RuntimeError(f"focal {K[0, 0]} differs from the evaluation's {report.focal_used}")
    scores = []
    for c2w, image in zip(to_nerf.apply_to_poses(data.test.c2w), data.test.images,
                          strict=True):
        gt, K_eval = resize_view(image, K, report.eval_size)
        height, width = gt.shape[:2]
        better = refine_test_pose(model, c2w, K_eval, gt, steps) if steps else c2w
        rgb, _ = model.render_image(better, K_eval, width, height, background=1.0)
        scores.append(image_metrics(rgb, gt).psnr)
    return float(np.mean(scores))


def score_report(report: EvalReport, tta: bool, device: str = DEVICE) -> dict[str, Any]:
    """The table's numbers for one evaluated job (its model loaded on ``device``)."""
    from cadnerf_core.jobfolder import JobFolder

    metrics = JobFolder(report.job_dir).read_metrics() or {}
    return {"psnr": report.image.psnr,
            # The same cameras mapped by the camera centres alone: six noisy centres on a
            # ring fix the frame only roughly.
            "psnr_centred": refined_test_psnr(report, 0, "centred", device),
            "psnr_tta": (refined_test_psnr(report, TTA_STEPS, device=device) if tta
                         else float("nan")),
            "rot_before": float(np.median(report.pose_retrieved.rotation_deg_per_view)),
            "rot_after": float(np.median(report.pose_refined.rotation_deg_per_view)),
            "kept": len(report.kept), "model_id": report.model_id,
            "train_psnr": metrics["mean_psnr"],
            "stages": {k.removesuffix("_s"): float(v)
                       for k, v in (metrics.get("timings_s") or {}).items()},
            # evaluate_dataset's wall time less the held-out renders: the whole job (writing
            # its photos, retrieval, training, exports), loading its model and the frame fit.
            "seconds": report.seconds - report.render_seconds}

"""Training benchmark: whole jobs on synthetic datasets, test-view PSNR, poses, ablations.

For each mesh in ``../shared/eval/meshes``: ``render_dataset`` (128 px, 6 training views in
walking order, 12 held-out test views, white background), the training photos go through
``run_job`` (retrieval from the built library, three phases, orbit, mesh) with preset
``preview``. Then:

- whole-job wall time;
- rotation error (degrees, after similarity alignment of camera centres) of the retrieved and of
  the refined poses against the ground truth;
- test-view PSNR: the test cameras are mapped into the NeRF frame by the similarity (Umeyama)
  between ground-truth and refined training camera centres, then rendered. Also reported, as
  BARF and its successors do: PSNR after a short test-time pose refinement of each test camera
  (the NeRF frozen, only the camera's 6-vector optimised on its image), which removes the error
  of the centre-only alignment;
- the paper's Table 5 ablations (no CAD initialisation, no pose optimisation, no deformation).

Usage: ``python -m benchmarks.bench_training [--quick] [--threads N]``.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EVAL = ROOT / ".." / "shared" / "eval" / "meshes"
LIBRARY = ROOT / "library_data" / "build"
ORBIT_FRAME = ROOT / "docs" / "orbit_frame.png"
QUICK_MESHES = ("Duck", "CesiumMilkTruck")
ABLATIONS: dict[str, dict[str, Any]] = {
    "full": {},
    "no CAD init": {"use_cad_init": False},
    "no pose optimisation": {"optimise_poses": False},
    "no deformation": {"use_deformation": False},
}
# Ablation runs skip what does not change their score: a 2-frame orbit, a coarse mesh.
LIGHT_EXPORT = {"export.orbit_frames": 2, "export.mesh_resolution": 16, "export.novel_views": 0}
TTA_STEPS = 20  # test-time pose refinement steps per test view

log = logging.getLogger(__name__)


def mesh_files(quick: bool, names: list[str] | None = None) -> list[Path]:
    """One mesh file per folder of the evaluation set (``QUICK_MESHES`` with ``quick``, or the
    folders ``names``)."""
    out = []
    wanted = names or (list(QUICK_MESHES) if quick else None)
    for folder in sorted(EVAL.iterdir()) if EVAL.is_dir() else []:
        if wanted is not None and folder.name not in wanted:
            continue
        files = sorted(p for p in folder.iterdir()
                       if p.suffix.lower() in {".obj", ".glb", ".ply", ".off", ".stl"})
        if files:
            out.append(files[0])
    return out


def make_job(dataset: Path, job: Path, overrides: dict[str, Any]) -> None:
    """A job folder whose inputs are the dataset's training images (RGBA: alpha = mask)."""
    import json

    (job / "inputs").mkdir(parents=True)
    for image in sorted((dataset / "images").glob("*.png")):
        shutil.copyfile(image, job / "inputs" / f"{image.stem}_view.png")
    (job / "config.json").write_text(json.dumps({"preset": "preview", "overrides": overrides}))


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


def _anchor_points(c2w: np.ndarray) -> np.ndarray:
    """Camera centres and the points each camera looks at (its axis at the centre's distance
    from the origin): aligning both fixes where the cameras point, not only where they are.
    Returns [2N, 3]."""
    centres = c2w[:, :3, 3]
    distance = np.linalg.norm(centres, axis=-1, keepdims=True)
    return np.concatenate([centres, centres + distance * c2w[:, :3, 2]])


def _apply(similarity: tuple[float, np.ndarray, np.ndarray], c2w: np.ndarray) -> np.ndarray:
    """Map a ground-truth camera into the NeRF frame. Returns [4, 4]."""
    scale, R, t = similarity
    out = c2w.copy()
    out[:3, :3] = R @ c2w[:3, :3]
    out[:3, 3] = scale * R @ c2w[:3, 3] + t
    return out


def score_job(job: Path, dataset: Any, tta: bool) -> dict[str, Any]:
    """Pose errors and test-view PSNR of a finished job against its dataset."""
    import json

    from cadnerf_core.cameras import pose_errors, umeyama
    from cadnerf_core.metrics import psnr
    from cadnerf_core.nerf.model import TrainedModel

    model = TrainedModel.load(job, "cpu")
    poses = [p for p in json.loads((job / "poses.json").read_text())["photos"]
             if not p["discarded"]]
    kept = [p["index"] for p in poses]
    gt = dataset.c2w[kept]
    init = np.array([p["c2w_initial"] for p in poses])
    refined = model.c2w
    test = dataset.test
    size = test.images.shape[1]
    scores, scores_axis, scores_tta = [], [], []
    by_centres = umeyama(gt[:, :3, 3], refined[:, :3, 3])
    by_axes = umeyama(_anchor_points(gt), _anchor_points(refined))
    for i in range(len(test.c2w)):
        c2w = _apply(by_centres, test.c2w[i])
        scores.append(psnr(model.render_image(c2w, test.K[i], size, size)[0], test.images[i]))
        c2w = _apply(by_axes, test.c2w[i])
        scores_axis.append(psnr(model.render_image(c2w, test.K[i], size, size)[0],
                                test.images[i]))
        if tta:
            better = refine_test_pose(model, c2w, test.K[i], test.images[i], TTA_STEPS)
            scores_tta.append(psnr(model.render_image(better, test.K[i], size, size)[0],
                                   test.images[i]))
    metrics = json.loads((job / "metrics.json").read_text())
    return {"psnr": float(np.mean(scores)), "psnr_axis": float(np.mean(scores_axis)),
            "psnr_tta": float(np.mean(scores_tta)) if scores_tta else float("nan"),
            "rot_before": float(np.median(pose_errors(init, gt)[0])),
            "rot_after": float(np.median(pose_errors(refined, gt)[0])),
            "kept": len(kept), "model_id": model.extra.get("model_id", "?"),
            "train_psnr": metrics["mean_psnr"]}


def run_one(mesh: Path, work: Path, library: Any, name: str, overrides: dict[str, Any],
            tta: bool) -> dict[str, Any]:
    """Render the dataset (once per mesh), run a job with ``overrides``, score it."""
    from cadnerf_core.dataset import load_dataset, render_dataset
    from cadnerf_core.pipeline import run_job

    dataset_dir = work / mesh.parent.name / "dataset"
    if not dataset_dir.exists():
        render_dataset(mesh, dataset_dir, 6, 128, seed=0, test_views=12)
    job = work / mesh.parent.name / name.replace(" ", "_")
    make_job(dataset_dir, job, overrides)
    start = time.perf_counter()
    run_job(job, library, None, "cpu")
    seconds = time.perf_counter() - start
    result = score_job(job, load_dataset(dataset_dir), tta)
    result["seconds"] = seconds
    return result


def _table(rows: list[tuple[str, str, dict[str, Any]]]) -> list[str]:
    lines = ["| mesh | run | retrieved | kept | job s | train PSNR | test PSNR (centres) | "
             "test PSNR (centres + axes) | + test-time pose | rot err retrieval (median deg) | "
             "rot err refined |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for mesh, name, r in rows:
        lines.append(f"| {mesh} | {name} | {r['model_id']} | {r['kept']} | {r['seconds']:.0f} | "
                     f"{r['train_psnr']:.2f} | {r['psnr']:.2f} | {r['psnr_axis']:.2f} | "
                     f"{r['psnr_tta']:.2f} | {r['rot_before']:.1f} | {r['rot_after']:.1f} |")
    return lines


def _summary(rows: list[tuple[str, str, dict[str, Any]]]) -> list[str]:
    lines = ["", "| run | mean test PSNR (centres) | (centres + axes) | (+ test-time pose) | "
             "mean job s |", "|---|---|---|---|---|"]
    for name in ABLATIONS:
        rs = [r for _, n, r in rows if n == name]
        if rs:
            lines.append(f"| {name} | {np.mean([r['psnr'] for r in rs]):.2f} | "
                         f"{np.mean([r['psnr_axis'] for r in rs]):.2f} | "
                         f"{np.mean([r['psnr_tta'] for r in rs]):.2f} | "
                         f"{np.mean([r['seconds'] for r in rs]):.0f} |")
    return lines


def save_orbit_frame(job: Path) -> None:
    """The middle frame of a job's orbit video, as docs/orbit_frame.png."""
    import imageio_ffmpeg
    from PIL import Image

    reader = imageio_ffmpeg.read_frames(str(job / "orbit.mp4"))
    meta = next(reader)
    frames = list(reader)
    width, height = meta["size"]
    frame = np.frombuffer(frames[len(frames) // 3], np.uint8).reshape(height, width, 3)
    ORBIT_FRAME.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(frame).save(ORBIT_FRAME)


def run(quick: bool, threads: int | None = None, names: list[str] | None = None) -> str:
    """The markdown section (see the module docstring)."""
    import torch

    from cadnerf_core.library import load_library

    meshes = mesh_files(quick, names)
    if not meshes or not LIBRARY.is_dir():
        return "## Training\n\nSkipped: no ../shared/eval/meshes or no built library.\n"
    if threads:
        torch.set_num_threads(threads)
    library = load_library(LIBRARY)
    rows: list[tuple[str, str, dict[str, Any]]] = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for i, mesh in enumerate(meshes):
            for name, overrides in ABLATIONS.items():
                extra = {} if name == "full" else LIGHT_EXPORT
                rows.append((mesh.parent.name, name, run_one(
                    mesh, work, library, name, {**overrides, **extra}, tta=True)))
                log.info("%s %s: %s", mesh.parent.name, name, rows[-1][2])
            if i == 0:
                save_orbit_frame(work / mesh.parent.name / "full")
    flags = " --quick" if quick else ""
    flags += f" --threads {threads}" if threads else ""
    flags += f" --meshes {' '.join(names)}" if names else ""
    lines = ["## Training (preset `preview`, CPU)", "",
             f"Command: `.venv/bin/python -m benchmarks.bench_training{flags}` "
             f"(torch threads: {torch.get_num_threads()}). Datasets: `render_dataset` 128 px, "
             "6 training views in walking order, 12 held-out test views, seed 0. Rotation errors "
             "are medians over the kept photos after similarity alignment. Test cameras are mapped "
             "into the NeRF frame by a similarity (Umeyama) fitted on the training cameras' "
             "centres only, or on centres and the points they look at (their axes at the same "
             "distance); test-time pose: then "
             f"{TTA_STEPS} steps of per-view pose refinement with the NeRF frozen (BARF's "
             "protocol).", "",
             *_table(rows), *_summary(rows), "",
             "An orbit frame of the first mesh's full run: `docs/orbit_frame.png`.", ""]
    return "\n".join(lines)


def main() -> None:
    """Print the section."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two meshes only")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--meshes", nargs="*", default=None, help="mesh folder names")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    print(run(args.quick, args.threads, args.meshes))  # noqa: T201 (the section is the command's output)


if __name__ == "__main__":
    main()

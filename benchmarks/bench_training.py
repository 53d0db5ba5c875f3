"""Training benchmark: whole jobs on synthetic datasets, test-view PSNR, poses, ablations.

Each run is executed and scored by ``evaluation.evaluate.evaluate_dataset``, the protocol of
the evaluation benchmark (``benchmarks.bench_eval``), so both score held-out views the same
way. For each mesh in ``../shared/eval/meshes``: ``render_dataset`` (128 px, 6 training views in
walking order, 12 held-out test views, white background, seed 0); the 6 training views become
the photos of a job run by ``run_job`` (retrieval from the built library, three phases, orbit,
mesh) with preset ``preview``; the held-out ground-truth cameras are mapped into the NeRF frame
by the centred similarity (rotation and scale about the object's centre, which both frames
share, fitted on the training cameras' centres) and that mapping refined on the training photos
(``evaluation.fit_frame``: one rotation, translation and scale for all cameras, fitted so the
NeRF reproduces the training photos from the mapped true training cameras), rendered at the
NeRF's estimated focal length and scored. On top of that report this benchmark adds:

- the test PSNR with the centres' mapping alone (the protocol before session 11);

- whole-job wall time;
- rotation error (median degrees, after similarity alignment of camera centres) of the
  retrieved and of the refined poses against the ground truth (the report's pose metrics);
- the train PSNR of the job's ``metrics.json``;
- as BARF and its successors do, test PSNR after test-time pose refinement of each test
  camera (the NeRF frozen, only the camera's 6-vector optimised on its image; 100 steps,
  BARF's ``optim.test_iter``), started from the same mapped camera and intrinsics as the test
  PSNR, so the two differ only by it. A pose-free method's frame is only known up to a
  similarity, and this protocol removes what is left of that fit's error from the image score
  using each held-out image itself; it cannot change the NeRF (6 numbers per test view);
- the paper's Table 5 ablations (no CAD initialisation, no pose optimisation, no deformation),
  and G left out with D fitted to the silhouettes in its place (``preview``'s own setting);
- an oracle, "true cameras": the same job with every kept photo's retrieved camera replaced by
  the ground truth (``true_cameras``), poses held fixed. It measures what the networks and the
  preset's schedule reach with perfect cameras, and so how much of the gap to a PSNR target
  comes from the cameras and how much from the NeRF.

Which runs each mesh gets (``run_plan``): with ``--quick`` (the meshes of ``QUICK_MESHES``) or
``--meshes``, every run; over the whole evaluation set (``make bench``), the ablations and the
oracle on ``QUICK_MESHES`` and the full method on every mesh, with the two means reported apart.

With ``--seeds N`` every run is repeated with training seeds 0 to N-1 on the same datasets, and
the summary gives the mean over meshes and seeds and each seed's mean: training is
deterministic for a seed, but two seeds differ by a few tenths of a dB, which is the noise a
difference between ablations has to beat.

Usage: ``python -m benchmarks.bench_training [--quick] [--threads N] [--meshes NAME ...]
[--seeds N] [--runs NAME ...] [--exif-focal] [--preset P] [--device D] [--size N]``;
``--preset``/``--device``/``--size`` (default ``preview``, CPU, 128 px) give the GPU figure
with ``--preset standard --device cuda --size 256``; ``--runs`` keeps only the named runs (of
"full", the ablations and the oracle), as when one ablation is checked on more meshes;
``--exif-focal`` gives the photos their true focal length in EXIF, as a phone's photos have;
``--overrides JSON`` sets configuration values in every run (``'{"field.deform_freqs": 2}'``).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import math
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from benchmarks.bench_eval import Z_UP

if TYPE_CHECKING:
    from cadnerf_core.evaluation.evaluate import EvalReport
    from cadnerf_core.library.format import Library

ROOT = Path(__file__).resolve().parents[1]
EVAL = ROOT / ".." / "shared" / "eval" / "meshes"
LIBRARY = ROOT / "library_data" / "build"
ORBIT_FRAME = ROOT / "docs" / "orbit_frame.png"
QUICK_MESHES = ("Duck", "CesiumMilkTruck")
# The paper's full method and its Table 5 ablations, whatever the preset's own default. "no
# deformation": nothing deforms the density in phase two, whose poses are refined against the
# CAD shape (D learns in phase three), the paper's pipeline without its deformation. "no G":
# G left out but D fitted to the silhouettes in its place, the preset's own default since
# session 9 (until session 12 that was the "no deformation" row).
ABLATIONS: dict[str, dict[str, Any]] = {
    "full": {"use_deformation": True},
    "no CAD init": {"use_cad_init": False, "use_deformation": True},
    "no pose optimisation": {"optimise_poses": False, "use_deformation": True},
    "no deformation": {"use_deformation": False, "phase2.train_density": False},
    "no G (D fitted in phase two)": {"use_deformation": False},
}
ORACLE = "true cameras"
ORACLE_OVERRIDES: dict[str, Any] = {"optimise_poses": False, "use_deformation": True}
# Ablation runs skip what does not change their score: a 2-frame orbit, a coarse mesh.
LIGHT_EXPORT = {"export.orbit_frames": 2, "export.mesh_resolution": 16, "export.novel_views": 0}
TTA_STEPS = 100  # test-time pose refinement steps per test view (BARF: optim.test_iter)
IMAGE_SIZE = 128  # dataset side in pixels
TRAIN_VIEWS = 6
TEST_VIEWS = 12
SEED = 0
PRESET = "preview"
DEVICE = "cpu"
FOV_DEG = 40.0  # the photos' horizontal field of view: the library's own

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
    metrics = json.loads((Path(report.job_dir) / "metrics.json").read_text())
    return {"psnr": report.image.psnr,
            # The same cameras mapped by the camera centres alone (the protocol before
            # session 11): six noisy centres on a ring fix the frame only roughly.
            "psnr_centred": refined_test_psnr(report, 0, "centred", device),
            "psnr_tta": (refined_test_psnr(report, TTA_STEPS, device=device) if tta
                         else float("nan")),
            "rot_before": float(np.median(report.pose_retrieved.rotation_deg_per_view)),
            "rot_after": float(np.median(report.pose_refined.rotation_deg_per_view)),
            "kept": len(report.kept), "model_id": report.model_id,
            "train_psnr": metrics["mean_psnr"],
            # evaluate_dataset's wall time less the held-out renders: the whole job (writing
            # its photos, retrieval, training, exports), loading its model and the frame fit.
            "seconds": report.seconds - report.render_seconds}


def run_one(mesh: Path, work: Path, library: Library, name: str, overrides: dict[str, Any],
            tta: bool, oracle: bool = False, exif_focal: bool = False,
            fov_deg: float = FOV_DEG, views: int = TRAIN_VIEWS, preset: str = PRESET,
            device: str = DEVICE, size: int = IMAGE_SIZE) -> dict[str, Any]:
    """Render the dataset (once per mesh, ``size`` pixels square), run and score a job of
    ``preset`` with ``overrides`` on ``device`` through ``evaluate_dataset`` (with the true
    cameras for ``oracle``; the photos carrying their true focal length in EXIF, as a phone's
    do, with ``exif_focal``; the photos' field of view ``fov_deg``; ``views`` training
    photos), and add this benchmark's numbers."""
    from cadnerf_core.evaluation.dataset import render_dataset
    from cadnerf_core.evaluation.evaluate import evaluate_dataset

    dataset_dir = work / mesh.parent.name / "dataset"
    if not dataset_dir.exists():
        render_dataset(mesh, dataset_dir, views, size, seed=SEED,
                       test_views=TEST_VIEWS, up="z" if mesh.parent.name in Z_UP else "y",
                       fov_deg=fov_deg)
    job = work / mesh.parent.name / name.replace(" ", "_")
    with true_cameras(dataset_dir) if oracle else contextlib.nullcontext():
        report = evaluate_dataset(dataset_dir, views, library, preset=preset,
                                  overrides=overrides, job_dir=job, device=device,
                                  intrinsics="estimated", align="photometric",
                                  exif_focal=exif_focal)
    return score_report(report, tta, device)


def run_plan(meshes: list[Path], every_run_everywhere: bool,
             only: list[str] | None = None) -> list[tuple[Path, list[str]]]:
    """Which runs each mesh gets: every selected run (``only``, or all of ``ABLATIONS`` and
    the oracle) on every mesh with ``every_run_everywhere`` (``--quick`` or ``--meshes``);
    otherwise (the whole evaluation set, ``make bench``) the ablations and the oracle only on
    ``QUICK_MESHES`` and the full method on every mesh, which keeps the run near two hours on
    2 cores instead of five."""
    selected = [name for name in (*ABLATIONS, ORACLE) if only is None or name in only]
    plan = []
    for mesh in meshes:
        if every_run_everywhere or mesh.parent.name in QUICK_MESHES:
            plan.append((mesh, selected))
        elif "full" in selected:
            plan.append((mesh, ["full"]))
    return plan


def _table(rows: list[tuple[str, str, dict[str, Any]]]) -> list[str]:
    lines = ["| mesh | run | seed | retrieved | kept | job s | train PSNR | test PSNR | "
             "(centres mapping) | + test-time pose | rot err retrieval (median deg) | "
             "rot err refined |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for mesh, name, r in rows:
        lines.append(f"| {mesh} | {name} | {r['seed']} | {r['model_id']} | {r['kept']} | "
                     f"{r['seconds']:.0f} | "
                     f"{r['train_psnr']:.2f} | {r['psnr']:.2f} | {r['psnr_centred']:.2f} | "
                     f"{r['psnr_tta']:.2f} | "
                     f"{r['rot_before']:.1f} | {r['rot_after']:.1f} |")
    return lines


def _summary(rows: list[tuple[str, str, dict[str, Any]]]) -> list[str]:
    """Means over meshes and seeds; the per-seed means show how far a seed moves them."""
    lines = ["", "| run | mean test PSNR | per seed | (centres mapping) | (+ test-time pose) | "
             "mean rot err refined | mean job s |", "|---|---|---|---|---|---|---|"]
    for name in (*ABLATIONS, ORACLE):
        rs = [r for _, n, r in rows if n == name]
        if rs:
            seeds = sorted({r["seed"] for r in rs})
            per_seed = " / ".join(f"{np.mean([r['psnr'] for r in rs if r['seed'] == s]):.2f}"
                                  for s in seeds)
            lines.append(f"| {name} | {np.mean([r['psnr'] for r in rs]):.2f} | {per_seed} | "
                         f"{np.mean([r['psnr_centred'] for r in rs]):.2f} | "
                         f"{np.mean([r['psnr_tta'] for r in rs]):.2f} | "
                         f"{np.mean([r['rot_after'] for r in rs]):.1f} | "
                         f"{np.mean([r['seconds'] for r in rs]):.0f} |")
    return lines


def _summaries(rows: list[tuple[str, str, dict[str, Any]]],
               every_run_everywhere: bool) -> list[str]:
    """``_summary`` of all rows, or (the whole evaluation set, see ``run_plan``) one over
    ``QUICK_MESHES``, where every run was made, and one of the full method over every mesh."""
    if every_run_everywhere:
        return _summary(rows)
    table5 = [row for row in rows if row[0] in QUICK_MESHES]
    full = [row for row in rows if row[1] == "full"]
    return ["", f"Means over {' and '.join(QUICK_MESHES)}, where every run was made:",
            *_summary(table5), "",
            f"The full method over every mesh ({len(full)}):", *_summary(full)]


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


def run(quick: bool, threads: int | None = None, names: list[str] | None = None,
        seeds: int = 1, only: list[str] | None = None, exif_focal: bool = False,
        overrides: dict[str, Any] | None = None, fov_deg: float = FOV_DEG,
        first_seed: int = 0, views: int = TRAIN_VIEWS, preset: str = PRESET,
        device: str = DEVICE, size: int = IMAGE_SIZE) -> str:
    """The markdown section (see the module docstring); every run repeated with training
    seeds ``first_seed`` to ``first_seed + seeds - 1`` (the datasets stay the same);
    ``only``: the runs to keep (names of ``ABLATIONS`` or ``ORACLE``; all when None);
    ``exif_focal``: the photos carry their true focal length in EXIF; ``overrides``:
    configuration values applied to every run, under each run's own (dotted keys, as a job's
    config takes them); ``fov_deg``: the photos' horizontal field of view; ``views``: training
    photos per walk; ``preset``, ``device``: the jobs' preset and device ("cuda" for the
    GPU figures); ``size``: the photos' side in pixels."""
    import torch

    from cadnerf_core.library.format import load_library

    unknown = set(only or ()) - {*ABLATIONS, ORACLE}
    if unknown:
        raise ValueError(f"unknown runs {sorted(unknown)}; choose from {[*ABLATIONS, ORACLE]}")
    meshes = mesh_files(quick, names)
    if not meshes or not LIBRARY.is_dir():
        return "## Training\n\nSkipped: no ../shared/eval/meshes or no built library.\n"
    if threads:
        torch.set_num_threads(threads)
    library = load_library(LIBRARY)
    rows: list[tuple[str, str, dict[str, Any]]] = []
    orbit_note = ""
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for i, (mesh, wanted) in enumerate(run_plan(meshes, quick or names is not None, only)):
            for seed in range(first_seed, first_seed + seeds):
                runs = [(name, overrides, False) for name, overrides in ABLATIONS.items()]
                for name, own, oracle in [*runs, (ORACLE, ORACLE_OVERRIDES, True)]:
                    if name not in wanted:
                        continue
                    extra = {} if name == "full" and seed == 0 else LIGHT_EXPORT
                    label = name if seed == 0 else f"{name} seed {seed}"
                    result = run_one(mesh, work, library, label,
                                     {**(overrides or {}), **own, **extra, "seed": seed},
                                     tta=True,
                                     oracle=oracle, exif_focal=exif_focal, fov_deg=fov_deg,
                                     views=views, preset=preset, device=device, size=size)
                    rows.append((mesh.parent.name, name, {**result, "seed": seed}))
                    log.info("%s %s: %s", mesh.parent.name, label, result)
            if i == 0 and names is None and first_seed == 0 \
                    and (only is None or "full" in only):
                save_orbit_frame(work / mesh.parent.name / "full")
                orbit_note = ("An orbit frame of the first mesh's full run: "
                              "`docs/orbit_frame.png`.")
    flags = " --quick" if quick else ""
    flags += f" --threads {threads}" if threads else ""
    flags += f" --meshes {' '.join(names)}" if names else ""
    flags += f" --seeds {seeds}" if seeds > 1 else ""
    flags += f" --first-seed {first_seed}" if first_seed else ""
    flags += " --exif-focal" if exif_focal else ""
    flags += f" --fov {fov_deg:g}" if fov_deg != FOV_DEG else ""
    flags += f" --views {views}" if views != TRAIN_VIEWS else ""
    flags += f" --preset {preset}" if preset != PRESET else ""
    flags += f" --device {device}" if device != DEVICE else ""
    flags += f" --size {size}" if size != IMAGE_SIZE else ""
    flags += f" --overrides '{json.dumps(overrides)}'" if overrides else ""
    if only:
        flags += " --runs " + " ".join(f'"{name}"' if " " in name else name for name in only)
    last = first_seed + seeds - 1
    seed_text = f"{first_seed} to {last}" if seeds > 1 else f"{first_seed}"
    where = "CPU"
    if device != "cpu" and torch.cuda.is_available():
        where = f"GPU: {torch.cuda.get_device_name(0)}, torch {torch.__version__}"
    lines = [f"## Training (preset `{preset}`, {where})", "",
             f"Command: `.venv/bin/python -m benchmarks.bench_training{flags}` "
             f"(torch threads: {torch.get_num_threads()}). Datasets: `render_dataset` "
             f"{size} px, field of view {fov_deg:g} deg, {views} training views "
             f"in walking order, {TEST_VIEWS} held-out test views, seed {SEED}. "
             "Each run is executed and scored by "
             "`cadnerf_core.evaluation.evaluate.evaluate_dataset`, the evaluation benchmark's "
             "protocol: "
             "the held-out ground-truth cameras are mapped into the NeRF frame by the centred "
             "similarity (rotation and scale about the object's centre, fitted on the training "
             "cameras' centres), refined photometrically on the training photos (one rotation, "
             "translation and scale shared by all cameras, `evaluation.fit_frame`; no held-out "
             "image is used), rendered at the NeRF's estimated focal length and scored "
             "(mean PSNR over views). Centres mapping: the same without the photometric "
             "refinement (the protocol before session 11). + test-time pose: the same cameras "
             "and intrinsics, then "
             f"{TTA_STEPS} steps of per-view pose refinement with the NeRF frozen (BARF's "
             f"protocol). Training seeds: {seed_text} (same datasets). Rotation errors "
             "are medians over the kept photos after similarity "
             "(Umeyama) alignment of camera centres. Job s: the evaluation's wall time less "
             "the held-out renders (the whole job, loading its model and the evaluation's "
             "photometric frame fit). "
             f"{ORACLE} (an oracle, not the method): the full run with each kept photo's "
             "retrieved camera replaced by the ground truth (pose mapped into the CAD model's "
             "frame, true intrinsics), poses fixed; its retrieval column reads 0 since the "
             "true cameras are written back as the job's.", "",
             *_table(rows), *_summaries(rows, quick or names is not None), "",
             orbit_note, ""]
    return "\n".join(lines)


def main() -> None:
    """Print the section."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two meshes only")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--meshes", nargs="*", default=None, help="mesh folder names")
    parser.add_argument("--seeds", type=int, default=1,
                        help="repeat every run with training seeds 0..N-1 (the spread between "
                             "seeds is the noise an ablation's difference must beat)")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="the first training seed (seeds N..N+seeds-1)")
    parser.add_argument("--runs", nargs="*", default=None,
                        help=f"only these runs, of {[*ABLATIONS, ORACLE]}")
    parser.add_argument("--exif-focal", action="store_true",
                        help="the photos carry their true focal length in EXIF (a phone's do)")
    parser.add_argument("--overrides", type=json.loads, default=None,
                        help='JSON object of configuration values for every run, e.g. '
                             '\'{"retrieval.shared_focal": false}\'')
    parser.add_argument("--fov", type=float, default=FOV_DEG,
                        help="the photos' horizontal field of view in degrees (a phone's main "
                             "lens: about 65)")
    parser.add_argument("--views", type=int, default=TRAIN_VIEWS,
                        help="training photos per walk (the service takes 3 to 10)")
    parser.add_argument("--preset", default=PRESET, help="the jobs' preset")
    parser.add_argument("--device", default=DEVICE, help='training device ("cuda" for a GPU)')
    parser.add_argument("--size", type=int, default=IMAGE_SIZE,
                        help="side of the dataset's photos in pixels")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    print(run(args.quick, args.threads, args.meshes, max(1, args.seeds), args.runs,
              args.exif_focal, args.overrides, args.fov, max(0, args.first_seed),
              max(3, args.views), args.preset, args.device, args.size))  # noqa: T201 (the section is the command's output)


if __name__ == "__main__":
    main()

"""Training benchmark: whole jobs on synthetic datasets, test-view PSNR, poses, ablations.

The runs, meshes and tables live in ``benchmarks.training_plan``, the scores in
``benchmarks.training_scoring``. Each run is executed and scored by
``evaluation.evaluate.evaluate_dataset``, the protocol of the evaluation benchmark
(``benchmarks.bench_eval``), so both score held-out views the same way. For each mesh in
``../shared/eval/meshes``: ``render_dataset`` (128 px, 6 training views in walking order, 12
held-out test views, white background, seed 0); the 6 training views become the photos of a job
run by ``run_job`` (retrieval from the built library, three phases, orbit, mesh) with preset
``preview``; the held-out ground-truth cameras are mapped into the NeRF frame by the centred
similarity (rotation and scale about the object's centre, which both frames share, fitted on the
training cameras' centres) and that mapping refined on the training photos
(``evaluation.fit_frame``: one rotation, translation and scale for all cameras, fitted so the
NeRF reproduces the training photos from the mapped true training cameras), rendered at the
NeRF's estimated focal length and scored. On top of that report this benchmark adds:

- the test PSNR with the centres' mapping alone (no photometric refinement);
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
``--overrides JSON`` sets configuration values in every run (``'{"field.dir_freqs": 2}'``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from benchmarks.harness import (
    DEVICE,
    LIBRARY_DIR,
    PRESET,
    SEED,
    TEST_VIEWS,
    evaluate_walk,
    render_walk,
)
from benchmarks.harness import VIEWS as TRAIN_VIEWS
from benchmarks.lookalikes import Protocol
from benchmarks.results import Result, record, today
from benchmarks.training_plan import (
    ABLATIONS,
    FOV_DEG,
    IMAGE_SIZE,
    LIGHT_EXPORT,
    ORACLE,
    ORACLE_OVERRIDES,
    ORBIT_FRAME,
    TTA_STEPS,
    mesh_names,
    results_table,
    run_plan,
    stages_table,
    summaries,
)
from benchmarks.training_scoring import score_report, true_cameras

if TYPE_CHECKING:
    from cadnerf_core.library.format import Library

log = logging.getLogger(__name__)


def run_one(mesh: str, work: Path, library: Library, name: str, overrides: dict[str, Any],
            tta: bool, oracle: bool = False, exif_focal: bool = False,
            fov_deg: float = FOV_DEG, views: int = TRAIN_VIEWS, preset: str = PRESET,
            device: str = DEVICE, size: int = IMAGE_SIZE,
            protocol: Protocol = "leave-out") -> dict[str, Any]:
    """Render the dataset (once per mesh, ``size`` pixels square), run and score a job of
    ``preset`` with ``overrides`` on ``device`` through ``evaluate_dataset`` (with the true
    cameras for ``oracle``; the photos carrying their true focal length in EXIF, as a phone's
    do, with ``exif_focal``; the photos' field of view ``fov_deg``; ``views`` training
    photos; ``protocol``: the mesh's look-alikes left out of retrieval or not,
    ``benchmarks.lookalikes``), and add this benchmark's numbers."""
    dataset_dir = render_walk(mesh, work / mesh / "dataset", views, size=size, seed=SEED,
                              once=True, test_views=TEST_VIEWS, fov_deg=fov_deg)
    job = work / mesh / name.replace(" ", "_")
    with true_cameras(dataset_dir) if oracle else contextlib.nullcontext():
        report = evaluate_walk(dataset_dir, views, library, mesh, overrides, job,
                               protocol=protocol, preset=preset, device=device,
                               intrinsics="estimated", align="photometric",
                               exif_focal=exif_focal)
    return score_report(report, tta, device)


def record_gpu_job(rows: list[tuple[str, str, dict[str, Any]]], quick: bool,
                   names: list[str] | None) -> None:
    """The mean whole-job seconds of the full method's default runs on a GPU, as the README's
    figure."""
    seconds = [r["seconds"] for _, name, r in rows if name == "full"]
    if not seconds:
        return
    flags = (" --quick" if quick else "") + (f" --meshes {' '.join(names)}" if names else "")
    record(Result("preview_job_gpu", f"a `{PRESET}` job, {TRAIN_VIEWS} photos",
                  float(np.mean(seconds)), "s", 0, "one GPU",
                  f".venv/bin/python -m benchmarks.bench_training{flags} --device cuda "
                  "--runs full", today()))


def save_orbit_frame(job: Path) -> None:
    """The middle frame of a job's orbit video, as docs/orbit_frame.png."""
    import imageio_ffmpeg
    from PIL import Image

    from cadnerf_core.jobfolder import ORBIT_VIDEO, JobFolder

    reader = imageio_ffmpeg.read_frames(str(JobFolder(job).file(ORBIT_VIDEO)))
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
        device: str = DEVICE, size: int = IMAGE_SIZE,
        protocol: Protocol = "leave-out") -> str:
    """The markdown section (see the module docstring); every run repeated with training
    seeds ``first_seed`` to ``first_seed + seeds - 1`` (the datasets stay the same);
    ``only``: the runs to keep (names of ``ABLATIONS`` or ``ORACLE``; all when None);
    ``exif_focal``: the photos carry their true focal length in EXIF; ``overrides``:
    configuration values applied to every run, under each run's own (dotted keys, as a job's
    config takes them); ``fov_deg``: the photos' horizontal field of view; ``views``: training
    photos per walk; ``preset``, ``device``: the jobs' preset and device ("cuda" for the
    GPU figures); ``size``: the photos' side in pixels; ``protocol``: each mesh's look-alikes
    left out of the library (the headline) or not (``benchmarks.lookalikes``)."""
    import torch

    from cadnerf_core.library.format import load_library

    unknown = set(only or ()) - {*ABLATIONS, ORACLE}
    if unknown:
        raise ValueError(f"unknown runs {sorted(unknown)}; choose from {[*ABLATIONS, ORACLE]}")
    meshes = mesh_names(quick, names)
    if not meshes or not LIBRARY_DIR.is_dir():
        return "## Training\n\nSkipped: no ../shared/eval/meshes or no built library.\n"
    if threads:
        torch.set_num_threads(threads)
    library = load_library(LIBRARY_DIR)
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
                                     views=views, preset=preset, device=device, size=size,
                                     protocol=protocol)
                    rows.append((mesh, name, {**result, "seed": seed}))
                    log.info("%s %s: %s", mesh, label, result)
            if i == 0 and names is None and first_seed == 0 \
                    and (only is None or "full" in only):
                save_orbit_frame(work / mesh / "full")
                orbit_note = ("An orbit frame of the first mesh's full run: "
                              "`docs/orbit_frame.png`.")
    if device.startswith("cuda") and (preset, size, views, fov_deg) == (
            PRESET, IMAGE_SIZE, TRAIN_VIEWS, FOV_DEG) and not (overrides or exif_focal) \
            and protocol == "leave-out":
        record_gpu_job(rows, quick, names)
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
    flags += " --with-lookalike" if protocol != "leave-out" else ""
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
             f"Protocol: {protocol} (`benchmarks.lookalikes`: "
             + ("each mesh's look-alikes excluded from retrieval). "
                if protocol == "leave-out" else "the whole library). ") +
             "Each run is executed and scored by "
             "`cadnerf_core.evaluation.evaluate.evaluate_dataset`, the evaluation benchmark's "
             "protocol: "
             "the held-out ground-truth cameras are mapped into the NeRF frame by the centred "
             "similarity (rotation and scale about the object's centre, fitted on the training "
             "cameras' centres), refined photometrically on the training photos (one rotation, "
             "translation and scale shared by all cameras, `evaluation.fit_frame`; no held-out "
             "image is used), rendered at the NeRF's estimated focal length and scored "
             "(mean PSNR over views). Centres mapping: the same without the photometric "
             "refinement. + test-time pose: the same cameras "
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
             *results_table(rows), *summaries(rows, quick or names is not None), "",
             "Seconds per stage of each job (`metrics.json`, `timings_s`):", "",
             *stages_table(rows), "",
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
    parser.add_argument("--with-lookalike", action="store_true",
                        help="keep each mesh's look-alikes in the library (default: left out, "
                             "benchmarks.lookalikes)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    print(run(args.quick, args.threads, args.meshes, max(1, args.seeds), args.runs,
              args.exif_focal, args.overrides, args.fov, max(0, args.first_seed),
              max(3, args.views), args.preset, args.device, args.size,
              "with look-alike" if args.with_lookalike else "leave-out"))  # noqa: T201 (the section is the command's output)


if __name__ == "__main__":
    main()

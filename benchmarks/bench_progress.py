"""A ``preview`` job as a user's job runs: where its time goes, how its progress moves, and how
true its ETA is.

One job (a walk of 6 views of an evaluation mesh at 128 px, no EXIF, look-alikes left out, as
``bench_unseen``'s leave-out rows) runs alone on the machine with ``--threads`` torch threads.
Its reports go to the ETA model the workers use (``app.state.EtaModel``), starting from the
default stage table, and between reports the model is ticked every half second, as the
worker's cancel checks tick it; every change of the fraction is timed on the wall clock.

Figures: seconds per stage and per export part (``metrics.json``), the longest wall-clock wait
between two changes of the fraction in each stage, and the ETA given when the fraction first
reached a quarter against the seconds the job then took.

A second job is a user's: ``--capture NAME`` takes the first ``CAPTURE_PHOTOS`` photos of a real
capture of ``../shared/eval/captures`` as a phone would upload them (JPEGs enlarged to
``PHOTO_SIDE`` px on the longer side, 12 MP, each with its true focal length as EXIF, the
background left in for the job's own masks), with the capture's look-alikes left out.

Usage: ``python -m benchmarks.bench_progress [--mesh NAME] [--fov DEG] [--capture NAME]
[--threads N] [--set KEY=VALUE ...]``; QUICK (``make bench QUICK=1``) runs the evaluation
benchmark's cut-down schedule.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_unseen import WORK_DIR, make_plan
from benchmarks.harness import CAPTURES, LIBRARY_DIR, MESHES, PRESET, fov_walk, run_job
from benchmarks.lookalikes import exclude_overrides
from benchmarks.results import Result, cpu_cores, record, today

MESH = "ycb_mug"
FOV = 40.0
TICK_S = 0.5
CAPTURE = "temple_ring"
"""The user's job: a real walk of 10 photos about 36 degrees apart."""
CAPTURE_PHOTOS = 10
PHOTO_SIDE = 4000
"""Longer side of the uploaded photos (4000 x 3000: a phone's 12 MP)."""


class Recorder:
    """The worker's ETA model fed with a job's reports and ticked by a clock thread; every
    change of the fraction is kept as (wall seconds since the start, stage, fraction, ETA)."""

    def __init__(self, expected: dict[str, float]) -> None:
        from app.state import EtaModel

        self.eta = EtaModel(dict(expected))
        self.start = time.monotonic()
        self.trace: list[tuple[float, str, float, float]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()

    def _keep(self, moved: tuple[float, float] | None) -> None:
        if moved is None or self.eta.stage is None:
            return
        now = time.monotonic() - self.start
        if not self.trace or moved[0] > self.trace[-1][2] or self.eta.stage != self.trace[-1][1]:
            self.trace.append((now, self.eta.stage, moved[0], moved[1]))

    def report(self, stage: str, done: int, total: int) -> None:
        with self._lock:
            self._keep(self.eta.update(stage, done, total, time.monotonic()))

    def _ticks(self) -> None:
        while not self._stop.wait(TICK_S):
            with self._lock:
                self._keep(self.eta.tick(time.monotonic()))

    def __enter__(self) -> Recorder:
        threading.Thread(target=self._ticks, daemon=True).start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()


def phone_photos(capture: str, count: int, side: int, out: Path) -> list[Path]:
    """The first ``count`` photos of ``capture`` as a phone writes them: JPEGs of ``side`` px
    on the longer side, the focal length (scaled with them) in EXIF. Returns their paths."""
    import cv2
    from PIL import Image

    from cadnerf_core.evaluation.jobio import exif_with_focal

    folder = CAPTURES / capture
    frames = json.loads((folder / "cameras.json").read_text())["frames"][:count]
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, frame in enumerate(frames):
        with Image.open(folder / frame["image"]) as photo:
            rgb = np.asarray(photo.convert("RGB"))
        scale = side / max(rgb.shape[:2])
        big = cv2.resize(rgb, (round(rgb.shape[1] * scale), round(rgb.shape[0] * scale)),
                         interpolation=cv2.INTER_CUBIC)
        K = np.asarray(frame["K"], dtype=np.float64) * [[scale], [scale], [1.0]]
        path = out / f"{i:03d}.jpg"
        Image.fromarray(big).save(path, quality=92,
                                  exif=exif_with_focal(K, big.shape[1], big.shape[0]))
        paths.append(path)
    return paths


def measure(mesh: str, fov: float, quick: bool, threads: int, library_dir: Path,
            capture: str | None = None, settings: dict[str, Any] | None = None
            ) -> dict[str, Any]:
    """Run the job (the walk of ``mesh``, or ``capture``'s photos as a phone's) and return its
    timings, per-stage longest still bar and the quarter ETA."""
    import shutil

    import torch

    from app.state import default_stage_seconds
    from app.state.work import scaled, stage_work
    from cadnerf_core.config import internal_config
    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.evaluation.jobio import first_views, write_job
    from cadnerf_core.library.format import load_library
    from cadnerf_core.progress import Progress

    torch.set_num_threads(threads)
    library = load_library(library_dir)
    plan = make_plan(quick, [mesh], ["leave-out"], [fov])
    name = capture or mesh
    overrides = {**plan.overrides, **exclude_overrides(name, "leave-out"), "seed": 0,
                 **(settings or {})}
    job_dir = WORK_DIR / "progress_job"
    shutil.rmtree(job_dir, ignore_errors=True)
    config = internal_config(PRESET, overrides)
    photos = None
    if capture:
        photos = phone_photos(capture, CAPTURE_PHOTOS, PHOTO_SIDE, WORK_DIR / "phone_photos")
    else:
        walk = fov_walk(mesh, fov, WORK_DIR)
        write_job(job_dir, first_views(load_dataset(walk), plan.views), PRESET, overrides,
                  False)
    expected = scaled(default_stage_seconds(PRESET, "cpu"), stage_work(config))
    with Recorder(expected) as recorder:
        metrics = run_job(job_dir, library, photos=photos, config=config if capture else None,
                          progress=Progress(recorder.report)).metrics
        total = time.monotonic() - recorder.start
    return {"mesh": mesh, "fov": fov, "capture": capture, "photos": len(photos or []) or
            plan.views, "settings": settings or {}, "threads": threads, "total_s": total,
            "timings": metrics["timings_s"], "still": longest_still(recorder.trace),
            "quarter": quarter_eta(recorder.trace, total),
            "ops": op_profile(job_dir, library)}


def op_profile(job_dir: Path, library: Any, steps: int = 20, top: int = 8
               ) -> list[tuple[str, float, int]]:
    """``torch.profiler`` over ``steps`` phase-three steps of the finished job (its trained
    state, its photos, poses learning as in the pose window): the ``top`` operations by
    their own CPU time, as (name, share of the steps' CPU time in %, calls a step)."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    from cadnerf_core.nerf import phases
    from cadnerf_core.nerf.checkpoint import checkpoint_path, load_payload, restore_state
    from cadnerf_core.nerf.device import adam
    from cadnerf_core.nerf.grid_update import refresh_fine_grid
    from cadnerf_core.pipeline import read_job_config, run_intake, training_data
    from cadnerf_core.progress import Progress

    config = read_job_config(job_dir)
    intake = run_intake(job_dir, library, config, Progress())
    cpu = torch.device("cpu")
    data = training_data(intake, config, library.spec.margin, cpu)
    state = restore_state(load_payload(checkpoint_path(job_dir, 3)), cpu, config)
    params = [p for name, p in state.fields.named_parameters()
              if not name.startswith("background.")]
    optimizer = adam(params, config.phase3.lr, cpu)
    poses = adam(state.poses.optimizer_groups(config.phase3.pose_lr, config.phase2.focal_lr),
                 config.phase3.pose_lr, cpu)
    refresh_fine_grid(state)  # as phase three's culled passes use it
    phases.phase3_step(state, data, optimizer, poses)  # warm-up
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(steps):
            phases.phase3_step(state, data, optimizer, poses)
    events = [e for e in prof.key_averages() if e.self_cpu_time_total > 0]
    total = sum(e.self_cpu_time_total for e in events)
    events.sort(key=lambda e: e.self_cpu_time_total, reverse=True)
    return [(e.key, 100.0 * e.self_cpu_time_total / total, round(e.count / steps))
            for e in events[:top]]


def longest_still(trace: list[tuple[float, str, float, float]]) -> dict[str, float]:
    """Per stage, the longest wall-clock wait between two changes of the fraction."""
    out: dict[str, float] = {}
    for (before, _, _, _), (now, stage, _, _) in zip(trace, trace[1:], strict=False):
        out[stage] = max(out.get(stage, 0.0), now - before)
    return out


def quarter_eta(trace: list[tuple[float, str, float, float]], total: float) -> dict[str, float]:
    """The ETA when the fraction first reached 0.25, the seconds the job then took, and the
    error of the one against the other (%)."""
    at, _, _, eta = next(entry for entry in trace if entry[2] >= 0.25)
    actual = total - at
    return {"at_s": at, "eta_s": eta, "actual_s": actual,
            "error_pct": 100.0 * (eta - actual) / actual}


def command(result: dict[str, Any], quick: bool) -> str:
    """The command that measures ``result``'s job."""
    what = f"--capture {result['capture']}" if result.get("capture") else \
        f"--mesh {result['mesh']} --fov {result['fov']:g}"
    sets = "".join(f" --set {k}={json.dumps(v)}" for k, v in result.get("settings", {}).items())
    return (f"python -m benchmarks.bench_progress {what} --threads {result['threads']}"
            f"{sets}{' --quick' if quick else ''}")


def _job_words(result: dict[str, Any], quick: bool) -> str:
    """What the job was, in words."""
    schedule = "the cut-down QUICK schedule" if quick else "preset `preview`"
    settings = "".join(f", {k} = {json.dumps(v)}" for k, v in
                       result.get("settings", {}).items())
    if result.get("capture"):
        return (f"{schedule}{settings}, {result['photos']} photos of {result['capture']} as a "
                f"phone uploads them ({PHOTO_SIDE} px JPEGs with EXIF, backgrounds in), "
                "look-alikes left out")
    return (f"{schedule}{settings}, a walk of {result['photos']} views of {result['mesh']} at "
            f"{result['fov']:g} degrees, 128 px, look-alikes left out")


def section(result: dict[str, Any], quick: bool) -> str:
    """The markdown section of one measured job."""
    from benchmarks.run import cpu_summary

    timings = result["timings"]
    order = ["intake_s", "start_s", "phase1_s", "phase2_s", "phase3_s", "views_s", "orbit_s",
             "mesh_s", "bundle_s"]
    rows = [f"| {key[:-2]} | {timings[key]:.1f} |" for key in order if key in timings]
    still = result["still"]
    quarter = result["quarter"]
    return "\n".join([
        "## A preview job: time per stage, progress and ETA", "",
        f"Command: `{command(result, quick)}` ({cpu_summary()}, the job alone on the machine; "
        f"{_job_words(result, quick)}). Whole job {result['total_s']:.0f} s.", "",
        "| part | seconds |", "| --- | ---: |", *rows, "",
        "Longest wait between two moves of the progress bar, per stage (wall clock, the "
        "worker's ETA model ticked every half second): "
        + ", ".join(f"{stage} {seconds:.1f} s" for stage, seconds in still.items()) + ".", "",
        "Operations of a phase-three step (`torch.profiler`, 20 steps of the trained job, "
        "own CPU time):", "", "| operation | share of CPU time | calls a step |",
        "| --- | ---: | ---: |",
        *[f"| `{name}` | {share:.0f} % | {calls} |" for name, share, calls in result["ops"]],
        "",
        f"ETA when the bar first reached a quarter ({quarter['at_s']:.0f} s in): "
        f"{quarter['eta_s']:.0f} s; the job then took {quarter['actual_s']:.0f} s "
        f"({quarter['error_pct']:+.0f} %), from the default stage table scaled by the speed "
        "this job showed in its finished stages.", ""])


def record_job(result: dict[str, Any], quick: bool) -> None:
    """The whole job's seconds as the README's figure: the default jobs of a full run only
    (the walk of ``MESH``; the user's photos of ``CAPTURE``)."""
    if quick or result.get("settings"):
        return
    if result.get("capture") == CAPTURE:
        record(Result("preview_job_photos", f"a `preview` job, {result['photos']} phone "
                      "photos of 12 MP", result["total_s"], "s", 0, cpu_cores(),
                      f".venv/bin/{command(result, quick)}", today()))
    elif not result.get("capture") and result["mesh"] == MESH and result["fov"] == FOV:
        record(Result("preview_job_cpu", "a `preview` job, 6 photos", result["total_s"], "s", 0,
                      cpu_cores(), f".venv/bin/{command(result, quick)}", today()))


def run(quick: bool, library: Path | None = None) -> str:
    """``make bench``'s section."""
    if not MESHES.is_dir():
        return ("## A preview job: time per stage, progress and ETA\n\n"
                "Not run: `../shared/eval` is absent.\n")
    result = measure(MESH, FOV, quick, 2, library or LIBRARY_DIR)
    record_job(result, quick)
    return section(result, quick)


def main(argv: list[str] | None = None) -> int:
    import logging

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default=MESH)
    parser.add_argument("--fov", type=float, default=FOV)
    parser.add_argument("--capture", default=None,
                        help=f"a capture's photos as a phone's (default job: a walk; "
                             f"the README's user job: {CAPTURE})")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    parser.add_argument("--set", dest="settings", action="append", default=[],
                        help="a setting key=value on the preset (dotted key, JSON value)")
    args = parser.parse_args(argv)
    from cadnerf_cli.eval_cmd import parse_overrides

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    result = measure(args.mesh, args.fov, args.quick, args.threads, args.library,
                     args.capture, parse_overrides(args.settings))
    record_job(result, args.quick)
    print(json.dumps(result, indent=1), file=sys.stderr)
    sys.stdout.write(section(result, args.quick))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

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

Usage: ``python -m benchmarks.bench_progress [--mesh NAME] [--fov DEG] [--threads N]``; QUICK
(``make bench QUICK=1``) runs the evaluation benchmark's cut-down schedule.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks.bench_unseen import WORK_DIR, make_plan
from benchmarks.harness import LIBRARY_DIR, MESHES, PRESET, fov_walk, run_job
from benchmarks.lookalikes import exclude_overrides
from benchmarks.results import Result, cpu_cores, record, today

MESH = "ycb_mug"
FOV = 40.0
TICK_S = 0.5


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


def measure(mesh: str, fov: float, quick: bool, threads: int,
            library_dir: Path) -> dict[str, Any]:
    """Run the job and return its timings, per-stage longest still bar and the quarter ETA."""
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
    overrides = {**plan.overrides, **exclude_overrides(mesh, "leave-out"), "seed": 0}
    walk = fov_walk(mesh, fov, WORK_DIR)
    job_dir = WORK_DIR / "progress_job"
    shutil.rmtree(job_dir, ignore_errors=True)
    write_job(job_dir, first_views(load_dataset(walk), plan.views), PRESET, overrides, False)
    config = internal_config(PRESET, overrides)
    expected = scaled(default_stage_seconds(PRESET, "cpu"), stage_work(config))
    with Recorder(expected) as recorder:
        metrics = run_job(job_dir, library, progress=Progress(recorder.report)).metrics
        total = time.monotonic() - recorder.start
    return {"mesh": mesh, "fov": fov, "threads": threads, "total_s": total,
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
    return (f"python -m benchmarks.bench_progress --mesh {result['mesh']} --fov "
            f"{result['fov']:g} --threads {result['threads']}{' --quick' if quick else ''}")


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
        f"{'the cut-down QUICK schedule' if quick else 'preset `preview`'}, a walk of 6 views "
        f"of {result['mesh']} at {result['fov']:g} degrees, 128 px, look-alikes left out). "
        f"Whole job {result['total_s']:.0f} s.", "",
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
    """The whole job's seconds as the README's figure: the default job of a full run only."""
    if quick or result["mesh"] != MESH or result["fov"] != FOV:
        return
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
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    result = measure(args.mesh, args.fov, args.quick, args.threads, args.library)
    record_job(result, args.quick)
    print(json.dumps(result, indent=1), file=sys.stderr)
    sys.stdout.write(section(result, args.quick))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

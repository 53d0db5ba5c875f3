"""Objects the library has not seen: leave-out figures at three fields of view, and the levers.

For each mesh of ``../shared/eval/meshes`` a walk of 6 views (128 px, 12 held-out views on
white, seed 0) is rendered at horizontal fields of view of 40 (the library's), 55 and 70 degrees
(a phone's main lens), the object filling the same share of the frame. The photos carry no EXIF,
as a messaging app leaves them, so the focal length is the method's own estimate. Each walk
is a job of preset ``preview`` run and scored by ``evaluation.evaluate.evaluate_dataset`` (the
evaluation benchmark's protocol: held-out cameras mapped into the NeRF frame, refined on the
training photos, rendered at the job's focal length).

Rows:

- **leave-out** (the headline): the object's look-alikes (``benchmarks.lookalikes``) excluded
  from retrieval, every setting at its default;
- **with look-alike**: the whole library;
- the levers, each flipped from its default, leave-out: the focal length fixed at retrieval's
  estimate or learned with the poses (``phase2.focal_bound``), and the rest of ``LEVERS``;
- **with EXIF**: leave-out, the photos carrying their true focal length, as the files a phone
  wrote do (what giving the focal length is worth);
- **clockwise** (full runs): leave-out, a walk of the same seed taken clockwise. Seed 0 walks
  every mesh counter-clockwise, the way a job takes a walk whose direction neither silhouettes
  nor texture tell, so the leave-out rows alone never see that guess fail; the headline is
  over both.

QUICK: the evaluation benchmark's three quick meshes and its reduced schedule (48 px crops,
short phases, held-out views scored at 64 px); with look-alike at 40 degrees only, the levers at
40 and 70. Full: every mesh with ``preview`` itself; with look-alike at every field of view, the
levers on the quick meshes (on every mesh named with ``--meshes``).

Usage: ``python -m benchmarks.bench_unseen [--quick] [--meshes NAME ...] [--variants ...]
[--fovs DEG ...] [--views N] [--device cuda]`` prints the section (``--views 3`` and ``9``: the
paper's other Table 1 rows; several counts make one section each). Side by side: ``--workers K``
runs K jobs at a time from one queue (a machine with many cores or a GPU), or ``--shard I/N
--rows FILE`` in N processes, then ``--from-rows FILE --shards N`` makes the section from their
rows (``docs/bench_unseen_full.md``).
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing
import os
import shutil
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks.eval_tables import markdown_table
from benchmarks.harness import (
    LIBRARY_DIR,
    MESHES,
    PRESET,
    QUICK_MESHES,
    QUICK_OVERRIDES,
    SEED,
    SIZE,
    TEST_VIEWS,
    VIEWS,
    WORK_ROOT,
    eval_meshes,
    evaluate_walk,
    fov_walk,
    torch_threads,
)
from benchmarks.lookalikes import Protocol
from benchmarks.results import Result, cpu_cores, record, today

log = logging.getLogger(__name__)

WORK_DIR = WORK_ROOT / "bench_unseen"
FOVS = (40.0, 55.0, 70.0)

# Each lever: (label, the override that turns it off, the one that turns it on). The
# variant run is the one that differs from the default; the default is the leave-out row.
LEVERS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "focal": ("focal length learned with the poses", {"phase2.focal_bound": 1.0},
              {"phase2.focal_bound": 1.6}),
    "hypotheses": ("three start hypotheses, each a short silhouette fit",
                   {"retrieval.hypotheses": 1}, {"retrieval.hypotheses": 3}),
    "seeds": ("each hypothesis fitted from three seeds, the scores averaged",
              {"retrieval.hypothesis_seeds": 1}, {"retrieval.hypothesis_seeds": 3}),
    "mirror": ("the retrieved model's mirrored walk chosen only when it fits 0.01 IoU better",
               {"retrieval.mirror_margin": 0.0}, {"retrieval.mirror_margin": 0.01}),
    "prior": ("photos without EXIF taken for a 35 mm-equivalent lens (54 degrees)",
              {"retrieval.focal_35mm": None}, {"retrieval.focal_35mm": 35.0}),
    "poselr": ("the poses learned at 4e-3 in phases two and three, the start's fits at 2e-3 "
               "(off: 2e-3 throughout, the default)",
               {"phase2.pose_lr": 2e-3, "phase3.pose_lr": 2e-3},
               {"phase2.pose_lr": 4e-3, "phase3.pose_lr": 4e-3}),
}


@dataclass(frozen=True)
class Plan:
    """What one run of this benchmark does."""

    meshes: tuple[str, ...]
    overrides: dict[str, Any]
    lookalike_fovs: tuple[float, ...]
    lever_fovs: tuple[float, ...]
    lever_meshes: tuple[str, ...]
    eval_size: int | None
    variants: tuple[str, ...] | None = None  # only these rows (None: all)
    fovs: tuple[float, ...] = FOVS  # the fields of view rendered
    views: int = VIEWS  # photos in each walk (the paper's Table 1 rows: 3, 6, 9)
    quick: bool = False  # the QUICK plan (no clockwise rows unless asked for)


def make_plan(quick: bool, names: list[str] | None = None,
              variants: list[str] | None = None,
              fovs: list[float] | None = None, views: int = VIEWS) -> Plan:
    """The quick or the full plan (``names``: only these meshes; ``variants``: only these
    rows, of "leave-out", "with look-alike" and ``lever_variants``; ``fovs``: only these
    fields of view; ``views``: photos a walk)."""
    every = eval_meshes()
    only = tuple(variants) if variants else None
    chosen = tuple(float(f) for f in fovs) if fovs else FOVS

    def within(values: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(f for f in values if f in chosen)

    if quick:
        meshes = tuple(names or QUICK_MESHES)
        return Plan(meshes, dict(QUICK_OVERRIDES), within((40.0,)), within((40.0, 70.0)),
                    meshes, 64, only, chosen, views, quick=True)
    meshes = tuple(names or every)
    levered = meshes if names else tuple(m for m in meshes if m in QUICK_MESHES)
    return Plan(meshes, {}, chosen, chosen, levered, None, only, chosen, views)


def lever_variants() -> dict[str, tuple[str, dict[str, Any]]]:
    """Per lever, the variant that flips it from the configured default: name -> (label,
    overrides). A lever whose default is neither of its settings is run both ways."""
    from cadnerf_core.config import resolve_config

    defaults = resolve_config(PRESET).model_dump()
    out: dict[str, tuple[str, dict[str, Any]]] = {}
    for name, (label, off, on) in LEVERS.items():
        key, value = next(iter(off.items()))
        section, field = key.split(".")
        current = defaults[section][field]
        if current != value:
            out[f"{name}_off"] = (f"{label}: off", off)
        if current != next(iter(on.values())):
            out[f"{name}_on"] = (f"{label}: on", on)
    return out


def run_job(name: str, fov: float, variant: str, overrides: dict[str, Any],
            protocol: Protocol, plan: Plan, library: Any, work: Path,
            device: str = "cpu", exif: bool = False) -> dict[str, Any]:
    """One job, scored (``exif``: the photos carry their true focal length, as the files a
    phone wrote do). Returns its row (``error`` set when it failed)."""
    from cadnerf_core.jobfolder import JobFolder

    row: dict[str, Any] = {"mesh": name, "fov": fov, "variant": variant, "views": plan.views}
    config = {**plan.overrides, **overrides, "seed": SEED}
    try:
        walk = fov_walk(name, fov, work, plan.views,
                        direction=-1 if variant == CW_VARIANT else None)
        report = evaluate_walk(walk, plan.views, library, name, config,
                               walk.parent / f"job_{variant}_{walk.name}", protocol=protocol,
                               device=device, eval_size=plan.eval_size, exif_focal=exif)
    except Exception as exc:  # noqa: BLE001 - one failed job is a row, not a crash
        log.exception("%s %s at %g deg failed", name, variant, fov)
        return {**row, "error": f"{type(exc).__name__}: {exc}"}
    log.info("%s %s at %g deg: %.2f dB, %.1f deg, %.0f s", name, variant, fov,
             report.image.psnr, report.pose_refined.rotation_deg, report.seconds)
    fits = (JobFolder(report.job_dir).read_retrieval() or {}).get("hypotheses", [])
    return {**row, "model": report.model_id, "psnr": report.image.psnr,
            "rot": report.pose_refined.rotation_deg, "r_rot": report.pose_retrieved.rotation_deg,
            "focal_err": 100.0 * report.focal_error,
            "r_focal_err": 100.0 * report.focal_error_retrieved,
            "job_s": report.seconds - report.render_seconds, "hypotheses": len(fits),
            "fit_s": statistics.fmean(h["seconds"] for h in fits) if fits else None,
            "switched": any(h["chosen"] for h in fits[1:])}


# mesh, fov, variant, overrides, protocol, photos with EXIF
Job = tuple[str, float, str, dict[str, Any], Protocol, bool]
EXIF_VARIANT = "with EXIF"  # leave-out, the photos' true focal length in their EXIF
CW_VARIANT = "clockwise"  # leave-out, the walk taken clockwise (seed 0 walks counter-clockwise)
BOTH_WAYS = "leave-out, both ways"  # summary over the leave-out and clockwise jobs together


def job_list(plan: Plan) -> list[Job]:
    """Every job of the plan, in order."""
    levers = {k: v for k, v in lever_variants().items()
              if plan.variants is None or k in plan.variants}
    default = ("leave-out", "with look-alike") + (() if plan.quick else (CW_VARIANT,))
    wanted = plan.variants or default
    jobs: list[Job] = []
    for name in plan.meshes:
        for fov in plan.fovs:
            if "leave-out" in wanted:
                jobs.append((name, fov, "leave-out", {}, "leave-out", False))
            if fov in plan.lookalike_fovs and "with look-alike" in wanted:
                jobs.append((name, fov, "with look-alike", {}, "with look-alike", False))
            if CW_VARIANT in wanted:
                jobs.append((name, fov, CW_VARIANT, {}, "leave-out", False))
            if fov in plan.lever_fovs and name in plan.lever_meshes:
                jobs += [(name, fov, variant, overrides, "leave-out", False)
                         for variant, (_, overrides) in levers.items()]
                if plan.variants is None or EXIF_VARIANT in plan.variants:
                    jobs.append((name, fov, EXIF_VARIANT, {}, "leave-out", True))
    return jobs


def run_rows(plan: Plan, library: Any, work: Path, device: str = "cpu",
             shard: tuple[int, int] = (0, 1), rows_file: Path | None = None
             ) -> list[dict[str, Any]]:
    """The plan's jobs of one shard (every ``shard[1]``-th from ``shard[0]``), in order; each
    row is also appended to ``rows_file`` (JSON lines) as soon as its job ends."""
    rows = []
    index, count = shard
    for name, fov, variant, overrides, protocol, exif in job_list(plan)[index::count]:
        row = run_job(name, fov, variant, overrides, protocol, plan, library, work, device,
                      exif)
        rows.append(row)
        append_row(rows_file, row)
    return rows


def append_row(rows_file: Path | None, row: dict[str, Any]) -> None:
    """Append one job's row to ``rows_file`` (JSON lines) as soon as it ends (None: nowhere)."""
    if rows_file is not None:
        with rows_file.open("a") as f:
            f.write(json.dumps(row) + "\n")


LOG_FORMAT = "%(asctime)s %(process)d %(levelname)s %(name)s: %(message)s"
_WORKER: dict[str, Any] = {}  # a queue worker's library, loaded once per process


def _start_worker() -> None:
    """A queue worker's start: one torch thread, the library loaded once."""
    import torch

    from cadnerf_core.library.format import load_library

    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    torch.set_num_threads(1)
    _WORKER["library"] = load_library(LIBRARY_DIR)


def _queued_job(job: Job, plan: Plan, work: Path, device: str) -> dict[str, Any]:
    """One job in a queue worker, its walk rendered in the worker's own folder (two jobs of
    one walk never write it at once)."""
    name, fov, variant, overrides, protocol, exif = job
    return run_job(name, fov, variant, overrides, protocol, plan, _WORKER["library"],
                   work / f"worker{os.getpid()}", device, exif)


def rows_done(rows_file: Path | None) -> dict[tuple[str, float, str, int], dict[str, Any]]:
    """The rows a file already holds of jobs that ran (``--rows`` of a run cut short), by
    (mesh, fov, variant, views): a queue run with the same file runs only the others."""
    if rows_file is None or not rows_file.is_file():
        return {}
    done = {}
    for line in rows_file.read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            if "error" not in row:
                done[(row["mesh"], float(row["fov"]), row["variant"],
                      int(row.get("views", VIEWS)))] = row
    return done


def run_queue(jobs: list[tuple[Plan, Job]], work: Path, device: str, workers: int,
              rows_file: Path | None = None) -> list[dict[str, Any]]:
    """``jobs`` (each with its plan) run ``workers`` at a time from one queue, in fresh
    (spawned) processes, since torch must not run in a process that forks; each row appended
    to ``rows_file`` as its job ends. Returns the rows in the jobs' order."""
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_start_worker) as pool:
        futures = {pool.submit(_queued_job, job, plan, work, device): k
                   for k, (plan, job) in enumerate(jobs)}
        for future in as_completed(futures):
            k = futures[future]
            plan, job = jobs[k]
            try:
                row = future.result()
            except Exception as exc:  # noqa: BLE001 - a worker that died is a row, not a crash
                row = {"mesh": job[0], "fov": job[1], "variant": job[2], "views": plan.views,
                       "error": f"{type(exc).__name__}: {exc}"}
            rows[k] = row
            append_row(rows_file, row)
    return [row for row in rows if row is not None]


def summary_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per variant (and field of view, and all together): mean PSNR, median rotation error,
    mean |focal error|, mean job time over the jobs that ran; levers compared with the
    leave-out jobs of the same meshes and fields of view; with clockwise rows, also the
    leave-out and clockwise jobs together (``BOTH_WAYS``, the headline). Rows without a
    record of the start's fits (``fit_s``, ``switched``: taken from an older table) leave
    those columns empty."""
    done = [r for r in rows if "error" not in r]
    groups = [(v, [r for r in done if r["variant"] == v])
              for v in dict.fromkeys(r["variant"] for r in done)]
    if {"leave-out", CW_VARIANT} <= {v for v, _ in groups}:  # the headline: both ways round
        groups.append((BOTH_WAYS, [r for r in done
                                   if r["variant"] in ("leave-out", CW_VARIANT)]))
    out = []
    for variant, mine in groups:
        for fov in [*sorted({r["fov"] for r in mine}), None]:
            group = [r for r in mine if fov is None or r["fov"] == fov]
            pairs = {(r["mesh"], r["fov"]) for r in group}
            base = [r for r in done if r["variant"] == "leave-out"
                    and (r["mesh"], r["fov"]) in pairs]
            fits = [r["fit_s"] for r in group if r.get("fit_s") is not None]
            out.append({
                "fit_s": statistics.fmean(fits) if fits else None,
                "switched": sum(bool(r["switched"]) for r in group)
                if all("switched" in r for r in group) else None,
                "variant": variant, "fov": "all" if fov is None else f"{fov:g}",
                "jobs": len(group), "psnr": statistics.fmean(r["psnr"] for r in group),
                "base_psnr": statistics.fmean(r["psnr"] for r in base) if base else None,
                "rot": statistics.median(r["rot"] for r in group),
                "base_rot": statistics.median(r["rot"] for r in base) if base else None,
                "focal": statistics.fmean(abs(r["focal_err"]) for r in group),
                "job_s": statistics.fmean(r["job_s"] for r in group),
                "max_s": max(r["job_s"] for r in group)})
    return out


CPU_WHERE = "CPU, one torch thread, 2 shared cores"
FULL_POINTER = ("The full benchmark (every mesh, preset `preview` itself, run in shards): "
                "`docs/bench_unseen_full.md`.")


def record_headline(plan: Plan, rows: list[dict[str, Any]], command: str,
                    hardware: str) -> None:
    """The README's figures from a full run that walked every mesh both ways round
    (``BOTH_WAYS`` over every field of view): mean PSNR and median rotation error."""
    if len(rows) < len(job_list(plan)) or any("error" in r for r in rows):
        return  # a shard, or a run with failed jobs: not the whole benchmark
    both = [r for r in summary_rows(rows) if r["variant"] == BOTH_WAYS and r["fov"] == "all"]
    if not both:
        return
    jobs = both[0]["jobs"]
    conditions = f"leave-out, {jobs} jobs, {hardware}"
    record(Result("unseen_psnr", f"held-out view PSNR, {len(plan.meshes)} unseen meshes, "
                  f"{plan.views} photos at {SIZE} px, `{PRESET}`", both[0]["psnr"], "dB", 2,
                  conditions, command, today()))
    record(Result("unseen_rotation", "camera rotation error after refinement, same jobs",
                  both[0]["rot"], "degrees (median)", 1, conditions, command, today()))


def section(plan: Plan, rows: list[dict[str, Any]], seconds: float, quick: bool,
            names: list[str] | None, where: str = CPU_WHERE, extra_flags: str = "") -> str:
    """The markdown section (``where``: what ran the jobs; ``extra_flags``: the command's
    options beyond the plan's)."""
    flags = (" --quick" if quick else "") + (f" --meshes {' '.join(names)}" if names else "")
    if plan.variants:
        flags += " --variants " + " ".join(f'"{v}"' if " " in v else v for v in plan.variants)
    if plan.fovs != FOVS:
        flags += " --fovs " + " ".join(f"{f:g}" for f in plan.fovs)
    if plan.views != VIEWS:
        flags += f" --views {plan.views}"
    flags += extra_flags
    labels = {name: label for name, (label, _) in lever_variants().items()}
    lines = [
        "## Objects the library has not seen ("
        + ", ".join(plan.variants or ("leave-out", "with look-alike", "levers")) + "; "
        + ", ".join(f"{f:g}" for f in plan.fovs) + " deg"
        + ("" if plan.views == VIEWS else f"; {plan.views} views") + ")", "",
        f"Command: `.venv/bin/python -m benchmarks.bench_unseen{flags}` ({seconds:.0f} s, "
        f"{where}). Meshes: {', '.join(plan.meshes)}. Walks of "
        f"{plan.views} views at {SIZE} px, {TEST_VIEWS} held-out views, fields of view "
        f"{', '.join(f'{f:g}' for f in plan.fovs)} deg, no EXIF; preset `{PRESET}`"
        + (f" with `{plan.overrides}`" if plan.overrides else "")
        + (f"; held-out views scored at {plan.eval_size} px" if plan.eval_size else "")
        + ". leave-out: each mesh's look-alikes (`benchmarks.lookalikes`) excluded from "
        "retrieval; with look-alike: the whole library "
        f"(at {', '.join(f'{f:g}' for f in plan.lookalike_fovs)} deg). Levers, leave-out, "
        f"at {', '.join(f'{f:g}' for f in plan.lever_fovs)} deg on "
        f"{', '.join(plan.lever_meshes)}: "
        + "; ".join(f"`{k}` = {v}" for k, v in labels.items())
        + f"; `{EXIF_VARIANT}` = the photos carry their true focal length in EXIF (no lever: "
        "what a user gains by uploading the files the phone wrote)"
        + f"; `{CW_VARIANT}` = leave-out, a walk of the same seed taken clockwise (the other "
        "rows' walks go counter-clockwise, the way a job takes a walk whose direction it "
        "cannot tell)"
        + ". PSNR: mean over jobs; rotation error: median over jobs of each job's mean over "
        "its kept photos (after similarity alignment); focal error: the job's focal length "
        "against the truth, |%|, mean; job s: whole job (retrieval, training, export) "
        "without the held-out renders. `base` columns: the leave-out jobs of the same "
        "meshes and fields of view. s per hypothesis: mean wall time of one hypothesis's "
        "coarse fit; start switched: jobs whose best fit was not the retrieved walk.", "",
        markdown_table([("variant", "variant", 0), ("fov", "fov", 0), ("jobs", "jobs", 0),
                        ("PSNR", "psnr", 2), ("base PSNR", "base_psnr", 2),
                        ("rot. err. (deg)", "rot", 1), ("base rot.", "base_rot", 1),
                        ("|focal err.| %", "focal", 0), ("mean job s", "job_s", 0),
                        ("max job s", "max_s", 0), ("s per hypothesis", "fit_s", 1),
                        ("start switched", "switched", 0)], summary_rows(rows)), "",
        markdown_table([("mesh", "mesh", 0), ("fov", "fov", 0), ("variant", "variant", 0),
                        ("model", "model", 0), ("PSNR", "psnr", 2),
                        ("rot. retrieved", "r_rot", 1), ("rot. refined", "rot", 1),
                        ("focal err. retrieved %", "r_focal_err", 0),
                        ("focal err. %", "focal_err", 0), ("job s", "job_s", 0)],
                       [r for r in rows if "error" not in r]),
    ]
    if quick:
        lines += ["", FULL_POINTER]
    elif names is None and plan.views == VIEWS:
        record_headline(plan, rows, f".venv/bin/python -m benchmarks.bench_unseen{flags}",
                        "one GPU" if "--device cuda" in flags else cpu_cores())
    failed = [f"- {r['mesh']} {r['variant']} {r['fov']:g} deg: {r['error']}"
              for r in rows if "error" in r]
    if failed:
        lines += ["", "Failed jobs:", "", *failed]
    return "\n".join(lines) + "\n"


def run(quick: bool, names: list[str] | None = None, variants: list[str] | None = None,
        device: str = "cpu", shard: tuple[int, int] = (0, 1),
        rows_file: Path | None = None, fovs: list[float] | None = None,
        views: int | list[int] = VIEWS, workers: int = 1, threads: int = 1) -> str:
    """Run the benchmark (``variants``: only these rows; ``shard``: only every ``shard[1]``-th
    job from ``shard[0]``, for running shards side by side; ``rows_file``: JSON lines of the
    rows, for ``from_rows``; ``views``: photos a walk, one section per count; ``workers``: jobs
    at a time from one queue; ``threads``: torch threads of a job run one at a time, 2 for a
    job as a user's runs alone on 2 cores). Returns its markdown sections."""

    from cadnerf_core.library.format import load_library

    if not MESHES.is_dir():
        return "## Objects the library has not seen\n\nNot run: `../shared/eval` is absent.\n"
    plans = [make_plan(quick, names, variants, fovs, v)
             for v in ([views] if isinstance(views, int) else views)]
    work = WORK_DIR if shard[1] == 1 else WORK_DIR / f"shard{shard[0]}"
    shutil.rmtree(work, ignore_errors=True)
    index, count = shard
    done = rows_done(rows_file)
    start = time.perf_counter()
    if workers > 1:
        queue = [(plan, job) for plan in plans for job in job_list(plan)[index::count]
                 if (job[0], job[1], job[2], plan.views) not in done]
        rows = list(done.values()) + run_queue(queue, work, device, workers, rows_file)
    else:
        library = load_library(LIBRARY_DIR)
        with torch_threads(threads):  # 1 as bench_eval: no OpenMP oversubscription
            rows = [row for plan in plans
                    for row in run_rows(plan, library, work, device, shard, rows_file)]
    seconds = time.perf_counter() - start
    where = (CPU_WHERE if device == "cpu" and workers == 1 and threads == 1
             else f"CPU, {threads} torch threads, one job at a time" if device == "cpu"
             and workers == 1 and shard[1] == 1
             else device_words(device, max(workers, shard[1])))
    if len(plans) > 1:
        where += f"; one run for {' and '.join(str(p.views) for p in plans)} views"
    extra = ((f" --device {device}" if device != "cpu" else "")
             + (f" --workers {workers}" if workers > 1 else "")
             + (f" --threads {threads}" if threads != 1 and workers == 1 else ""))
    return "\n".join(section(plan, [r for r in rows if r.get("views", VIEWS) == plan.views],
                             seconds, quick, names, where, extra) for plan in plans)


def device_words(device: str, jobs_at_once: int) -> str:
    """What ran the jobs, in words, for a device other than the CPU."""
    import torch

    name = torch.cuda.get_device_name() if device.startswith("cuda") else device
    return f"{name}, {jobs_at_once} job(s) at a time, one torch thread each"


def from_rows(files: list[Path], quick: bool, names: list[str] | None,
              variants: list[str] | None, where: str, seconds: float, shards: int,
              device: str = "cuda", fovs: list[float] | None = None,
              views: int = VIEWS, workers: int = 1) -> str:
    """The section from the rows that shards wrote (``run(rows_file=...)``), in the plan's
    order; a job of the plan without a row is listed as not run (rows of walks of another
    ``views`` count are not the plan's). ``workers`` > 1: the rows came from one queue run
    (``--workers``) rather than from shards."""
    plan = make_plan(quick, names, variants, fovs, views)
    got = {}
    for file in files:
        for line in file.read_text().splitlines():
            if line.strip():
                row = json.loads(line)
                if row.get("views", VIEWS) == views:
                    got[(row["mesh"], float(row["fov"]), row["variant"])] = row
    rows = [got.get((name, fov, variant),
                    {"mesh": name, "fov": fov, "variant": variant, "error": "not run"})
            for name, fov, variant, *_ in job_list(plan)]
    how = (f" --workers {workers}" if workers > 1
           else f" --shard I/{shards} (I = 0..{shards - 1}, side by side)")
    return section(plan, rows, seconds, quick, names, where, f" --device {device}{how}")


def main(argv: list[str] | None = None) -> int:
    """Print the section."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--meshes", nargs="*", default=None, help="mesh folder names")
    parser.add_argument("--variants", nargs="*", default=None,
                        help='only these rows: "leave-out", "with look-alike", "with EXIF", '
                             '"clockwise" '
                             'and the levers flipped from their defaults (focal_on, '
                             'hypotheses_off, seeds_on, mirror_off, prior_on, poselr_on)')
    parser.add_argument("--fovs", type=float, nargs="*", default=None,
                        help=f"only these fields of view (of {', '.join(f'{f:g}' for f in FOVS)})")
    parser.add_argument("--views", type=int, nargs="+", default=[VIEWS],
                        help=f"photos a walk (default {VIEWS}; the paper's Table 1: 3, 6, 9); "
                             "several: one section each")
    parser.add_argument("--workers", type=int, default=1,
                        help="jobs at a time, from one queue, each in a process of its own")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch threads of a job when jobs run one at a time")
    parser.add_argument("--shard", default="0/1",
                        help="I/N: only every N-th job from the I-th (run N side by side)")
    parser.add_argument("--rows", type=Path, default=None,
                        help="append each job's row to this file (JSON lines); with "
                             "--workers, jobs whose rows it already holds are not run again")
    parser.add_argument("--from-rows", type=Path, nargs="*", default=None,
                        help="run nothing: the section from the shards' rows files")
    parser.add_argument("--where", default=CPU_WHERE, help="with --from-rows: what ran them")
    parser.add_argument("--seconds", type=float, default=0.0,
                        help="with --from-rows: the wall time of the shards")
    parser.add_argument("--shards", type=int, default=1,
                        help="with --from-rows: how many shards ran side by side")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    if args.from_rows:
        sys.stdout.write("\n".join(
            from_rows(args.from_rows, args.quick, args.meshes, args.variants, args.where,
                      args.seconds, args.shards, args.device, args.fovs, views, args.workers)
            for views in args.views))
        return 0
    index, count = (int(x) for x in args.shard.split("/"))
    if not 0 <= index < count:
        parser.error(f"--shard {args.shard}: I must be in 0..N-1")
    if args.fovs and not set(args.fovs) <= set(FOVS):
        parser.error(f"--fovs: each must be one of {', '.join(f'{f:g}' for f in FOVS)}")
    for views in args.views:
        if not 3 <= views <= 10:
            parser.error(f"--views {views}: a job takes 3 to 10 photos")
    if args.workers < 1:
        parser.error(f"--workers {args.workers}: at least 1")
    sys.stdout.write(run(args.quick, args.meshes, args.variants, args.device,
                         (index, count), args.rows, args.fovs, args.views, args.workers,
                         args.threads))
    return 0


if __name__ == "__main__":
    sys.exit(main())

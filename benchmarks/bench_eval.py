"""The paper's tables, measured on our own runs.

Datasets are rendered from the meshes in ``../shared/eval/meshes`` (128 px, 12 held-out test
views on white, the same held-out views for every number of input views). For each object:

- Table 1: novel-view PSNR / SSIM / LPIPS / Average for 3, 6, 9 input views, ours against the
  no-prior baseline (the same networks and retrieved poses, no phase one and no deformation,
  poses refined: the BARF-like setting).
- Table 3: pose errors (rotation in degrees, translation x 100) of the retrieved cameras and
  after refinement, ours against the baseline.
- Table 4: retrieval: the paper's Algorithm 1 against our exact DP solver.
- Table 5: ablations at 6 views: full, without CAD initialisation, without pose optimisation,
  without deformation (nothing deforms the density in phase two), without G but with D
  fitted to the silhouettes in its place (``preview``'s own setting), and the full method
  with the object's look-alikes in the library.

Every job but the last runs the leave-out protocol (``benchmarks.lookalikes``): the library
models made to resemble the object are excluded from retrieval, as for an object the library
has never seen.

QUICK: 3 objects and a reduced training schedule, sized to finish in a few minutes on 2 CPU
cores; full: every mesh with the ``preview`` preset.

Usage: ``python -m benchmarks.bench_eval [--quick]`` prints the section.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarks import eval_report
from benchmarks.eval_tables import with_mean
from benchmarks.harness import (
    DOCS,
    LIBRARY_DIR,
    MESHES,
    QUICK_MESHES,
    QUICK_OVERRIDES,
    WORK_ROOT,
    eval_meshes,
    evaluate_walk,
    render_walk,
    torch_threads,
)
from benchmarks.lookalikes import Protocol, excluded

log = logging.getLogger(__name__)

WORK_DIR = WORK_ROOT / "bench_eval"
PICTURES_DIR = DOCS / "bench"

# "ours" is the paper's full method, G included, whatever the preset's default (`preview`
# runs without G); each ablation removes one part of it.
VARIANTS: dict[str, dict[str, Any]] = {
    "ours": {"use_deformation": True},
    "baseline": {"use_cad_init": False, "use_deformation": False, "optimise_poses": True},
    "no_cad_init": {"use_cad_init": False, "use_deformation": True},
    "no_pose_opt": {"optimise_poses": False, "use_deformation": True},
    # Nothing deforms the density in phase two: the poses are refined against the CAD shape
    # (D learns in phase three), the paper's pipeline without its deformation.
    "no_deformation": {"use_deformation": False, "phase2.train_density": False},
    # G left out but D fitted to the silhouettes in phase two in its place: `preview`'s own
    # setting.
    "no_g": {"use_deformation": False},
}
# The full method with the object's look-alikes kept in the library (every other job leaves
# them out: ``benchmarks.lookalikes``).
VARIANTS["ours_lookalike"] = VARIANTS["ours"]
ABLATIONS = ("ours", "no_cad_init", "no_pose_opt", "no_deformation", "no_g", "ours_lookalike")


@dataclass(frozen=True)
class BenchPlan:
    """What one benchmark run does."""

    meshes: tuple[str, ...]
    views: tuple[int, ...]
    preset: str
    overrides: dict[str, Any] = field(default_factory=dict)
    ablation_views: int = 6
    size: int = 128
    test_views: int = 12
    seed: int = 0
    eval_size: int | None = None  # side of the scored held-out views (None: dataset size)


def make_plan(quick: bool) -> BenchPlan:
    """The plan of the quick or the full benchmark."""
    if quick:
        return BenchPlan(meshes=QUICK_MESHES, views=(3, 6, 9), preset="preview",
                         overrides=QUICK_OVERRIDES, eval_size=64)
    return BenchPlan(meshes=eval_meshes(), views=(3, 6, 9), preset="preview")


def prepare_datasets(name: str, plan: BenchPlan, work: Path) -> dict[int, Path]:
    """Render one dataset per number of views, all sharing the largest one's test split.

    The largest view count is rendered first with the held-out views; the others use its
    camera distance and get a copy of its test split, so every row is scored on the same views.

    Returns:
        view count -> dataset folder.
    """
    counts = sorted(set(plan.views) | {plan.ablation_views}, reverse=True)
    base = render_walk(name, work / name / f"v{counts[0]}", counts[0], size=plan.size,
                       seed=plan.seed, test_views=plan.test_views)
    distance = float(json.loads((base / "dataset.json").read_text())["distance"])
    out = {counts[0]: base}
    for n in counts[1:]:
        folder = render_walk(name, work / name / f"v{n}", n, size=plan.size, seed=plan.seed,
                             distance=distance)
        shutil.copytree(base / "test", folder / "test")
        shutil.copy2(base / "transforms_test.json", folder / "transforms_test.json")
        out[n] = folder
    return out


def _jobs(plan: BenchPlan) -> list[tuple[str, int]]:
    """(variant, views) pairs to run per object, without duplicates."""
    jobs = [(v, n) for n in plan.views for v in ("ours", "baseline")]
    jobs += [(v, plan.ablation_views) for v in ABLATIONS]
    return list(dict.fromkeys(jobs))


def run_job_once(name: str, variant: str, n: int, plan: BenchPlan, library: Any,
                 lpips_net: Any, work: Path, suffix: str = "") -> Any:
    """One evaluation job. Returns its EvalReport, or the exception it raised."""
    protocol: Protocol = "with look-alike" if variant == "ours_lookalike" else "leave-out"
    overrides = {**plan.overrides, **VARIANTS[variant], "seed": plan.seed}
    start = time.perf_counter()
    try:
        report = evaluate_walk(
            work / name / f"v{n}", n, library, name, overrides,
            work / name / f"job_{variant}_{n}{suffix}", protocol=protocol, preset=plan.preset,
            lpips_net=lpips_net, device="cpu", eval_size=plan.eval_size)
    except Exception as exc:  # noqa: BLE001 - one failed job is a row, not a crash
        log.exception("%s %s %d views failed", name, variant, n)
        return exc
    log.info("%s %s %d views: %.1f s", name, variant, n, time.perf_counter() - start)
    return report


def run_object(name: str, plan: BenchPlan, library: Any, lpips_net: Any,
               work: Path) -> dict[tuple[str, int], Any]:
    """Every job of one object. Returns (variant, views) -> EvalReport or the exception."""
    prepare_datasets(name, plan, work)
    return {(variant, n): run_job_once(name, variant, n, plan, library, lpips_net, work)
            for variant, n in _jobs(plan)}


def repeat_check(plan: BenchPlan, results: dict[str, dict[tuple[str, int], Any]],
                 library: Any, lpips_net: Any) -> str:
    """Re-run the first object's full method with the same seed and compare PSNR."""
    name, n = plan.meshes[0], plan.ablation_views
    first = results[name].get(("ours", n))
    again = run_job_once(name, "ours", n, plan, library, lpips_net, WORK_DIR, "_repeat")
    if isinstance(first, BaseException) or isinstance(again, BaseException) or first is None:
        return f"Repeatability: not measured ({name}, {n} views: a run failed)."
    delta = abs(first.image.psnr - again.image.psnr)
    verdict = "within" if delta <= 0.1 else "NOT within"
    return (f"Repeatability: {name}, full method, {n} views, seed {plan.seed}, run twice: "
            f"PSNR {first.image.psnr:.3f} and {again.image.psnr:.3f} dB "
            f"(difference {delta:.3f} dB, {verdict} 0.1 dB); rotation error "
            f"{first.pose_refined.rotation_deg:.3f} and {again.pose_refined.rotation_deg:.3f} deg.")


def run(quick: bool) -> str:
    """Run the evaluation benchmark. Returns its markdown section."""
    plan = make_plan(quick)
    if not MESHES.is_dir():
        return "## Evaluation (paper tables)\n\nNot run: `../shared/eval/meshes` is absent.\n"
    # The jobs are small: one thread each avoids OpenMP oversubscription, which made them
    # up to 8x slower on a shared 2-core machine (same results, measured).
    with torch_threads(1):
        return _run_plan(plan, quick)


def _run_plan(plan: BenchPlan, quick: bool) -> str:
    """Every object's jobs, retrieval rows and pictures, then the section."""
    from cadnerf_core.evaluation.metrics import load_lpips
    from cadnerf_core.library.format import load_library

    library = load_library(LIBRARY_DIR)
    weights = os.environ.get("CADNERF_LPIPS_WEIGHTS")
    lpips_net = load_lpips(Path(weights) if weights else None)
    shutil.rmtree(WORK_DIR, ignore_errors=True)
    start = time.perf_counter()
    results: dict[str, dict[tuple[str, int], Any]] = {}
    retrieval_rows = []
    for name in plan.meshes:
        results[name] = run_object(name, plan, library, lpips_net, WORK_DIR)
        retrieval_rows.append(eval_report.retrieval_row(name, WORK_DIR / name /
                                                        f"v{plan.ablation_views}", library,
                                                        excluded(name)))
        eval_report.save_pictures(name, results[name].get(("ours", plan.ablation_views)),
                                  PICTURES_DIR)
    repeat = repeat_check(plan, results, library, lpips_net)
    return eval_report.section(plan, results, with_mean(retrieval_rows, "object"),
                               lpips_net is not None, time.perf_counter() - start, quick,
                               repeat)


def main(argv: list[str] | None = None) -> int:
    """Print the section (``--quick`` for the reduced run)."""
    parser = argparse.ArgumentParser(description="CAD-NeRF evaluation benchmark")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    sys.stdout.write(run(args.quick))
    return 0


if __name__ == "__main__":
    sys.exit(main())

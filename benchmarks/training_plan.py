"""The training benchmark's runs and tables: which meshes, which runs on each, the fixed
dataset settings, and the markdown tables of the results (``benchmarks.bench_training``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from benchmarks.harness import DOCS, LIBRARY_FOV, SIZE, eval_meshes

ORBIT_FRAME = DOCS / "orbit_frame.png"
QUICK_MESHES = ("Duck", "CesiumMilkTruck")  # the paper's Table 5 meshes
# The paper's full method and its Table 5 ablations, whatever the preset's own default. "no
# deformation": nothing deforms the density in phase two, whose poses are refined against the
# CAD shape (D learns in phase three), the paper's pipeline without its deformation. "no G":
# G left out but D fitted to the silhouettes in its place, the `preview` preset's own setting.
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
IMAGE_SIZE = SIZE  # dataset side in pixels
FOV_DEG = LIBRARY_FOV  # the photos' horizontal field of view: the library's own


def mesh_names(quick: bool, names: list[str] | None = None) -> list[str]:
    """The evaluation set's meshes (``QUICK_MESHES`` with ``quick``, or those of ``names``),
    in the set's order."""
    wanted = names or (list(QUICK_MESHES) if quick else None)
    return [name for name in eval_meshes() if wanted is None or name in wanted]


def run_plan(meshes: list[str], every_run_everywhere: bool,
             only: list[str] | None = None) -> list[tuple[str, list[str]]]:
    """Which runs each mesh gets: every selected run (``only``, or all of ``ABLATIONS`` and
    the oracle) on every mesh with ``every_run_everywhere`` (``--quick`` or ``--meshes``);
    otherwise (the whole evaluation set, ``make bench``) the ablations and the oracle only on
    ``QUICK_MESHES`` and the full method on every mesh, which keeps the run near two hours on
    2 cores instead of five."""
    selected = [name for name in (*ABLATIONS, ORACLE) if only is None or name in only]
    plan = []
    for mesh in meshes:
        if every_run_everywhere or mesh in QUICK_MESHES:
            plan.append((mesh, selected))
        elif "full" in selected:
            plan.append((mesh, ["full"]))
    return plan


def results_table(rows: list[tuple[str, str, dict[str, Any]]]) -> list[str]:
    """One markdown row per (mesh, run, seed): the benchmark's numbers."""
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


STAGES = ["intake", "start", "phase1", "phase2", "phase3", "views", "orbit", "mesh", "bundle"]


def stages_table(rows: list[tuple[str, str, dict[str, Any]]]) -> list[str]:
    """Where each job's time went (``metrics.json``'s ``timings_s``): intake (photos, masks,
    retrieval), start (the hypotheses' silhouette fits), the three phases, and the export's
    parts; "other" is the job s column less these (loading, the frame fit, writing)."""
    lines = ["| mesh | run | seed | " + " | ".join(STAGES) + " | other |",
             "|---|---|---|" + "---:|" * (len(STAGES) + 1)]
    for mesh, name, r in rows:
        stages = r.get("stages", {})
        known = [stages.get(s) for s in STAGES]
        other = r["seconds"] - sum(v for v in known if v is not None)
        cells = " | ".join("" if v is None else f"{v:.1f}" for v in known)
        lines.append(f"| {mesh} | {name} | {r['seed']} | {cells} | {other:.1f} |")
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


def summaries(rows: list[tuple[str, str, dict[str, Any]]],
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

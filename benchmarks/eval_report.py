"""Tables and pictures of the evaluation benchmark, from its EvalReports."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.eval_figures import save_camera_plot, save_strip
from benchmarks.eval_tables import Row, markdown_table, with_mean, worst

log = logging.getLogger(__name__)

Results = dict[str, dict[tuple[str, int], Any]]  # object -> (variant, views) -> report | error
VARIANT_LABELS = {"ours": "full (ours)", "baseline": "no prior (BARF-like)",
                  "no_cad_init": "w/o CAD init", "no_pose_opt": "w/o pose optimisation",
                  "no_deformation": "w/o deformation",
                  "no_g": "w/o G, D fitted in phase two",
                  "ours_lookalike": "full, look-alike in the library"}


def _ok(report: Any) -> bool:
    return report is not None and not isinstance(report, BaseException)


def _image_cells(report: Any, prefix: str) -> Row:
    if not _ok(report):
        return {}
    img = report.image
    return {f"{prefix}psnr": img.psnr, f"{prefix}ssim": img.ssim, f"{prefix}lpips": img.lpips,
            f"{prefix}avg": img.average}


def _pose_cells(report: Any, prefix: str) -> Row:
    if not _ok(report):
        return {}
    return {f"{prefix}rot": report.pose_refined.rotation_deg,
            f"{prefix}trans": report.pose_refined.translation_x100}


def _failures(results: Results) -> list[str]:
    lines = []
    for name, runs in results.items():
        for (variant, n), report in runs.items():
            if isinstance(report, BaseException):
                lines.append(f"- {name}, {variant}, {n} views: FAILED "
                             f"`{type(report).__name__}: {report}`")
    return lines


def _by_views(rows_for: dict[int, list[Row]]) -> list[Row]:
    """Per-object rows of each view count followed by that count's mean row."""
    out: list[Row] = []
    for n, rows in sorted(rows_for.items()):
        for row in with_mean(rows, "object"):
            out.append({**row, "views": n})
    return out


def table1(results: Results, views: tuple[int, ...]) -> str:
    """Novel views: ours against the no-prior baseline, per object and view count."""
    rows_for: dict[int, list[Row]] = {}
    for n in views:
        rows_for[n] = [{"object": name, **_image_cells(runs.get(("ours", n)), "o_"),
                        **_image_cells(runs.get(("baseline", n)), "b_")}
                       for name, runs in results.items()]
    cols = [("object", "object", 0), ("views", "views", 0),
            ("PSNR ours", "o_psnr", 2), ("PSNR base", "b_psnr", 2),
            ("SSIM ours", "o_ssim", 3), ("SSIM base", "b_ssim", 3),
            ("LPIPS ours", "o_lpips", 3), ("LPIPS base", "b_lpips", 3),
            ("Avg ours", "o_avg", 3), ("Avg base", "b_avg", 3)]
    return markdown_table(cols, _by_views(rows_for))


def table3(results: Results, views: tuple[int, ...]) -> str:
    """Pose errors: retrieved (before refinement), refined by ours and by the baseline."""
    rows_for: dict[int, list[Row]] = {}
    for n in views:
        rows = []
        for name, runs in results.items():
            ours = runs.get(("ours", n))
            row: Row = {"object": name, **_pose_cells(ours, "o_"),
                        **_pose_cells(runs.get(("baseline", n)), "b_")}
            if ours is not None and _ok(ours):
                row.update(r_rot=ours.pose_retrieved.rotation_deg,
                           r_trans=ours.pose_retrieved.translation_x100,
                           discarded=len(ours.discarded))
            rows.append(row)
        rows_for[n] = rows
    cols = [("object", "object", 0), ("views", "views", 0),
            ("rot retrieved", "r_rot", 2), ("rot ours", "o_rot", 2), ("rot base", "b_rot", 2),
            ("trans retrieved", "r_trans", 2), ("trans ours", "o_trans", 2),
            ("trans base", "b_trans", 2), ("discarded", "discarded", 1)]
    return markdown_table(cols, _by_views(rows_for))


def table5(results: Results, n: int, variants: tuple[str, ...]) -> str:
    """Ablations at ``n`` views: per object and variant, then the mean of each variant."""
    rows: list[Row] = []
    for variant in variants:
        per = []
        for name, runs in results.items():
            rep = runs.get((variant, n))
            per.append({"object": name, "variant": VARIANT_LABELS[variant],
                        **_image_cells(rep, ""), **_pose_cells(rep, "")})
        rows += [{**r, "variant": VARIANT_LABELS[variant]} for r in with_mean(per, "object")]
    cols = [("object", "object", 0), ("variant", "variant", 0), ("PSNR", "psnr", 2),
            ("SSIM", "ssim", 3), ("LPIPS", "lpips", 3), ("Avg", "avg", 3),
            ("rot (deg)", "rot", 2), ("trans x100", "trans", 2)]
    return markdown_table(cols, rows)


def table4(rows: list[Row]) -> str:
    """Retrieval: the paper's Algorithm 1 against our DP solver."""
    cols = [("object", "object", 0), ("model", "model", 0),
            ("rot paper (deg)", "paper_rot", 2), ("rot DP (deg)", "dp_rot", 2),
            ("discarded paper", "paper_discarded", 1), ("discarded DP", "dp_discarded", 1),
            ("solver paper (ms)", "paper_ms", 2), ("solver DP (ms)", "dp_ms", 2),
            ("same poses", "same", 0)]
    return markdown_table(cols, rows)


def _solver_ms(iou: np.ndarray, library: Any, config: Any, repeats: int = 5) -> float:
    """Median wall time of one pose solve on one model's IoU table, in milliseconds."""
    from cadnerf_core.retrieval.scoring import azimuth_bins
    from cadnerf_core.retrieval.walks import solve_poses

    az_index = azimuth_bins(library.az_el, library.spec.n_azimuths)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        solve_poses(iou, az_index, library.spec.n_azimuths, config)
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1000.0)


def retrieval_row(name: str, dataset_dir: Path, library: Any,
                  exclude: tuple[str, ...] = ()) -> Row:
    """Table 4 row: both pose solvers on one dataset's photos (model, rotation error, time),
    the ``exclude``d library models left out.

    The rotation error is measured on the kept photos after similarity alignment; the time is
    the solver's alone (the IoU table and the model vote are shared by both).
    """
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.evaluation.metrics import pose_metrics
    from cadnerf_core.intake.photos import canonical_masks
    from cadnerf_core.retrieval.scoring import iou_table
    from cadnerf_core.retrieval.search import retrieve

    ds = load_dataset(dataset_dir)
    crops, _ = canonical_masks(list(ds.masks), library.spec.silhouette_size, library.spec.margin)
    iou = iou_table(crops, library.silhouettes)
    row: Row = {"object": name}
    views = {}
    for solver in ("paper", "dp"):
        config = RetrievalConfig(solver=solver, exclude_models=exclude)
        result = retrieve(list(ds.masks), ds.names, library, config,
                          images=list(ds.images))
        kept = [m for m in result.matches if not m.discarded]
        idx = [m.index for m in kept]
        if len(kept) >= 3:
            pm = pose_metrics(np.stack([m.c2w for m in kept]), ds.c2w[idx])
            row[f"{solver}_rot"] = pm.rotation_deg
        row["model"] = result.model_id
        row[f"{solver}_discarded"] = len(result.matches) - len(kept)
        row[f"{solver}_ms"] = _solver_ms(iou[:, library.index(result.model_id)], library,
                                         config)
        views[solver] = [-1 if m.discarded else m.view for m in result.matches]
    row["same"] = "yes" if views["paper"] == views["dp"] else "no"
    return row


def cost_table(results: Results) -> str:
    """Mean seconds and peak memory per phase over all successful jobs.

    Peak memory is the process's resident-set peak so far (it never goes down), as the
    pipeline records it.
    """
    phases: dict[str, list[dict[str, float]]] = {}
    totals = []
    for runs in results.values():
        for report in runs.values():
            if _ok(report):
                totals.append(report.seconds)
                for phase, values in report.phases.items():
                    phases.setdefault(phase, []).append(values)
                phases.setdefault("eval render", []).append({"seconds": report.render_seconds})
    rows: list[Row] = []
    for phase, values in phases.items():
        row: Row = {"phase": phase}
        for key in sorted({k for v in values for k in v}):
            row[key] = float(np.mean([v[key] for v in values if key in v]))
        rows.append(row)
    keys = sorted({k for r in rows for k in r if k != "phase"}, key=lambda k: (k != "seconds", k))
    cols = [("phase", "phase", 0), *[(k, k, 2) for k in keys]]
    head = f"{len(totals)} jobs, mean wall time per job {np.mean(totals) if totals else 0:.1f} s."
    return head + "\n\n" + markdown_table(cols, rows)


def _read_rgb(path: Path) -> np.ndarray:
    """A PNG as float RGB in [0, 1], RGBA composited on white."""
    from PIL import Image

    with Image.open(path) as image:
        pixels = np.asarray(image.convert("RGBA"), dtype=np.float32) / 255.0
    alpha = pixels[..., 3:]
    return pixels[..., :3] * alpha + (1.0 - alpha)


def save_pictures(name: str, report: Any, folder: Path) -> list[Path]:
    """The strip and the camera plot of one object's full run (nothing when it failed).

    Returns:
        The pictures written.
    """
    if not _ok(report):
        return []
    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.jobfolder import JobFolder

    inputs = [_read_rgb(p.path) for p in JobFolder(report.job_dir).photos()]
    test = load_dataset(report.dataset).test
    assert test is not None
    picks = sorted({0, len(report.renders) // 2})
    held_out = [(test.images[i], _read_rgb(Path(report.renders[i]))) for i in picks]
    cams = {k: np.asarray(v, dtype=np.float64) for k, v in report.cameras.items()}
    return [save_strip(folder / f"{name}_views.png", inputs, held_out),
            save_camera_plot(folder / f"{name}_cameras.png", cams["gt"], cams["retrieved"],
                             cams["refined"])]


def _worst_line(results: Results, n: int) -> str:
    rows = [{"object": name, "psnr": runs[("ours", n)].image.psnr,
             "rot": runs[("ours", n)].pose_refined.rotation_deg,
             "r_rot": runs[("ours", n)].pose_retrieved.rotation_deg,
             "model": runs[("ours", n)].model_id}
            for name, runs in results.items() if _ok(runs.get(("ours", n)))]
    bad = worst(rows, "psnr")
    if bad is None:
        return ""
    return (f"Worst object at {n} views (lowest PSNR, ours): **{bad['object']}**, "
            f"{bad['psnr']:.2f} dB, retrieved model `{bad['model']}`, rotation error "
            f"{bad['r_rot']:.1f} deg retrieved -> {bad['rot']:.1f} deg refined.")


def section(plan: Any, results: Results, retrieval_rows: list[Row], has_lpips: bool,
            seconds: float, quick: bool, repeat: str = "") -> str:
    """The benchmark's markdown section."""
    from cadnerf_core.evaluation.metrics import LPIPS_MISSING

    n = plan.ablation_views
    mode = "quick" if quick else "full"
    lines = [
        "## Evaluation: the paper's tables on our own runs",
        "",
        f"Command: `.venv/bin/python -m benchmarks.bench_eval{' --quick' if quick else ''}` "
        f"({mode}; {seconds:.0f} s). Objects: {', '.join(plan.meshes)}. Datasets rendered "
        f"from `../shared/eval/meshes` at {plan.size} px, {plan.test_views} held-out views on "
        f"white (the same for every view count), seed {plan.seed}. Preset `{plan.preset}`"
        + (f" with overrides `{plan.overrides}`" if plan.overrides else "") + ", CPU. "
        "Translation errors x 100 in units of the object's bounding sphere (radius 1); pose "
        "errors after a similarity (Umeyama) alignment of camera centres, as BARF and the paper. "
        "Held-out views: the ground-truth cameras mapped into the NeRF's frame by the rotation "
        "and scale about the object's centre that best map the ground-truth training centres "
        "onto the refined ones, then refined on the training photos (one rotation, "
        "translation and scale for all cameras, fitted so that the NeRF reproduces the "
        "training photos from them; no held-out image used), rendered with the NeRF's own "
        "focal length"
        + (f", scored at {plan.eval_size} px (ground truth area-averaged)."
           if plan.eval_size else ".")
        + " Protocol: leave-out (each object's look-alikes, `benchmarks.lookalikes`, excluded "
        "from retrieval) in every row but Table 5's `full, look-alike in the library`.",
        "",
        "" if has_lpips else f"LPIPS and Average: not computed ({LPIPS_MISSING}).",
        "",
        "### Table 1: novel views (ours vs no-prior baseline)",
        "",
        table1(results, plan.views),
        "",
        "### Table 3: camera poses (rotation deg, translation x100)",
        "",
        table3(results, plan.views),
        "",
        "### Table 4: retrieval, the paper's Algorithm 1 vs our DP solver",
        "",
        f"On the {n}-view photos of each object; rotation error of the retrieved cameras.",
        "",
        table4(retrieval_rows),
        "",
        f"### Table 5: ablations at {n} views",
        "",
        table5(results, n, ("ours", "no_cad_init", "no_pose_opt", "no_deformation", "no_g",
                            "ours_lookalike")),
        "",
        "### Cost per phase (time in s, peak memory in MiB)",
        "",
        cost_table(results),
        "",
        _worst_line(results, n),
        "",
        repeat,
        "",
        "### Pictures",
        "",
    ]
    for name in plan.meshes:
        lines += [f"- {name}: ![views](bench/{name}_views.png) "
                  f"![cameras](bench/{name}_cameras.png)"]
    failures = _failures(results)
    if failures:
        lines += ["", "### Failed jobs", "", *failures]
    return "\n".join(lines) + "\n"

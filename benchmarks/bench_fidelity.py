"""Fidelity on real captures: held-out photos at 512 px inside the object's mask, from the
field and from the textured mesh.

Each capture of ``../shared/eval/captures`` (photos round a real object, reference cameras from
its own calibration or a COLMAP/Bundler reconstruction over many frames) loses two of its
photos (``held_out_frames``: a third and two thirds of the way round, so that kept photos lie
on both sides); a ``preview`` job runs on the others, as ``cadnerf eval CAPTURE --hold-out
... --exif-focal --mesh --eval-size 512`` runs it (``evaluation.evaluate.evaluate_dataset``),
each photo's true focal length given as EXIF, so that the figure is about rendering rather than
the focal length. Each held-out reference camera is brought into the job's frame by a
similarity of the kept photos' reference cameras onto the job's, refined photometrically on the
kept photos (``evaluation.frame.fit_frame``: one 7-number correction for every camera, fitted
from two starts, rotation and scale about the object's centre where the optical axes meet, and
the free similarity of the camera centres; the one that reproduces the kept photos better is
kept; the held-out photos play no part), then refined on its own photo with the field frozen,
as BARF and SPARF evaluate (``evaluation.frame.refine_view``: 6 numbers per view). Rendered at
512 px on the longer side and scored inside the photo's mask (the capture's own; found by the
job's background removal where the capture has none): PSNR, SSIM (scikit-image's map averaged
in the mask), LPIPS where its weights are on disk. Scored twice: rendered from the field, and
from the exported textured ``mesh.glb`` (unlit: its texture is baked). Beside them, the
camera's error: the kept cameras' rotation error against the references (mean, after
similarity alignment), how far the frame fit moved the held-out camera from where the camera
centres put it, and how far its own refinement then moved it. The held-out views as rendered
stay in ``WORK_DIR/renders/<capture>``.

QUICK: ``QUICK_CAPTURES``; full: every capture.

Usage: ``python -m benchmarks.bench_fidelity [--quick] [--captures NAME ...] [--rows FILE]
[--set KEY=VALUE ...]`` (``--set``: a setting on the preset, to compare a lever; ``--rows``
keeps each finished capture's row in a JSON file and skips those already there).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import shutil
import statistics
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import (
    ABSENT,
    CAPTURES,
    DEVICE,
    LIBRARY_DIR,
    PRESET,
    WORK_ROOT,
    section_head,
    torch_threads,
)
from benchmarks.lookalikes import exclude_overrides

log = logging.getLogger("benchmarks.fidelity")

QUICK_CAPTURES = ("ethiopian_head", "kermit")
"""One capture with its own masks (a painted head, 1600 px) and one without (a toy, 640 px)."""
EVAL_SIZE = 512
"""Longer side in pixels of the scored held-out views."""
WORK_DIR = WORK_ROOT / "bench_fidelity"
ALIGN = "per-view"
"""How the held-out cameras are placed (``evaluate_dataset``'s ``align``); a kept row made
another way is measured again."""


def capture_names() -> list[str]:
    """Every capture of ``../shared/eval/captures`` (none where it is absent), sorted."""
    return sorted(p.name for p in CAPTURES.iterdir() if (p / "cameras.json").is_file()) \
        if CAPTURES.is_dir() else []


def held_out_frames(n: int) -> list[int]:
    """The two photos of ``n`` in walking order that the job never sees: a third and two
    thirds of the way round (one where ``n`` < 5)."""
    return sorted({n // 3, (2 * n) // 3}) if n >= 5 else [n // 2]


def camera_move(before: np.ndarray, after: np.ndarray) -> tuple[float, float]:
    """How far one camera moved: rotation (degrees) and centre shift as a share of its
    distance from the object's centre (the origin). before, after: [4, 4] c2w."""
    from cadnerf_core.cameras import rotation_angle_deg

    turn = float(rotation_angle_deg((after[:3, :3] @ before[:3, :3].T)[None])[0])
    shift = float(np.linalg.norm(after[:3, 3] - before[:3, 3]) / np.linalg.norm(before[:3, 3]))
    return turn, shift


def _scores(items: list[Any]) -> dict[str, float | None]:
    """Mean PSNR, SSIM and LPIPS of per-view ImageMetrics."""
    lp = [m.lpips for m in items]
    return {"psnr": float(np.mean([m.psnr for m in items])),
            "ssim": float(np.mean([m.ssim for m in items])),
            "lpips": float(np.mean(lp)) if lp and None not in lp else None}


def run_capture(name: str, library: Any, lpips_net: Any,
                settings: dict[str, Any] | None = None) -> dict[str, Any]:
    """One capture's job (``settings``: dotted overrides on ``PRESET``) and its held-out
    views' scores. Returns its row."""
    from cadnerf_core.evaluation.evaluate import evaluate_dataset
    from cadnerf_core.jobfolder import JobFolder

    folder = CAPTURES / name
    n = len(json.loads((folder / "cameras.json").read_text())["frames"])
    hold = held_out_frames(n)
    # Runs with other settings may go on beside this one: each its own folder.
    tag = hashlib.sha1(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:8] \
        if settings else ""
    job = WORK_DIR / (f"{name}-{tag}" if tag else name)
    shutil.rmtree(job, ignore_errors=True)
    try:
        report = evaluate_dataset(folder, n - len(hold), library, preset=PRESET,
                                  overrides={**exclude_overrides(name), **(settings or {})},
                                  job_dir=job,
                                  lpips_net=lpips_net, device=DEVICE, eval_size=EVAL_SIZE,
                                  exif_focal=True, hold_out=hold, mesh=True,
                                  align=ALIGN)
        # The held-out views as rendered, kept to look at (the job itself is large).
        kept = WORK_DIR / "renders" / job.name
        shutil.rmtree(kept, ignore_errors=True)
        shutil.copytree(JobFolder(job).eval_dir, kept)
    finally:
        shutil.rmtree(job, ignore_errors=True)
    held = report.held_out
    moves = [camera_move(np.asarray(a), np.asarray(b)) for a, b in
             zip(held["c2w_centred"], held["c2w_frame"], strict=True)]
    own = [camera_move(np.asarray(a), np.asarray(b)) for a, b in
           zip(held["c2w_frame"], held["c2w"], strict=True)]
    row: dict[str, Any] = {"capture": name, "align": ALIGN, "model": report.model_id,
           "photos": n,
           "kept": len(report.kept), "held_out": report.test_names,
           "masks": report.test_masks, "field": _scores(report.per_view_masked),
           "mesh": _scores(report.per_view_mesh), "whole_psnr": report.image.psnr,
           "rotation_deg": report.pose_refined.rotation_deg,
           "fit_turn_deg": float(np.mean([m[0] for m in moves])),
           "fit_shift": float(np.mean([m[1] for m in moves])),
           "view_turn_deg": float(np.mean([m[0] for m in own])),
           "view_shift": float(np.mean([m[1] for m in own])),
           "focal_error": report.focal_error, "seconds": report.seconds}
    log.info("%s: field %.2f dB / %.3f, mesh %.2f dB / %.3f, cameras %.1f deg", name,
             row["field"]["psnr"], row["field"]["ssim"], row["mesh"]["psnr"],
             row["mesh"]["ssim"], row["rotation_deg"])
    return row


def _num(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def table(rows: list[dict[str, Any]]) -> list[str]:
    """The per-capture table and the means."""
    lines = ["| capture | model | kept / photos | held out | masks | field PSNR (dB) | "
             "field SSIM | mesh PSNR (dB) | mesh SSIM | LPIPS field / mesh | whole-frame PSNR, "
             "field (dB) | kept cameras' rotation error (deg) | frame fit moved the held-out "
             "camera (deg, % of distance) | its own refinement moved it (deg, %) | "
             "focal error | seconds |",
             "|---|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        f, m = r["field"], r["mesh"]
        lines.append(
            f"| {r['capture']} | {r['model']} | {r['kept']}/{r['photos'] - len(r['held_out'])} "
            f"| {', '.join(r['held_out'])} | {r['masks']} | **{f['psnr']:.2f}** | "
            f"{f['ssim']:.3f} | **{m['psnr']:.2f}** | {m['ssim']:.3f} | "
            f"{_num(f['lpips'], 3)} / {_num(m['lpips'], 3)} | {r['whole_psnr']:.2f} | "
            f"{r['rotation_deg']:.1f} | {r['fit_turn_deg']:.2f}, {100 * r['fit_shift']:.1f} | "
            f"{r['view_turn_deg']:.2f}, {100 * r['view_shift']:.1f} | "
            f"{100 * r['focal_error']:+.0f} % | {r['seconds']:.0f} |")
    if rows:
        def mean(part: str, key: str) -> float:
            return statistics.fmean(r[part][key] for r in rows)

        lines += ["", f"- Mean over the {len(rows)} captures: field **{mean('field', 'psnr'):.2f}"
                  f" dB**, SSIM {mean('field', 'ssim'):.3f}; mesh **{mean('mesh', 'psnr'):.2f}"
                  f" dB**, SSIM {mean('mesh', 'ssim'):.3f}."]
    return lines


def record_means(rows: list[dict[str, Any]]) -> None:
    """The mean held-out PSNR over every capture, from the field and from the textured mesh,
    as headline figures (``benchmarks.results``; full runs of the default settings only)."""
    from benchmarks.results import Result, cpu_cores, record, today

    if not rows:
        return
    command = ".venv/bin/python -m benchmarks.bench_fidelity --rows ROWS"
    for key, part, what in (("fidelity_field_psnr", "field", "the field"),
                            ("fidelity_mesh_psnr", "mesh", "the textured mesh")):
        value = statistics.fmean(r[part]["psnr"] for r in rows)
        record(Result(key, f"held-out photos of {len(rows)} real captures at {EVAL_SIZE} px "
                           f"inside the mask, rendered from {what}", value, "dB", 2,
                      f"`{PRESET}`, held-out cameras by a photometric frame fit, then "
                      f"refined per view, "
                      f"{cpu_cores()}", command, today()))


def _rows(names: list[str], library: Any, lpips_net: Any, rows_file: Path | None,
          settings: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """Each capture's row (those already in ``rows_file`` kept), in ``names``' order."""
    rows: dict[str, dict[str, Any]] = {}
    if rows_file is not None and rows_file.is_file():
        rows = {r["capture"]: r for r in json.loads(rows_file.read_text())
                if r.get("align") == ALIGN}
    for name in names:
        if name in rows:
            continue
        log.info("fidelity: %s", name)
        rows[name] = run_capture(name, library, lpips_net, settings)
        if rows_file is not None:
            rows_file.write_text(json.dumps(list(rows.values()), indent=1))
    return [rows[name] for name in names]


def lpips_line(loaded: bool) -> str:
    """What the section says of LPIPS."""
    if loaded:
        return "LPIPS (AlexNet) from the weights named by `CADNERF_LPIPS_WEIGHTS`."
    return ("LPIPS not measured: its weights are not on this machine (`CADNERF_LPIPS_WEIGHTS` "
            "unset; the `lpips` wheel ships its linear layers but not torchvision's AlexNet "
            "backbone, and nothing is downloaded).")


def run(quick: bool, library_dir: Path = LIBRARY_DIR, names: list[str] | None = None,
        rows_file: Path | None = None, settings: dict[str, Any] | None = None) -> str:
    """Run the benchmark (``settings``: dotted overrides on ``PRESET``, as ``--set``).
    Returns its markdown section."""
    head = section_head("Fidelity: held-out photos of real captures at 512 px",
                        "bench_fidelity", quick,
                        f": `{PRESET}` jobs on the CPU, 2 torch threads, each capture's "
                        "photos but two, their true focal length as EXIF; held-out views at "
                        f"{EVAL_SIZE} px on the longer side, scored inside the object's mask"
                        + (f"; settings {json.dumps(settings)}." if settings else "."))
    found = capture_names()
    if not found:
        return "\n".join([*head, ABSENT, ""])
    from cadnerf_core.evaluation.metrics import load_lpips
    from cadnerf_core.library.format import load_library

    weights = os.environ.get("CADNERF_LPIPS_WEIGHTS")
    lpips_net = load_lpips(Path(weights) if weights else None)
    chosen = names or [n for n in (QUICK_CAPTURES if quick else found) if n in found]
    library = load_library(library_dir)
    with torch_threads(2):
        rows = _rows(chosen, library, lpips_net, rows_file, settings)
    if not quick and names is None and not settings:
        record_means(rows)
    notes = [lpips_line(lpips_net is not None),
             "Masks: `dataset` where the capture ships them, `found` where the job's own "
             "background removal made them (the held-out photo masked as the job masks its "
             "photos).",
             "The mesh is `mesh.glb` as the job exports it, rendered unlit at the same cameras."]
    return "\n".join([*head, *table(rows), "", *[f"- {n}" for n in notes], ""])


def main(argv: list[str] | None = None) -> int:
    """Print the section."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else "")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    parser.add_argument("--captures", nargs="*", default=None)
    parser.add_argument("--rows", type=Path, default=None)
    parser.add_argument("--set", dest="settings", action="append", default=[],
                        help="a setting key=value on the preset (dotted key, JSON value)")
    args = parser.parse_args(argv)
    from cadnerf_cli.eval_cmd import parse_overrides
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    sys.stdout.write(run(args.quick, args.library, args.captures, args.rows,
                         parse_overrides(args.settings)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

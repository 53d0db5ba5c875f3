"""Real captures and textured synthetic walks: how far each stage's cameras end from the truth.

Three sets (``capture_set``). The headline, **the users' spacing**: 3 to 10 photos 30 to 60
degrees apart round a real object, as users take them: the captures ``benchmarks.capture_import``
made from public dense captures (``benchmarks/captures_sources.md``; in ``data/captures``) and
the dense captures of ``../shared/eval/captures`` subsampled to that spacing where their frames
allow. **Dense**: those captures as they are (the DTU arcs 16 degrees apart, the Bundler toy
...) and the espresso phone photos. **Textured**: synthetic walks round the evaluation set's
textured meshes on a textured floor (``textured_walks``).

Each capture runs as one ``preview`` job (``capture_jobs``), twice: with the photos' matches
(the default) and on silhouettes alone (``retrieval.matches.enabled`` false). Per job: the
photos and their spacing (the median angle between neighbours seen from the object), whether
the photos carry an EXIF focal length (the imported captures: the reference's, as a phone's
EXIF gives it), the photos the mapper registered, the verified pairs whose rotation is within
10 degrees of the reference's or not, the median rotation error after similarity alignment of
the camera centres of the retrieved cameras (library views), the started ones (what training
starts from) and the refined ones, the focal length's error, PSNR, seconds.

``--cameras-only`` stops each job where training would start (``capture_jobs.start_capture``):
for iterating on camera code without training; no refined cameras then, and the summary lines
score the started ones. ``--no-fits`` also skips the start hypotheses' short silhouette fits
(the retrieved walk alone).

QUICK: not run (whole jobs, hours on 2 cores).

Usage: ``python -m benchmarks.bench_captures [--sets users dense textured] [--captures NAME
...] [--variants ...] [--cameras-only [--no-fits]] [--rows FILE]`` prints the section;
``--rows`` keeps each finished job's row in a JSON file and skips jobs already there (a long
run can be resumed).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.capture_jobs import VARIANTS, run_capture, start_capture
from benchmarks.capture_set import (
    SETS,
    Capture,
    capture_names,
    dense_captures,
    load_capture,
    textured_capture,
    users_captures,
)
from benchmarks.capture_tables import UNTEXTURED, table, textured_errors
from benchmarks.harness import ABSENT, EVAL_ROOT, LIBRARY_DIR, PRESET, section_head
from benchmarks.results import Result, cpu_cores, record, today

__all__ = ["Capture", "UNTEXTURED", "capture_names", "load_capture", "main", "run", "table"]

log = logging.getLogger("benchmarks.captures")

RECORDED = {"users": ("captures_users_rotation", "cameras on real captures at the users' "
                      "spacing ({n} textured captures, 30-60 degrees apart)"),
            "dense": ("captures_real_rotation", "cameras on the dense real captures ({n} "
                      "textured sets)"),
            "textured": ("captures_textured_rotation", "cameras on textured synthetic walks "
                         "({n} meshes, 768 x 576)")}
"""Per set: the README figure's key and quantity (median refined error of the matches)."""
ALIASES = {"real": "dense"}
"""Earlier names of the sets."""
INTRO = {
    "users": "### Real captures at the users' spacing\n\nPhotos 30 to 60 degrees apart (the "
             "imported captures and the dense captures' frames subsampled; `frames` in the "
             "rows say which). Preset `{preset}` on a CPU, every capture's look-alikes left "
             "out (none in the library). Registered: photos the mapper placed, of the kept "
             "ones. Pairs: verified pairs with a rotation, right when within 10 degrees of "
             "the reference's relative rotation; used: of them, those within 60 degrees of "
             "the retrieved cameras', which the mapper and the fusion take "
             "(`prior.PRIOR_DEG`). Rotation errors: median over the kept photos "
             "after similarity alignment of the camera centres; retrieved: the library views; "
             "started: the cameras training starts from; refined: after training. Focal "
             "error: the job's focal length against the reference (EXIF: the imported "
             "captures' photos carry the reference's 35 mm focal length as a phone's would).",
    "dense": "### Dense captures\n\nThe captures of `../shared/eval/captures` as they are "
             "(no EXIF) and the espresso phone photos (EXIF; reference: the set's coarse "
             "metadata); columns as above. The temple frames its gantry took upside down are "
             "given upright, as a phone's orientation tag gives its photos.",
    "textured": "### Textured synthetic walks\n\n8 photos at 768 x 576 through a 65 degree "
                "lens (27 mm EXIF) round each textured mesh on a tiled floor, the mesh's "
                "look-alikes left out of the library; columns as above.",
}


def record_median(rows: list[dict[str, Any]], tag: str) -> None:
    """The default variant's median refined rotation error over the textured captures of a
    whole set (``tag``) as the README's figure (whole jobs only)."""
    if tag not in RECORDED or any(r.get("refined") is None for r in rows):
        return
    errors = textured_errors(rows, "matches")
    if not errors:
        return
    key, what = RECORDED[tag]
    conditions = "leave-out" if tag == "textured" else f"`{PRESET}`"
    record(Result(key, what.format(n=len(errors)), float(np.median(errors)),
                  "degrees (median)", 1, f"{conditions}, {cpu_cores()}",
                  f".venv/bin/python -m benchmarks.bench_captures --sets {tag} --rows ROWS",
                  today()))


def _photos_key(capture: Capture) -> str:
    return "|".join(str(p) for p in capture.photos)


def _run_one(capture: Capture, library: Any, variant: str, mode: str,
             rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The capture's row under ``variant``: a row of another set on the same photos, else a
    new job (``start_capture`` for the cameras-only mode, else ``run_capture``)."""
    key = _photos_key(capture)
    for row in rows:
        if row.get("photos_key") == key and row["variant"] == variant and row["mode"] == mode:
            return dict(row)
    if mode.startswith("cameras"):
        return start_capture(capture, library, variant, fits=mode == "cameras")
    return run_capture(capture, library, variant)


def _rows(captures: list[Capture], library: Any, variants: list[str], tag: str,
          rows_file: Path | None, whole: bool, mode: str) -> list[dict[str, Any]]:
    """Each capture's job under each variant (rows already in ``rows_file`` kept); ``whole``:
    every capture of the set, whose figure is recorded (``record_median``)."""
    rows: list[dict[str, Any]] = []
    if rows_file is not None and rows_file.is_file():
        rows = json.loads(rows_file.read_text())

    def mine(row: dict[str, Any]) -> bool:
        return ALIASES.get(row.get("set", "dense"), row.get("set", "dense")) == tag \
            and row.get("mode", "full") == mode

    for capture in captures:
        for variant in variants:
            if any(r["capture"] == capture.name and r["variant"] == variant and mine(r)
                   for r in rows):
                continue
            log.info("%s (%s, %s), %s", capture.name, tag, mode, variant)
            row = _run_one(capture, library, variant, mode, rows)
            rows.append({**row, "set": tag, "photos_key": _photos_key(capture)})
            if rows_file is not None:
                rows_file.write_text(json.dumps(rows, indent=1))
    order = [c.name for c in captures]
    kept = sorted((r for r in rows if r["capture"] in order and mine(r)
                   and r["variant"] in variants),
                  key=lambda r: (list(VARIANTS).index(r["variant"]), order.index(r["capture"])))
    if whole:
        record_median(kept, tag)
    return kept


def _captures(tag: str, names: list[str] | None, work: Path) -> list[Capture]:
    from benchmarks.textured_walks import TEXTURED

    if tag == "users":
        return users_captures(names)
    if tag == "dense":
        return [c for c in dense_captures(names) if c.name not in TEXTURED]
    return [textured_capture(n, work) for n in names or TEXTURED if n in TEXTURED]


def run(quick: bool, library_dir: Path = LIBRARY_DIR, names: list[str] | None = None,
        variants: list[str] | None = None, rows_file: Path | None = None,
        sets: list[str] | None = None, cameras_only: bool = False,
        fits: bool = True) -> str:
    """Run the benchmark. Returns its markdown section (``cameras_only``: each job to its
    start; ``fits`` False: without the start hypotheses' silhouette fits)."""
    head = section_head("Cameras on real captures and textured walks", "bench_captures", quick,
                        (" --cameras-only" if cameras_only else "")
                        + ("" if fits or not cameras_only else " --no-fits"))
    if not EVAL_ROOT.is_dir():
        return "\n".join([*head, ABSENT, ""])
    if quick:
        return "\n".join([*head, "Not run in QUICK: whole jobs (hours on 2 cores); run "
                          "without `--quick`, or `--cameras-only` for the cameras in minutes.",
                          ""])
    from cadnerf_core.library.format import load_library

    library = load_library(library_dir)
    variants = variants or list(VARIANTS)
    mode = "full" if not cameras_only else ("cameras" if fits else "cameras-no-fits")
    out = list(head)
    with tempfile.TemporaryDirectory(prefix="bench_textured_") as work:
        for tag in [ALIASES.get(s, s) for s in sets or SETS]:
            captures = _captures(tag, names, Path(work))
            if not captures:
                out += [INTRO[tag].split("\n")[0], "", "None found.", ""]
                continue
            rows = _rows(captures, library, variants, tag, rows_file, names is None, mode)
            out += [INTRO[tag].format(preset=PRESET), "", *table(rows), ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    """Print the section."""
    parser = argparse.ArgumentParser(description="CAD-NeRF real-capture cameras benchmark")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    parser.add_argument("--captures", nargs="*", default=None)
    parser.add_argument("--variants", nargs="*", default=None, choices=list(VARIANTS))
    parser.add_argument("--rows", type=Path, default=None)
    parser.add_argument("--sets", nargs="*", default=None, choices=[*SETS, *ALIASES])
    parser.add_argument("--cameras-only", action="store_true",
                        help="stop each job where training would start (minutes, no refined "
                             "cameras)")
    parser.add_argument("--no-fits", action="store_true",
                        help="with --cameras-only: the retrieved walk alone, no start "
                             "hypotheses fitted (faster)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    sys.stdout.write(run(args.quick, args.library, args.captures, args.variants, args.rows,
                         args.sets, args.cameras_only, not args.no_fits))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Real captures and textured synthetic walks: how far each stage's cameras end from the truth.

Each capture of ``../shared/eval/captures`` (6-10 frames round a real object, reference
cameras from the capture's own calibration or a COLMAP/Bundler reconstruction over many
frames, the capture's masks where it ships them) and the espresso phone photos (coarse
metadata poses) runs as one ``preview`` job, as ``cadnerf reconstruct`` runs it, twice: with
the photos' matches (the default: learned matches, cameras fused with their rotations, the
epipolar loss) and on silhouettes alone (``retrieval.matches.enabled`` false). Per job: the
median rotation error after similarity alignment of the camera centres (``cameras.pose_errors``)
of the retrieved cameras (library views), the started ones (what training starts from: the
chosen hypothesis, fused) and the refined ones; the focal length's error against the
reference (the photos carry no EXIF); training PSNR; seconds.

The textured synthetic walks (``textured_walks``: the evaluation set's textured meshes on a
textured floor, 768 x 576 through a phone's lens, its focal length given as a phone's EXIF
would) run the same way; their rows also say whether the refined walk went round the wrong
way (``textured_walks.mirrored``).

QUICK: not run (26 whole jobs, about 80 minutes on 2 cores).

Usage: ``python -m benchmarks.bench_captures [--sets real textured] [--captures NAME ...]
[--variants ...] [--rows FILE]`` prints the section; ``--rows`` keeps each finished job's row
in a JSON file and skips jobs already there (a long run can be resumed).
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import (
    ABSENT,
    CAPTURES,
    EVAL_ROOT,
    LIBRARY_DIR,
    PHOTOS,
    PRESET,
    run_job,
    section_head,
)
from benchmarks.lookalikes import exclude_overrides
from benchmarks.results import Result, cpu_cores, record, today

log = logging.getLogger("benchmarks.captures")

UNTEXTURED = {"dino_ring": "matte white ceramic"}
"""Captures whose object shows next to no texture (the acceptance's median leaves them out)."""
VARIANTS: dict[str, dict[str, Any]] = {
    "matches": {},
    "silhouettes": {"retrieval.matches.enabled": False},
}


@dataclass(frozen=True)
class Capture:
    """One capture: photos in walking order, their masks (None: the job makes them), the
    reference cameras [N, 4, 4] (OpenCV c2w) and focal lengths [N] in photo pixels (None
    where unknown)."""

    name: str
    photos: list[Path]
    masks: list[Path] | None
    c2w: np.ndarray
    focal: np.ndarray | None
    overrides: dict[str, Any] = field(default_factory=dict)
    """Configuration values the job gets besides the preset's and the variant's."""


def load_capture(name: str) -> Capture:
    """A capture of ``../shared/eval/captures`` (``cameras.json``: frames with image, K, c2w)
    or the espresso photos (``../shared/eval/photos``, metadata azimuth and elevation)."""
    if name == "ners_espresso":
        from benchmarks.retrieval_real import real_set_photos

        photos, masks, truth = real_set_photos(name)
        assert truth is not None
        return Capture(name, photos, masks, truth, None)
    folder = CAPTURES / name
    frames = json.loads((folder / "cameras.json").read_text())["frames"]
    photos = [folder / f["image"] for f in frames]
    masks = [folder / "masks" / f"{Path(f['image']).stem}.png" for f in frames]
    c2w = np.array([f["c2w"] for f in frames], dtype=np.float64)
    flipped = [k for k, f in enumerate(frames) if f.get("upside_down_by_design")]
    has_masks = all(m.is_file() for m in masks)
    if flipped:
        photos, masks, c2w = upright(name, photos, masks if has_masks else None, c2w, flipped)
    return Capture(name, photos, masks if has_masks else None, c2w,
                   np.array([f["K"][0][0] for f in frames], dtype=np.float64))


def upright(name: str, photos: list[Path], masks: list[Path] | None, c2w: np.ndarray,
            flipped: list[int]) -> tuple[list[Path], list[Path], np.ndarray]:
    """The capture as a phone saves it: frames a camera rig took upside down (a gantry's
    ``upside_down_by_design``) turned upright, as a phone's orientation tag turns its photos
    (``intake.photos`` applies it), their reference cameras rolled half a turn about the
    optical axis to match. The turned copies go to a temporary folder."""
    import cv2

    work = Path(tempfile.gettempdir()) / "cadnerf_bench_upright" / name
    work.mkdir(parents=True, exist_ok=True)
    photos, masks = list(photos), list(masks or [])
    c2w = c2w.copy()
    roll = np.diag([-1.0, -1.0, 1.0, 1.0])  # half a turn about the camera's z axis
    for k in flipped:
        for files, suffix in ((photos, "photo"), (masks, "mask")):
            if not files:
                continue
            image = cv2.imread(str(files[k]), cv2.IMREAD_UNCHANGED)
            assert image is not None, f"cannot read {files[k]}"
            turned = work / f"{k:03d}_{suffix}{files[k].suffix}"
            cv2.imwrite(str(turned), cv2.rotate(image, cv2.ROTATE_180))
            files[k] = turned
        c2w[k] = c2w[k] @ roll
    return photos, masks, c2w


def textured_capture(name: str, work: Path) -> Capture:
    """A textured synthetic walk of mesh ``name`` (``textured_walks``), rendered into ``work``,
    its focal length given as a phone's EXIF gives it."""
    from benchmarks.textured_walks import phone_focal_35mm, render_walk

    photos, masks, c2w = render_walk(name, work / name)
    return Capture(name, photos, masks, c2w, None,
                   {"retrieval.focal_35mm": round(phone_focal_35mm(), 2)})


def capture_names() -> list[str]:
    """Every capture found, then the espresso photos."""
    names = sorted(p.name for p in CAPTURES.iterdir() if (p / "cameras.json").is_file()) \
        if CAPTURES.is_dir() else []
    if (PHOTOS / "ners_espresso").is_dir():
        names.append("ners_espresso")
    return names


def run_capture(capture: Capture, library: Any, variant: str) -> dict[str, Any]:
    """One ``preview`` job on the capture. Returns its row: errors in degrees per stage, focal
    error (share), PSNR, seconds, pairs and fused photos."""
    from cadnerf_core.cameras.conventions import pose_errors
    from cadnerf_core.config import internal_config
    from cadnerf_core.evaluation.jobio import read_job_cameras
    from cadnerf_core.nerf.model import TrainedModel

    job = Path(tempfile.mkdtemp(prefix="bench_captures_"))
    try:
        run = run_job(job, library, photos=capture.photos, masks=capture.masks,
                      config=internal_config(PRESET, {**exclude_overrides(capture.name),
                                                     **capture.overrides, **VARIANTS[variant]}))
        cams = read_job_cameras(job, TrainedModel.load(job, "cpu"))
    finally:
        shutil.rmtree(job, ignore_errors=True)
    retrieval, metrics, seconds = run.retrieval, run.metrics, run.seconds
    truth = capture.c2w[cams.kept]
    by_index = {int(m["index"]): m for m in retrieval["matches"]}
    retrieved = np.array([by_index[k].get("c2w_retrieved", by_index[k]["c2w"])
                          for k in cams.kept], dtype=np.float64)

    def median(c2w: np.ndarray) -> float:
        return float(np.median(pose_errors(c2w, truth)[0]))

    focal = None
    if capture.focal is not None:
        focal = float(np.median(cams.K_photo[:, 0, 0] / capture.focal[cams.kept] - 1.0))
    pairs = [p for p in retrieval.get("photo_pairs", []) if p.get("turn_deg") is not None]
    from benchmarks.textured_walks import mirrored

    return {"capture": capture.name, "variant": variant, "model": cams.model_id,
            "mirrored": mirrored(cams.refined, truth),
            "kept": len(cams.kept), "photos": len(capture.photos),
            "retrieved": median(retrieved), "started": median(cams.retrieved),
            "refined": median(cams.refined), "focal": focal,
            "psnr": float(metrics.get("mean_psnr", float("nan"))), "seconds": seconds,
            "pairs": len(pairs), "fused": len((retrieval.get("fusion") or {}).get("photos", []))}


def _mirrored(row: dict[str, Any]) -> str:
    return "" if "mirrored" not in row else ("yes" if row["mirrored"] else "no")


def textured_refined(rows: list[dict[str, Any]], variant: str) -> list[float]:
    """The refined rotation errors of ``variant``'s jobs on captures with texture."""
    return [r["refined"] for r in rows if r["variant"] == variant
            and r["capture"] not in UNTEXTURED]


def record_median(rows: list[dict[str, Any]], tag: str) -> None:
    """The default variant's median refined rotation error over the textured captures of a
    whole set (``tag``: "real" or "textured") as the README's figure."""
    errors = textured_refined(rows, "matches")
    if not errors:
        return
    what = (f"cameras on real captures ({len(errors)} textured sets with reference cameras)"
            if tag == "real" else
            f"cameras on textured synthetic walks ({len(errors)} meshes, 768 x 576)")
    conditions = f"`{PRESET}`" if tag == "real" else "leave-out"
    record(Result(f"captures_{tag}_rotation", what, float(np.median(errors)),
                  "degrees (median)", 1, f"{conditions}, {cpu_cores()}",
                  ".venv/bin/python -m benchmarks.bench_captures --sets real textured "
                  "--rows ROWS", today()))


def table(rows: list[dict[str, Any]]) -> list[str]:
    """The per-job table and the acceptance lines."""
    lines = ["| capture | variant | model | kept | retrieved (deg) | started (deg) | "
             "refined (deg) | mirrored | focal error | PSNR (dB) | pairs with a rotation | "
             "fused | seconds |", "|---|---|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        focal = "" if r["focal"] is None else f"{100 * r['focal']:+.0f} %"
        lines.append(f"| {r['capture']} | {r['variant']} | {r['model']} | "
                     f"{r['kept']}/{r['photos']} | {r['retrieved']:.1f} | {r['started']:.1f} | "
                     f"**{r['refined']:.1f}** | {_mirrored(r)} | "
                     f"{focal} | {r['psnr']:.2f} | {r['pairs']} | {r['fused']} | "
                     f"{r['seconds']:.0f} |")
    lines.append("")
    for variant in VARIANTS:
        textured = textured_refined(rows, variant)
        if textured:
            flipped = sum(bool(r.get("mirrored")) for r in rows if r["variant"] == variant)
            lines.append(f"- {variant}: median refined rotation error over the {len(textured)} "
                         f"textured captures **{np.median(textured):.1f} deg**; mirrored "
                         f"walks: {flipped}.")
    worse = worse_than_silhouettes(rows)
    if worse is not None:
        lines.append("- matches worse than silhouettes alone by more than "
                     f"{WORSE_MARGIN_DEG:.0f} degrees: "
                     + (", ".join(f"{name} ({gap:+.1f})" for name, gap in worse) or "none")
                     + ".")
    return lines


WORSE_MARGIN_DEG = 2.0
"""How much worse than silhouettes alone the matches may leave a capture's refined cameras."""


def worse_than_silhouettes(rows: list[dict[str, Any]]) -> list[tuple[str, float]] | None:
    """The textured captures whose refined error with the matches exceeds the one on
    silhouettes alone by more than ``WORSE_MARGIN_DEG`` (name, difference); None when no
    capture ran both ways."""
    refined = {(r["capture"], r["variant"]): r["refined"] for r in rows}
    both = [name for name, variant in refined if variant == "matches"
            and (name, "silhouettes") in refined and name not in UNTEXTURED]
    if not both:
        return None
    gaps = [(name, refined[(name, "matches")] - refined[(name, "silhouettes")])
            for name in both]
    return [(name, gap) for name, gap in gaps if gap > WORSE_MARGIN_DEG]


SETS = ("real", "textured")


def _rows(captures: list[Capture], library: Any, variants: list[str], tag: str,
          rows_file: Path | None, whole: bool) -> list[dict[str, Any]]:
    """Each capture's job under each variant (rows already in ``rows_file`` kept); ``whole``:
    every capture of the set, whose figure is recorded (``record_median``)."""
    rows: list[dict[str, Any]] = []
    if rows_file is not None and rows_file.is_file():
        rows = json.loads(rows_file.read_text())
    for capture in captures:
        for variant in variants:
            if any(r["capture"] == capture.name and r["variant"] == variant
                   and r.get("set", "real") == tag for r in rows):
                continue
            log.info("%s (%s), %s", capture.name, tag, variant)
            rows.append({**run_capture(capture, library, variant), "set": tag})
            if rows_file is not None:
                rows_file.write_text(json.dumps(rows, indent=1))
    names = {c.name for c in captures}
    order = [c.name for c in captures]
    mine = sorted((r for r in rows if r["capture"] in names and r.get("set", "real") == tag
                   and r["variant"] in variants),
                  key=lambda r: (list(VARIANTS).index(r["variant"]), order.index(r["capture"])))
    if whole:
        record_median(mine, tag)
    return mine


def run(quick: bool, library_dir: Path = LIBRARY_DIR, names: list[str] | None = None,
        variants: list[str] | None = None, rows_file: Path | None = None,
        sets: list[str] | None = None) -> str:
    """Run the benchmark. Returns its markdown section."""
    head = section_head("Cameras on real captures and textured walks", "bench_captures", quick)
    if not EVAL_ROOT.is_dir():
        return "\n".join([*head, ABSENT, ""])
    if quick:
        return "\n".join([*head, "Not run in QUICK: 26 whole jobs (about 80 minutes on 2 "
                          "cores); run without `--quick`.", ""])
    from benchmarks.textured_walks import TEXTURED
    from cadnerf_core.library.format import load_library

    library = load_library(library_dir)
    variants = variants or list(VARIANTS)
    sets = sets or list(SETS)
    out = list(head)
    if "real" in sets:
        captures = [load_capture(n) for n in names or capture_names()
                    if n not in TEXTURED]
        out += [f"### Real captures\n\nPreset `{PRESET}` on a CPU, every capture's look-alikes "
                "left out (none in the library). Rotation errors: median over the kept photos "
                "after similarity alignment of the camera centres; retrieved: the library "
                "views; started: the cameras training starts from (the mapper's where it "
                "registered the photos, else the chosen hypothesis fused with the pairs' "
                "rotations); refined: after training. Focal error: the job's focal length "
                "against the reference (no photo carries EXIF). The espresso reference is the "
                "set's coarse metadata (azimuth, elevation); its photos carry EXIF. The temple "
                "frames its gantry took upside down are given upright, as a phone's "
                "orientation tag gives its photos.", "",
                *table(_rows(captures, library, variants, "real", rows_file, names is None)),
                ""]
    if "textured" in sets:
        with tempfile.TemporaryDirectory(prefix="bench_textured_") as work:
            captures = [textured_capture(n, Path(work)) for n in names or TEXTURED
                        if n in TEXTURED]
            rows = _rows(captures, library, variants, "textured", rows_file, names is None)
        out += ["### Textured synthetic walks\n\n8 photos at 768 x 576 through a 65 degree "
                "lens (27 mm EXIF) round each textured mesh on a tiled floor, the mesh's "
                "look-alikes left out of the library; columns as above.", "", *table(rows), ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    """Print the section."""
    parser = argparse.ArgumentParser(description="CAD-NeRF real-capture cameras benchmark")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    parser.add_argument("--captures", nargs="*", default=None)
    parser.add_argument("--variants", nargs="*", default=None, choices=list(VARIANTS))
    parser.add_argument("--rows", type=Path, default=None)
    parser.add_argument("--sets", nargs="*", default=None, choices=list(SETS))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    sys.stdout.write(run(args.quick, args.library, args.captures, args.variants, args.rows,
                         args.sets))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Training with the photos' matches: the epipolar loss on the poses, on and off.

The training benchmark's protocol (``benchmarks.bench_training.run_one``: ``render_dataset``
walks, a ``preview`` job through ``evaluate_dataset``, look-alikes left out of the library),
with the photos rendered at ``PHOTO_SIZE`` px so their texture can be matched (the job still
trains on 128-pixel crops), on the meshes that carry a texture, at 6 views (the training
benchmark's walks: consecutive photos 60 degrees apart) and ``MANY_VIEWS`` views. Each walk
is run with ``phase2.lambda_matches`` and ``phase3.lambda_matches`` at ``WEIGHT`` and at 0
(off): test PSNR, median refined rotation error, and the matches the job trained with. A
walk whose photos share too few matches trains without the term, and its "off" run, the same
computation, is not repeated.

Usage: ``python -m benchmarks.bench_epipolar [--quick]`` prints the section.
"""

from __future__ import annotations

import logging
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.bench_matches import PAINTED
from benchmarks.harness import ABSENT, LIBRARY_DIR, MESHES, section_head

log = logging.getLogger(__name__)

PHOTO_SIZE = 512
MANY_VIEWS = 10
WEIGHT = 0.01  # the default of ``phase2.lambda_matches`` and ``phase3.lambda_matches``
QUICK = ("CesiumMilkTruck", "fuze")


def _overrides(weight: float) -> dict[str, Any]:
    return {"phase2.lambda_matches": weight, "phase3.lambda_matches": weight}


def _matches_used(job: Path) -> int:
    """Matches between the training photos the job's log reports (0: none)."""
    from cadnerf_core.jobfolder import JobFolder

    log_path = JobFolder(job).log_path
    text = log_path.read_text() if log_path.is_file() else ""
    found = re.findall(r"epipolar loss: (\d+) matches", text)
    return int(found[-1]) if found else 0


def run_mesh(name: str, views: int, library: Any, work: Path) -> dict[float, dict[str, Any]]:
    """One walk of ``name`` with the loss at ``WEIGHT`` and off. Returns weight -> scores."""
    from benchmarks.bench_training import run_one

    out: dict[float, dict[str, Any]] = {}
    for weight in (WEIGHT, 0.0):
        if not weight and not out[WEIGHT]["matches"]:
            # No pair reached min_inliers: the job had no epipolar term, so "off" is the
            # same computation (training is deterministic for a seed).
            out[weight] = out[WEIGHT]
            break
        label = f"{views}v_{'on' if weight else 'off'}"
        row = run_one(name, work / str(views), library, label, _overrides(weight), tta=False,
                      views=views, size=PHOTO_SIZE)
        row["matches"] = _matches_used(work / str(views) / name / label)
        out[weight] = row
        log.info("%s, %d views, weight %g: %.2f dB, %.1f deg, %d matches", name, views,
                 weight, row["psnr"], row["rot_after"], row["matches"])
    return out


def run(quick: bool, library_dir: Path = LIBRARY_DIR) -> str:
    """Run the benchmark. Returns its markdown section."""
    from cadnerf_core.library.format import load_library
    from cadnerf_core.nerf.epipolar import PRIOR_DEG

    head = section_head("Training with the matches (epipolar loss)", "bench_epipolar", quick)
    if not MESHES.is_dir():
        return "\n".join([*head, ABSENT, ""])
    library = load_library(library_dir)
    meshes = QUICK if quick else PAINTED
    lines = [*head, f"`preview` jobs on walks rendered at {PHOTO_SIZE} px (trained on 128-px "
             "crops), look-alikes left out; loss weight "
             f"{WEIGHT:g} in phases two and three (`phase*.lambda_matches`) against 0. "
             "Matches: SIFT inliers between the training photos the job used (pairs of at "
             "least `retrieval.matches.min_inliers` whose turn agrees with the starting "
             f"cameras within {PRIOR_DEG:g} degrees, `nerf.epipolar.PRIOR_DEG`); with none, "
             "the job is the same computation as off. Rotation error: median over the "
             "photos after similarity alignment (degrees).", "",
             "| mesh | views | matches used | test PSNR, off | on | rot. error refined, off "
             "| on | job s, off | on |", "|---|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory(prefix="bench_epipolar_") as tmp:
        for views in (6, MANY_VIEWS):
            for name in meshes:
                rows = run_mesh(name, views, library, Path(tmp) / name)
                on, off = rows[WEIGHT], rows[0.0]
                lines.append(f"| {name} | {views} | {on['matches']} | {off['psnr']:.2f} | "
                             f"{on['psnr']:.2f} | {off['rot_after']:.1f} | "
                             f"{on['rot_after']:.1f} | {off['seconds']:.0f} | "
                             f"{on['seconds']:.0f} |")
    return "\n".join([*lines, ""])


def main(argv: list[str] | None = None) -> int:
    """Print the section (``--quick``: two meshes)."""
    from benchmarks.run import area_main

    return area_main(run, "CAD-NeRF epipolar-loss benchmark", argv)


if __name__ == "__main__":
    sys.exit(main())

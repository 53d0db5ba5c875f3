"""The robust start on walks both ways round: does a coarse fit tell a direction retrieval had
to guess?

For each mesh of ``../shared/eval/meshes`` a walk of 6 views (128 px, seed 0, as
``bench_unseen`` renders them) is rendered walking counter-clockwise (+1) and clockwise (-1)
at 40, 55 and 70 degrees across, the mesh's look-alikes left out of the library. Each walk goes
through a ``preview`` job's intake and robust start (``pipeline.run_intake``,
``pipeline.robust_start``: retrieval, then a short silhouette fit of each hypothesis), without
training. Per walk: whether retrieval flagged the direction a guess, the rotation error (median
over the kept photos after similarity alignment) of the retrieved walk and of the start
chosen, and whether each walks the right way round.

The question it answers: where silhouettes and texture could not tell the direction (a bottle,
a mug, a lamp), retrieval takes the walk counter-clockwise (``retrieval.ambiguous_walk``) and
the start's fits may switch to the mirrored walk. The summary counts how often each is right
on the flagged walks, both ways round: a walk given one way only would credit whichever
convention matches it.

QUICK: the evaluation benchmark's three quick meshes at 40 degrees.

Usage: ``python -m benchmarks.bench_starts [--quick] [--meshes NAME ...] [--fovs DEG ...]``
prints the section.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks.bench_unseen import FOVS
from benchmarks.harness import (
    ABSENT,
    LIBRARY_DIR,
    MESHES,
    PRESET,
    QUICK_MESHES,
    SEED,
    SIZE,
    VIEWS,
    eval_meshes,
    fov_walk,
    rotation_error,
    section_head,
    torch_threads,
)
from benchmarks.lookalikes import exclude_overrides

log = logging.getLogger(__name__)

DIRECTIONS = (1, -1)  # counter-clockwise, clockwise seen from above
RIGHT_DEG = 90.0  # a walk further off than this after alignment went the wrong way round


@dataclass
class StartRow:
    """One walk's retrieval and start."""

    mesh: str
    fov: float
    direction: int  # the true one
    guessed: bool  # retrieval flagged the direction a guess
    retrieved: tuple[str, int, float]  # model, direction, rotation error (deg)
    chosen: tuple[str, int, float]
    hypotheses: int
    seconds: float  # intake and start

    @property
    def retrieved_right(self) -> bool:
        return self.retrieved[2] < RIGHT_DEG

    @property
    def chosen_right(self) -> bool:
        return self.chosen[2] < RIGHT_DEG


def start_row(name: str, fov: float, direction: int, library: Any, work: Path) -> StartRow:
    """Render one walk, run a job's intake and robust start on it, and score both."""
    import torch

    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.evaluation.jobio import first_views, write_job
    from cadnerf_core.pipeline import read_job_config, robust_start, run_intake
    from cadnerf_core.progress import Progress

    walk = first_views(load_dataset(fov_walk(name, fov, work, direction=direction)), VIEWS)
    job_dir = work / name / f"job_fov{fov:g}_{direction:+d}"
    shutil.rmtree(job_dir, ignore_errors=True)
    write_job(job_dir, walk, PRESET, {**exclude_overrides(name, "leave-out"), "seed": SEED})
    config = read_job_config(job_dir)
    start = time.perf_counter()
    intake = run_intake(job_dir, library, config, Progress())
    retrieval = intake.retrieval
    learn_focal = all(p.focal_pixels is None for p in intake.photos)
    chosen = robust_start(job_dir, intake, library, config, torch.device("cpu"), learn_focal,
                          Progress(), []).retrieval
    seconds = time.perf_counter() - start

    def scored(result: Any) -> tuple[str, int, float]:
        return result.model_id, result.direction, rotation_error(result, walk.c2w)

    return StartRow(name, fov, direction, retrieval.direction_ambiguous, scored(retrieval),
                    scored(chosen), len(chosen.hypotheses), seconds)


def _share(rows: list[StartRow], right: str) -> str:
    return f"{sum(getattr(r, right) for r in rows)} of {len(rows)}"


def summary_lines(rows: list[StartRow]) -> list[str]:
    """What the table adds up to, per direction and both together."""
    lines = []
    for label, pick in (("counter-clockwise walks", 1), ("clockwise walks", -1),
                        ("both", 0)):
        chosen = [r for r in rows if pick in (0, r.direction)]
        guessed = [r for r in chosen if r.guessed]
        known = [r for r in chosen if not r.guessed]
        lines.append(
            f"- {label}: direction flagged a guess on {len(guessed)} of {len(chosen)} walks; "
            f"right way round there: retrieval's walk {_share(guessed, 'retrieved_right')}, "
            f"the start chosen {_share(guessed, 'chosen_right')}. Not flagged: retrieval "
            f"{_share(known, 'retrieved_right')}, the start {_share(known, 'chosen_right')}.")
    switched = [r for r in rows if r.guessed and r.retrieved[1] != r.chosen[1]]
    lines.append(f"- On the flagged walks the start turned the walk round on {len(switched)}, "
                 f"rightly on {sum(r.chosen_right for r in switched)}.")
    return lines


def table_lines(rows: list[StartRow]) -> list[str]:
    lines = ["| mesh | fov | walk | guess | retrieved | rot. (deg) | start | rot. (deg) "
             "| hypotheses | s |", "|---|---:|---|---|---|---:|---|---:|---:|---:|"]
    for r in rows:
        lines.append(
            f"| {r.mesh} | {r.fov:g} | {'ccw' if r.direction > 0 else 'cw'} "
            f"| {'yes' if r.guessed else ''} | {r.retrieved[0]} {r.retrieved[1]:+d} "
            f"| {r.retrieved[2]:.1f} | {r.chosen[0]} {r.chosen[1]:+d} | {r.chosen[2]:.1f} "
            f"| {r.hypotheses} | {r.seconds:.0f} |")
    return lines


def run(quick: bool, meshes: list[str] | None = None, fovs: list[float] | None = None,
        library_dir: Path = LIBRARY_DIR) -> str:
    """Run the benchmark. Returns its markdown section."""
    from cadnerf_core.library.format import load_library

    head = section_head("The start on walks both ways round", "bench_starts", quick)
    if not MESHES.is_dir():
        return "\n".join([*head, ABSENT, ""])
    names = meshes or list(QUICK_MESHES if quick else eval_meshes())
    angles = fovs or ([40.0] if quick else list(FOVS))
    library = load_library(library_dir)
    with torch_threads(1), tempfile.TemporaryDirectory() as tmp:
        rows = [start_row(name, fov, direction, library, Path(tmp))
                for name in names for fov in angles for direction in DIRECTIONS]
    intro = (f"{len(names)} meshes ({', '.join(names)}), walks of {VIEWS} views at {SIZE} px, "
             f"fields of view {', '.join(f'{f:g}' for f in angles)} deg, each walked both "
             "ways round; look-alikes left out; preset `preview`, one torch thread. A walk is "
             f"the right way round when its rotation error is under {RIGHT_DEG:g} degrees.")
    return "\n".join([*head, intro, "", *summary_lines(rows), "", *table_lines(rows), ""])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--meshes", nargs="*", default=None)
    parser.add_argument("--fovs", type=float, nargs="*", default=None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    print(run(args.quick, args.meshes, args.fovs))
    return 0


if __name__ == "__main__":
    sys.exit(main())

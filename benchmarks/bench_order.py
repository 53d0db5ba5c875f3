"""Photos in any order (``RetrievalConfig.order``): found walks, poses, and the solver's time.

- Synthetic walks: every mesh of ``../shared/eval/meshes`` rendered as walks of 6 and 9 views
  at 128 px (as the retrieval benchmark renders them, both walking directions), the mesh's
  look-alikes left out of the library (``benchmarks.lookalikes``). Each walk is retrieved in
  order with ``walk`` and ``auto`` (also rendered at a phone's 55 and 70 degrees, where the
  silhouettes fit the library's views less well and a wrong order can look better), and
  shuffled with fixed seeds with ``walk`` (what a
  shuffled set got before), ``any`` and ``auto``: the median rotation error of the retrieved
  poses (kept photos, after similarity alignment), and whether the walk's cyclic order was
  found (up to start and direction).
- Solver time: the order search of 10 photos against the full candidate table of the shipped
  library (every azimuth and elevation), for one model and for the five most voted.
- Real photos: ``ners_espresso`` and ``raydiffusion_robot`` with their shipped masks, in
  walking order and shuffled: the model, whether the walk was found, and how far each shuffled
  run's poses are from the ordered run's (median rotation difference after similarity
  alignment).

QUICK: the retrieval benchmark's three quick meshes, one shuffle per walk.

Usage: ``python -m benchmarks.bench_order [--quick]`` prints the section.
"""

from __future__ import annotations

import logging
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import (
    LIBRARY_DIR,
    MESHES,
    PHOTOS,
    QUICK_MESHES,
    SEED,
    eval_meshes,
    load_walk,
    rotation_error,
    section_head,
)
from benchmarks.lookalikes import excluded
from benchmarks.retrieval_walks import VIEW_COUNTS

log = logging.getLogger(__name__)

SHUFFLES = 3  # fixed seeds 0 .. SHUFFLES - 1 per walk (QUICK: 1)
REAL_SETS = ("ners_espresso", "raydiffusion_robot")
WIDE_FOVS = (55.0, 70.0)
"""Fields of view (degrees) of a phone's main lens at which each walk is also rendered and
retrieved in order with ``walk`` and ``auto``: silhouettes through a wider lens fit the
library's 40-degree views less well, and ``auto`` must still keep a walk given in order."""


@dataclass
class Walk:
    """One rendered walk retrieved in order and shuffled."""

    mesh: str
    views: int
    ordered: dict[str, float]  # order mode -> median rotation error, photos in order
    shuffled: dict[str, list[float]]  # order mode -> errors over the shuffles
    found: dict[str, list[bool]]  # order mode -> cyclic order found, per shuffle
    guess: list[bool]  # ``any``: the result said the order is a guess, per shuffle
    wide: dict[float, dict[str, float]] = field(default_factory=dict)
    # field of view -> order mode -> median rotation error, the same walk in order rendered
    # with a phone's wider lens (``WIDE_FOVS``)
    alike: int = 0  # neighbouring pairs of the walk among its most alike pairs (``alike_hits``)


def photo_likeness(masks: list[np.ndarray], images: list[np.ndarray], library: Any,
                   config: Any = None) -> np.ndarray:
    """[P, P] how alike the photos look, as retrieval's order search weighs it (colours and
    outlines, and the matches between them where the object has texture).

    Args:
        masks, images: the photos' masks [H, W] bool and RGB [H, W, 3] in walking order.
        library: the loaded CAD library (its crop size and margin).
        config: a ``RetrievalConfig`` (None: the defaults).
    """
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.retrieval import search as retrieve

    seen = retrieve._look(masks, images, None, library, config or RetrievalConfig())
    found = retrieve._likeness(seen)
    assert found is not None, "photos given"
    return found


def alike_hits(likeness: np.ndarray) -> int:
    """How many of a walk's ``P`` neighbouring pairs (photo i and i + 1, the last and the first)
    are among its ``P`` most alike pairs by ``likeness`` [P, P] (photos in walking order)."""
    n = len(likeness)
    pairs = sorted(((float(likeness[a, b]), a, b) for a in range(n) for b in range(a + 1, n)),
                   reverse=True)[:n]
    return sum((b - a) in (1, n - 1) for _, a, b in pairs)


def _retrieve(data: Any, perm: np.ndarray, library: Any, mode: str, exclude: tuple[str, ...],
              ) -> tuple[float, bool, bool]:
    """Retrieve the walk's photos in the order ``perm`` with ``order`` = ``mode``. Returns
    the median rotation error, whether the walk's cyclic order was found and whether the
    result said the order is a guess."""
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.retrieval.ordering import same_cycle
    from cadnerf_core.retrieval.search import retrieve

    config = RetrievalConfig(order=mode, exclude_models=exclude)  # type: ignore[arg-type]
    result = retrieve([data.masks[i] for i in perm], [data.names[i] for i in perm], library,
                      config, images=[data.images[i] for i in perm])
    order = result.order or list(range(len(perm)))
    walked = [int(perm[i]) for i in order]
    return (rotation_error(result, data.c2w[perm]),
            same_cycle(walked, list(range(len(perm)))), result.order_ambiguous)


def walk_set(name: str, views: int, direction: int, library: Any, work: Path,
             shuffles: int) -> Walk:
    """Render one walk of a mesh and retrieve it in order and shuffled."""
    def render(fov: float) -> Any:
        return load_walk(name, work / f"{name}_{views}_{direction}_{fov:g}", views,
                         seed=SEED + views, direction=direction, fov_deg=fov)

    data = render(40.0)
    alike = alike_hits(photo_likeness(list(data.masks), list(data.images), library))
    exclude = excluded(name)
    identity = np.arange(views)
    ordered = {mode: _retrieve(data, identity, library, mode, exclude)[0]
               for mode in ("walk", "auto")}
    wide = {}
    for fov in WIDE_FOVS:
        seen = render(fov)
        wide[fov] = {mode: _retrieve(seen, identity, library, mode, exclude)[0]
                     for mode in ("walk", "auto")}
    shuffled: dict[str, list[float]] = {"walk": [], "any": [], "auto": []}
    found: dict[str, list[bool]] = {"walk": [], "any": [], "auto": []}
    guess: list[bool] = []
    for seed in range(shuffles):
        perm = np.random.default_rng(seed).permutation(views)
        for mode in shuffled:
            error, right, ambiguous = _retrieve(data, perm, library, mode, exclude)
            shuffled[mode].append(error)
            found[mode].append(right)
            if mode == "any":
                guess.append(ambiguous)
    return Walk(name, views, ordered, shuffled, found, guess, wide, alike)


def solver_lines(library: Any) -> list[str]:
    """Time of the order search on 10 photos x the shipped library's full table."""
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.retrieval.ordering import any_order, choose_order, runner_up
    from cadnerf_core.retrieval.scoring import azimuth_bins

    config = RetrievalConfig()
    spec = library.spec
    rng = np.random.default_rng(0)
    iou = rng.random((10, 5, spec.n_views))
    similarity = rng.random((10, 10))
    similarity = (similarity + similarity.T) / 2
    az = azimuth_bins(library.az_el, spec.n_azimuths)
    one, five, second = [], [], []
    for _ in range(5):
        start = time.perf_counter()
        found = any_order(iou[:, 0], az, spec.n_azimuths, config.spread_weight, similarity,
                          config.similarity_weight)
        one.append(time.perf_counter() - start)
        start = time.perf_counter()
        runner_up(iou[:, 0], az, spec.n_azimuths, config.spread_weight, found.order,
                  similarity, config.similarity_weight)
        second.append(time.perf_counter() - start)
        start = time.perf_counter()
        choose_order(iou, range(5), az, spec.n_azimuths, "any", config.order_margin,
                     config.spread_weight, similarity, config.similarity_weight)
        five.append(time.perf_counter() - start)
    return [f"- Order search, 10 photos x {spec.n_views} views ({spec.n_azimuths} azimuths x "
            f"{len(spec.elevations)} elevations, every view a candidate): "
            f"**{statistics.median(one):.3f} s** for one model (target < 0.5 s); "
            f"{statistics.median(five):.3f} s for the five most voted, and "
            f"{statistics.median(second):.3f} s for the best walk in any other order (one "
            "search per neighbouring pair of the order found: whether the order is a guess); "
            "a job runs both, median of 5."]


def real_lines(library: Any, shuffles: int) -> list[str]:
    """The real photo sets in order and shuffled."""
    from benchmarks.retrieval_real import real_set_photos
    from cadnerf_core.cameras.conventions import pose_errors
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.intake.photos import load_photos
    from cadnerf_core.retrieval.ordering import same_cycle
    from cadnerf_core.retrieval.search import retrieve

    lines = []
    for name in REAL_SETS:
        if not (PHOTOS / name).is_dir():
            continue
        paths, mask_paths, _ = real_set_photos(name)
        photos = load_photos(paths, mask_paths)
        masks = [p.mask for p in photos if p.mask is not None]
        images = [p.rgb for p in photos]
        names = [p.name for p in photos]
        exclude = excluded(name)
        base = retrieve(masks, names, library, RetrievalConfig(order="walk",
                                                               exclude_models=exclude),
                        images=images)
        ref = np.stack([m.c2w for m in base.matches])
        runs = []
        for seed in range(shuffles):
            perm = np.random.default_rng(seed).permutation(len(photos))
            got = retrieve([masks[i] for i in perm], [names[i] for i in perm], library,
                           RetrievalConfig(order="any", exclude_models=exclude),
                           images=[images[i] for i in perm])
            rot, _ = pose_errors(np.stack([m.c2w for m in got.matches]), ref[perm])
            walked = [int(perm[i]) for i in got.order]
            found = "order found" if same_cycle(walked, list(range(len(perm)))) else \
                "order not found"
            ambiguous = ", direction a guess" if got.direction_ambiguous else ""
            if got.order_ambiguous:
                ambiguous += ", said a guess"
            runs.append(f"seed {seed}: {got.model_id}, {found}{ambiguous}, "
                        f"{float(np.median(rot)):.1f} deg")
        guess = " (direction a guess)" if base.direction_ambiguous else ""
        lines.append(f"- {name} ({len(photos)} photos, shipped masks): in order "
                     f"**{base.model_id}**{guess}; shuffled, `any` (poses against the ordered "
                     "run's): " + "; ".join(runs) + ".")
    return lines


def _table(walks: list[Walk]) -> list[str]:
    """Per view count: medians over walks, and the share of shuffles whose order was found."""
    rows = ["| views | in order, `walk` | in order, `auto` | shuffled, `walk` | shuffled, "
            "`any` | shuffled, `auto` | order found, `any` | order found, `auto` | `any` said "
            "a guess: orders not found / found | `auto` worse than `walk` in order |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for views in sorted({w.views for w in walks}):
        group = [w for w in walks if w.views == views]

        def med(values: list[float]) -> str:
            return f"{statistics.median(values):.1f}"

        def share(mode: str, of: list[Walk] = group) -> str:
            hits = [h for w in of for h in w.found[mode]]
            return f"{100.0 * sum(hits) / len(hits):.0f} %"

        worse = sum(w.ordered["auto"] > w.ordered["walk"] + 0.5 for w in group)
        runs = [(right, said) for w in group
                for right, said in zip(w.found["any"], w.guess, strict=True)]
        wrong_said = sum(said for right, said in runs if not right)
        right_said = sum(said for right, said in runs if right)
        guesses = (f"{wrong_said} of {sum(not right for right, _ in runs)} / {right_said} of "
                   f"{sum(right for right, _ in runs)}")
        rows.append(f"| {views} | {med([w.ordered['walk'] for w in group])} | "
                    f"{med([w.ordered['auto'] for w in group])} | "
                    f"{med([e for w in group for e in w.shuffled['walk']])} | "
                    f"**{med([e for w in group for e in w.shuffled['any']])}** | "
                    f"{med([e for w in group for e in w.shuffled['auto']])} | "
                    f"**{share('any')}** | {share('auto')} | {guesses} | {worse} of "
                    f"{len(group)} |")
    return rows


def _wide_rows(walks: list[Walk]) -> list[str]:
    """The walks in order through a phone's wider lens: ``walk`` against ``auto``."""
    rows = ["| views | field of view | in order, `walk` | in order, `auto` | `auto` reordered | "
            "`auto` worse than `walk` |", "|---|---|---|---|---|---|"]
    for views in sorted({w.views for w in walks}):
        group = [w for w in walks if w.views == views]
        for fov in WIDE_FOVS:
            errors = [w.wide[fov] for w in group]
            moved = sum(abs(e["auto"] - e["walk"]) > 1e-6 for e in errors)
            worse = [w.mesh for w, e in zip(group, errors, strict=True)
                     if e["auto"] > e["walk"] + 0.5]
            rows.append(f"| {views} | {fov:g} deg | "
                        f"{statistics.median(e['walk'] for e in errors):.1f} | "
                        f"{statistics.median(e['auto'] for e in errors):.1f} | {moved} of "
                        f"{len(group)} | {len(worse)} of {len(group)}"
                        f"{' (' + ', '.join(worse) + ')' if worse else ''} |")
    return rows


def _alike_line(walks: list[Walk]) -> str:
    """How well the order search's likeness prior tells neighbours apart, against chance."""
    parts = []
    for views in sorted({w.views for w in walks}):
        group = [w for w in walks if w.views == views]
        hits = sum(w.alike for w in group)
        chance = 100.0 * views / (views * (views - 1) / 2)
        parts.append(f"{views} views: {100.0 * hits / (views * len(group)):.0f} % "
                     f"(chance {chance:.0f} %)")
    return ("- Neighbours by likeness (the order search's prior: colours and outlines inside "
            "the masks, and shared points where matched): of each walk's neighbouring pairs, "
            "the share among its most alike pairs (as many as it has photos): "
            + "; ".join(parts) + ".")


def _mesh_rows(walks: list[Walk]) -> list[str]:
    rows = ["| mesh | views | in order, `walk` | shuffled, `any` (per seed) | order found | "
            "said a guess |", "|---|---|---|---|---|---|"]
    for w in walks:
        errors = ", ".join(f"{e:.1f}" for e in w.shuffled["any"])
        rows.append(f"| {w.mesh} | {w.views} | {w.ordered['walk']:.1f} | {errors} | "
                    f"{sum(w.found['any'])}/{len(w.found['any'])} | "
                    f"{sum(w.guess)}/{len(w.guess)} |")
    return rows


def run(quick: bool, library_dir: Path = LIBRARY_DIR) -> str:
    """Run the order benchmark. Returns its markdown section."""
    from cadnerf_core.library.format import load_library

    head = section_head("Order", "bench_order", quick)
    library = load_library(library_dir)
    lines = [*head, *solver_lines(library), ""]
    if not MESHES.is_dir():
        return "\n".join([*lines, "Walks not run: `../shared/eval` is absent.", ""])
    meshes = QUICK_MESHES if quick else eval_meshes()
    shuffles = 1 if quick else SHUFFLES
    walks = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, name in enumerate(meshes):
            for views in VIEW_COUNTS:
                direction = 1 if (i + views) % 2 else -1
                walks.append(walk_set(name, views, direction, library, Path(tmp), shuffles))
                log.info("%s, %d views: %s", name, views, walks[-1])
    lines += [f"Median rotation error (degrees) of the retrieved poses over {len(meshes)} meshes "
              f"(look-alikes left out), {shuffles} shuffle(s) per walk; order found: the "
              "walk's cyclic order recovered, up to start and direction.", "",
              *_table(walks), "", "The same walks in order, rendered through a phone's wider "
              "lens (the object filling the same share of the frame, as in `bench_unseen`); "
              "`auto` reordered: its poses differ from `walk`'s:", "", *_wide_rows(walks), "",
              *_mesh_rows(walks), "", _alike_line(walks), "", *real_lines(library, shuffles),
              ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the section (``--quick``: the short run)."""
    from benchmarks.run import area_main

    return area_main(run, "CAD-NeRF order benchmark", argv)


if __name__ == "__main__":
    sys.exit(main())

"""Matches between the photos (``retrieval.matches``: ALIKED and LightGlue), on and off.

- Synthetic walks: the retrieval benchmark's walks (same seeds: 6 and 9 views, elevations
  0-60, both directions) of the textured meshes and of the mug and the lamp, rendered at
  ``SIZE`` px so there is texture to match, retrieved with ``retrieval.matches.enabled`` on
  and off under the leave-out protocol (``benchmarks.lookalikes``): median rotation error,
  whether the walking direction came out right, whether it was flagged a guess, how many
  consecutive pairs gave a usable turn (with the right sign) and how far off it was. Then
  level walks of 10 views (elevations 15-25) of the meshes with a texture, as a person walks.
- The real espresso photos (shipped masks, EXIF focal length): retrieval on and off against
  their coarse metadata poses, under both protocols; a picture of the matches of the
  consecutive pair with the most inliers in ``docs/matches_espresso.png``.
- Speed: matching ten photos of 12 megapixels (the espresso photos enlarged to 4000 x 3000,
  three of them mirrored to make ten), photo decoding excluded.

Usage: ``python -m benchmarks.bench_matches [--quick]`` prints the section.
"""

from __future__ import annotations

import logging
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import (
    ABSENT,
    DOCS,
    LIBRARY_DIR,
    MESHES,
    PHOTOS,
    SEED,
    render_walk,
    rotation_error,
    section_head,
)
from benchmarks.lookalikes import excluded
from benchmarks.results import Result, cpu_cores, record, today
from benchmarks.retrieval_real import real_set_photos
from benchmarks.retrieval_walks import VIEW_COUNTS

log = logging.getLogger(__name__)

PICTURE = DOCS / "matches_espresso.png"
SIZE = 512
TEXTURED = ("CesiumMilkTruck", "Duck", "spot", "fuze", "YcbMustardBottle", "YcbPowerDrill",
            "armchair")
MIRRORED = ("ycb_mug", "fsu_kerolamp")  # walks the silhouettes alone could come out mirrored
QUICK = ("CesiumMilkTruck", "fuze", "ycb_mug")
CONTEXT = 0.5  # ``MatchesConfig.context`` measured against the object alone on the real photos
PAINTED = ("CesiumMilkTruck", "Duck", "spot", "fuze", "armchair")  # meshes with a texture
LEVEL_VIEWS = 10
LEVEL_ELEVATIONS = (15.0, 25.0)


@dataclass
class WalkResult:
    """One walk retrieved with the matches on and off."""

    mesh: str
    views: int
    direction: int
    error: dict[bool, float]  # matches on? -> median rotation error (degrees)
    found: dict[bool, int]  # matches on? -> walking direction found
    guess: dict[bool, bool]  # matches on? -> direction flagged ambiguous
    turns: int  # consecutive pairs with a turn of a walking step's size
    right: int  # of which the sign is the walk's
    turn_errors: list[float]  # of those: |matched turn - true turn| (degrees)


def _config(name: str, enabled: bool) -> Any:
    from cadnerf_core.config import MatchesConfig, RetrievalConfig

    return RetrievalConfig(exclude_models=excluded(name),
                           matches=MatchesConfig(enabled=enabled))


def walk(name: str, views: int, direction: int, library: Any, work: Path,
         elevations: tuple[float, float] = (0.0, 60.0)) -> WalkResult:
    """Render one walk at ``SIZE`` px and retrieve it with the matches on and off."""
    import json

    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.retrieval.search import retrieve

    folder = render_walk(name, work / f"{name}_{views}_{direction}_{elevations[0]:g}", views,
                         size=SIZE, seed=SEED + views, direction=direction,
                         elevation_range=elevations)
    data = load_dataset(folder)
    azimuths = json.loads((folder / "dataset.json").read_text())["azimuths"]
    results = {on: retrieve(list(data.masks), data.names, library, _config(name, on),
                            images=list(data.images)) for on in (False, True)}
    low, high = (share * 360.0 / views for share in _config(name, True).matches.turn_range)
    turns = [(p["turn_deg"], (azimuths[p["j"]] - azimuths[p["i"]] + 180.0) % 360.0 - 180.0)
             for p in results[True].photo_pairs if p["j"] == p["i"] + 1
             and p["turn_deg"] is not None and low <= abs(p["turn_deg"]) <= high]
    return WalkResult(name, views, direction,
                      {on: rotation_error(r, data.c2w) for on, r in results.items()},
                      {on: r.direction for on, r in results.items()},
                      {on: r.direction_ambiguous for on, r in results.items()},
                      len(turns), sum(np.sign(t) == direction for t, _ in turns),
                      [abs(t - true) for t, true in turns])


def walk_lines(results: list[WalkResult]) -> list[str]:
    """Per mesh: median rotation error off/on, walks with the right direction, guesses."""
    lines = ["| mesh | walks | median rot. error, off | on | right direction, off | on | "
             "flagged a guess, off | on | consecutive pairs with a usable turn (right sign) | "
             "median turn error (deg) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for mesh in dict.fromkeys(r.mesh for r in results):
        own = [r for r in results if r.mesh == mesh]
        cells = [f"{np.median([r.error[on] for r in own]):.1f}" for on in (False, True)]
        cells += [str(sum(r.found[on] == r.direction for r in own)) for on in (False, True)]
        cells += [str(sum(r.guess[on] for r in own)) for on in (False, True)]
        pairs = sum(r.views - 1 for r in own)
        lines.append(f"| {mesh} | {len(own)} | {' | '.join(cells)} | "
                     f"{sum(r.turns for r in own)} of {pairs} "
                     f"({sum(r.right for r in own)}) | {_median_text(own)} |")
    return lines


def _median_text(results: list[WalkResult]) -> str:
    errors = [e for r in results for e in r.turn_errors]
    return f"{np.median(errors):.1f}" if errors else "-"


def espresso_lines(library: Any) -> list[str]:
    """The espresso photos retrieved with the matches on and off, and the picture."""
    from cadnerf_core.config import MatchesConfig, RetrievalConfig
    from cadnerf_core.intake.photos import load_photos
    from cadnerf_core.retrieval.search import photo_pairs, retrieve

    paths, mask_paths, gt = real_set_photos("ners_espresso")
    photos = load_photos(paths, mask_paths)
    masks = [p.mask for p in photos if p.mask is not None]
    images, focals = [p.rgb for p in photos], [p.focal_pixels for p in photos]
    names = [p.name for p in photos]
    lines = []
    assert gt is not None
    variants = (("off", MatchesConfig(enabled=False)),
                ("on, the object's own points", MatchesConfig(context=0.0)),
                (f"on, with what stands round it (context {CONTEXT})",
                 MatchesConfig(context=CONTEXT)))
    for protocol, exclude in (("leave-out", excluded("ners_espresso")), ("with look-alike", ())):
        said = []
        for label, matches in variants:
            config = RetrievalConfig(exclude_models=exclude, matches=matches)
            result = retrieve(masks, names, library, config, images=images, focals=focals)
            said.append(f"{rotation_error(result, gt):.1f} deg {label} ({result.model_id}, "
                        f"direction {result.direction:+d})")
        lines.append(f"- ners_espresso, {protocol}: median rotation error of the retrieved "
                     f"cameras vs the coarse metadata poses: {'; '.join(said)}.")
    alone = photo_pairs(images, masks, focals,
                        RetrievalConfig(matches=MatchesConfig(context=0.0)))
    usable = MatchesConfig().min_inliers
    lines.append(f"- pairs with {usable} inliers or more: "
                 f"{sum(p.inliers >= usable for p in alone)} on the object's own points")
    pairs = photo_pairs(images, masks, focals,
                        RetrievalConfig(matches=MatchesConfig(context=CONTEXT)))
    lines[-1] += f", {sum(p.inliers >= usable for p in pairs)} with what stands round it."
    lines.append("- pairs (i-j: inliers/mutual matches, median Sampson error px, turn deg): "
                 + ", ".join(f"{p.i}-{p.j}: {p.inliers}/{p.matched}"
                             + (f", {p.sampson_px:.2f}" if p.sampson_px is not None else "")
                             + (f", {p.turn_deg:+.0f}" if p.turn_deg is not None else "")
                             for p in pairs))
    best = max((p for p in pairs if p.j == p.i + 1), key=lambda p: p.inliers)
    draw_pair(images[best.i], images[best.j], best, PICTURE)
    lines.append(f"- picture: `docs/{PICTURE.name}` (photos {best.i} and {best.j}, "
                 f"{best.inliers} inliers)")
    return lines


def draw_pair(image_a: np.ndarray, image_b: np.ndarray, pair: Any, out: Path) -> None:
    """The pair's picture as a job stores it (``pairs_io.pair_picture``)."""
    from PIL import Image

    from cadnerf_core.cameras.pairs_io import pair_picture

    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pair_picture(image_a, image_b, pair)).save(out)


def ten_photos() -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Ten 12-megapixel photos: the espresso photos enlarged to 4000 x 3000, three of them
    mirrored to make ten, with their masks."""
    import cv2

    from cadnerf_core.intake.photos import load_photos

    paths, mask_paths, _ = real_set_photos("ners_espresso")
    photos = load_photos(paths, mask_paths)
    images, masks = [], []
    for i in range(10):
        photo = photos[i % len(photos)]
        assert photo.mask is not None
        image = cv2.resize(photo.rgb, (4000, 3000), interpolation=cv2.INTER_LINEAR)
        mask = cv2.resize(photo.mask.astype(np.uint8), (4000, 3000),
                          interpolation=cv2.INTER_NEAREST) > 0
        flip = i >= len(photos)
        images.append(image[:, ::-1] if flip else image)
        masks.append(mask[:, ::-1] if flip else mask)
    return images, masks


def speed_line(headline: bool = True) -> str:
    """Matching ten 12-megapixel photos (decoding excluded), and where the time goes
    (``headline``: recorded as the README's figure, ``benchmarks.results``)."""
    from cadnerf_core.cameras import learned
    from cadnerf_core.cameras.matches import verify_matches
    from cadnerf_core.config import MatchesConfig, RetrievalConfig
    from cadnerf_core.retrieval.search import photo_pairs

    images, masks = ten_photos()
    config = MatchesConfig()
    method = learned.learned_method(config)
    features_name, glue_name = ("ALIKED", "LightGlue") if method == "aliked" \
        else ("XFeat", "LighterGlue")
    photo_pairs(images[:2], masks[:2], [None] * 2, RetrievalConfig())  # networks loaded once
    start = time.perf_counter()
    pairs = photo_pairs(images, masks, [None] * 10, RetrievalConfig())
    seconds = time.perf_counter() - start
    clock = time.perf_counter()
    features = [learned.detect(image, mask, config.size, method=method,
                                keypoints=config.keypoints)
                for image, mask in zip(images, masks, strict=True)]
    detect_s, clock = time.perf_counter() - clock, time.perf_counter()
    close = learned.close_pairs(10)
    glued = {e: learned.match_glue(features[e[0]], features[e[1]]) for e in sorted(close)}
    glue_s, clock = time.perf_counter() - clock, time.perf_counter()
    others = {(i, j): learned.match_mutual(features[i], features[j])
              for i in range(10) for j in range(i + 1, 10) if (i, j) not in close}
    mutual_s, clock = time.perf_counter() - clock, time.perf_counter()
    K = np.array([[4800.0, 0.0, 2000.0], [0.0, 4800.0, 1500.0], [0.0, 0.0, 1.0]])
    for (i, j), found in {**glued, **others}.items():
        verify_matches(i, j, features[i], features[j], found, K, K, config)
    verify_s = time.perf_counter() - clock
    if headline:
        record(Result("matching_ten_photos", "matching ten 12 MP photos", seconds, "s", 1,
                      cpu_cores(), ".venv/bin/python -c 'from benchmarks.bench_matches import "
                      "speed_line; print(speed_line())'", today()))
    return (f"- Matching ten 4000 x 3000 photos (45 pairs: {glue_name} on the {len(close)} "
            f"neighbouring and next-but-one pairs, mutual nearest descriptors on the others; "
            f"crops at {config.size} px), decoding excluded: **{seconds:.1f} s** on 2 CPU "
            f"cores ({sum(p.inliers for p in pairs)} inliers in all). Where it goes: "
            f"{features_name} on the ten crops (and cropping, resizing) {detect_s:.1f} s, "
            f"{glue_name} "
            f"{glue_s:.1f} s, mutual nearest {mutual_s:.2f} s, verification (USAC essential "
            f"matrix, pose) {verify_s:.2f} s.")


def run(quick: bool, library_dir: Path = LIBRARY_DIR) -> str:
    """Run the benchmark. Returns its markdown section."""
    from cadnerf_core.library.format import load_library

    head = section_head("Matches between the photos", "bench_matches", quick)
    if not MESHES.is_dir():
        return "\n".join([*head, ABSENT, ""])
    library = load_library(library_dir)
    work = Path(tempfile.mkdtemp(prefix="bench_matches_"))
    meshes = QUICK if quick else TEXTURED + MIRRORED
    try:
        results = [walk(name, views, direction, library, work)
                   for name in meshes for views in VIEW_COUNTS for direction in (1, -1)]
        level = [walk(name, LEVEL_VIEWS, direction, library, work, LEVEL_ELEVATIONS)
                 for name in meshes if name in PAINTED for direction in (1, -1)]
    finally:
        shutil.rmtree(work, ignore_errors=True)
    lines = [*head, f"Synthetic walks at {SIZE} px, leave-out protocol; rotation error after "
             "similarity alignment (degrees), median over the walks (each walk's own median "
             "over its kept photos). The mustard bottle, the drill, the mug and the lamp "
             "render plain grey (the YCB meshes' texture images are not in the eval set; the "
             "lamp has none): nothing to match. A turn is usable at 0.4 to 2 even steps "
             "(`MatchesConfig.turn_range`); its error is against the true azimuth change.", "",
             "The retrieval benchmark's walks (its seeds; 6 and 9 views, elevations 0-60 at "
             "random, so consecutive photos differ by 40-60 degrees of azimuth and up to 50 "
             "of elevation):", "", *walk_lines(results), "",
             f"Level walks of the meshes with texture: {LEVEL_VIEWS} views, elevations "
             f"{LEVEL_ELEVATIONS[0]:g}-{LEVEL_ELEVATIONS[1]:g} (a person walking round with "
             "a phone), both directions:", "", *walk_lines(level), ""]
    if (PHOTOS / "ners_espresso").is_dir():
        lines += [*espresso_lines(library), speed_line(headline=not quick)]
    return "\n".join([*lines, ""])


def main(argv: list[str] | None = None) -> int:
    """Print the section (``--quick``: the short run)."""
    from benchmarks.run import area_main

    return area_main(run, "CAD-NeRF matches benchmark", argv)


if __name__ == "__main__":
    sys.exit(main())

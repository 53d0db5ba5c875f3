"""Background removal on real phone photos: mask quality, retrieval, speed and training.

- Quality: on each real set of ``../shared/eval/photos``, the IoU of the built-in masks against
  the shipped ones, per photo, for the methods ``learned``, ``grabcut`` and ``auto``.
- Retrieval: the model chosen with the learned masks and with the shipped masks, per set,
  with the set's look-alikes left out (the headline) and with them in.
- Speed: masks for ten 12 MP JPEGs (the real photos upscaled to 4000x3000), read by intake
  as a job reads them and masked by the learned method, on this machine's CPU (the median
  of three rounds); peak memory as the growth of the process's peak resident size
  (``ru_maxrss``) in the first round.
- Training (not with ``--quick``): a ``preview`` job's training PSNR per set with the built-in
  masks and with the shipped masks, look-alikes left out (a few minutes a job).

Usage: ``python -m benchmarks.bench_masks [--quick] [--library DIR]`` prints the section.
``python -m benchmarks.bench_masks --retrieval`` prints only the retrieval lines.
``python -m benchmarks.bench_masks --training [--sets NAME ...] [--seeds N ...] [--overrides JSON]``
prints only the training lines (seeds 0, 1, 2 by default, and their mean), with configuration
values set in both jobs of each set (a lever's effect:
``'{"masks.doubt_weight": 0, "retrieval.perspective": "near"}'``).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from benchmarks.harness import LIBRARY_DIR, PHOTOS, PRESET, run_job, section_head
from benchmarks.lookalikes import PROTOCOLS, exclude_overrides, excluded
from benchmarks.results import Result, cpu_cores, record, today
from benchmarks.retrieval_real import real_set_photos

if TYPE_CHECKING:
    from cadnerf_core.intake.masks import MaskMethod

SETS = ("ners_espresso", "raydiffusion_robot")
SET_LABELS = {"ners_espresso": "espresso", "raydiffusion_robot": "robot"}  # in the README
METHODS: tuple[MaskMethod, ...] = ("learned", "grabcut", "auto")
TARGET_IOU = 0.90
BIG_SIDES = (4000, 3000)  # a 12 MP phone photo, landscape
BIG_COUNT = 10
SPEED_ROUNDS = 3  # the speed figure is their median
TRAINING_SEEDS = (0, 1, 2)  # the training comparison's seeds, its figure their mean


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(int((a | b).sum()), 1))


def _load(name: str) -> tuple[list[Any], list[Path], list[Path]]:
    """A set's photos with their shipped masks, and the photo and mask paths."""
    from cadnerf_core.intake.photos import load_photos

    paths, mask_paths, _ = real_set_photos(name)
    return load_photos(paths, mask_paths), paths, mask_paths


def quality(name: str, shipped: list[Any]) -> tuple[list[str], dict[str, list[np.ndarray]]]:
    """Per-photo IoU table of one set for every method, and each method's masks."""
    from cadnerf_core.errors import InputError
    from cadnerf_core.intake.masks import photo_masks
    from cadnerf_core.intake.photos import Photo

    bare = [Photo(p.name, p.rgb) for p in shipped]
    ious: dict[str, list[float]] = {}
    found: dict[str, list[np.ndarray]] = {}
    notes = []
    for method in METHODS:
        start = time.perf_counter()
        try:
            results = photo_masks(bare, method)
        except InputError as exc:
            notes.append(f"- {method}: refused a photo: {exc}")
            continue
        seconds = (time.perf_counter() - start) / len(bare)
        found[method] = [r.mask for r in results]
        ious[method] = [_iou(r.mask, p.mask) for r, p in zip(results, shipped, strict=True)]
        warned = sum(bool(r.warnings) for r in results)
        notes.append(f"- {method} (ran {results[0].source}): mean IoU "
                     f"**{np.mean(ious[method]):.3f}**, min {min(ious[method]):.2f}; "
                     f"{seconds:.2f} s a photo ({shipped[0].rgb.shape[1]}x"
                     f"{shipped[0].rgb.shape[0]} px); {warned} photo(s) with warnings")
    header = "| photo | " + " | ".join(ious) + " |"
    lines = [f"### {name}", "", header, "|---" * (len(ious) + 1) + "|"]
    for i, photo in enumerate(shipped):
        lines.append(f"| {photo.name} | " + " | ".join(f"{v[i]:.3f}" for v in ious.values())
                     + " |")
    lines.append("| **mean** | " + " | ".join(f"**{np.mean(v):.3f}**" for v in ious.values())
                 + " |")
    return [*lines, "", *notes], found


def retrieval(name: str, shipped: list[Any], learned: list[np.ndarray], library: Any) -> str:
    """One line: the model retrieved with the shipped and with the learned masks, under the
    leave-out protocol (the headline: the set's look-alikes excluded) and with them in; where
    they differ, how close each set of masks scores the two models (``walk_scores``)."""
    from cadnerf_core.config_retrieval import RetrievalConfig
    from cadnerf_core.retrieval.search import retrieve

    names = [p.name for p in shipped]
    images = [p.rgb for p in shipped]
    focals = [p.focal_pixels for p in shipped]
    mask_sets = {"shipped": [p.mask for p in shipped], "learned": learned}
    parts = []
    for protocol in PROTOCOLS:
        config = RetrievalConfig(exclude_models=excluded(name, protocol))
        picked = [retrieve(masks, names, library, config=config, images=images,
                           focals=focals).model_id for masks in mask_sets.values()]
        same = "same model" if picked[0] == picked[1] else "DIFFERENT"
        part = (f"{protocol}: shipped masks **{picked[0]}**, learned masks **{picked[1]}** "
                f"({same})")
        if picked[0] != picked[1]:
            scores = {label: walk_scores(masks, names, images, focals, library, picked)
                      for label, masks in mask_sets.items()}
            part += "; best walk of each, objective a photo (IoU less the gap prior): " + \
                ", ".join(f"{label} masks {picked[0]} {s[0]:.3f} / {picked[1]} {s[1]:.3f}"
                          for label, s in scores.items())
        parts.append(part)
    return f"- {name}: " + "; ".join(parts)


def walk_scores(masks: list[np.ndarray], names: list[str], images: list[np.ndarray],
                focals: list[float | None], library: Any, models: list[str]) -> list[float]:
    """Each of ``models``' best walk with these masks (retrieval with that model alone in the
    library, its objective over the photos): how far apart the masks put two models."""
    from cadnerf_core.config_retrieval import RetrievalConfig
    from cadnerf_core.retrieval.search import retrieve

    ids = [m.id for m in library.models]
    out = []
    for model in models:
        alone = RetrievalConfig(exclude_models=tuple(i for i in ids if i != model))
        result = retrieve(masks, names, library, config=alone, images=images, focals=focals)
        out.append(result.score / len(masks))
    return out


def _big_photos(photos: list[Any], folder: Path) -> list[Path]:
    """``BIG_COUNT`` photos upscaled to 12 MP (4000x3000, or 3000x4000 for portrait ones),
    written as JPEG files (quality 92, as a phone writes them) into ``folder``."""
    import cv2

    paths = []
    for i in range(BIG_COUNT):
        photo = photos[i % len(photos)]
        height, width = photo.rgb.shape[:2]
        size = BIG_SIDES if width >= height else BIG_SIDES[::-1]
        big = cv2.resize(np.clip(photo.rgb * 255.0 + 0.5, 0, 255).astype(np.uint8), size,
                         interpolation=cv2.INTER_LINEAR)
        path = folder / f"big_{i}.jpg"
        cv2.imwrite(str(path), big[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 92])
        paths.append(path)
    return paths


def speed(photos: list[Any]) -> list[str]:
    """Time and peak memory growth for the learned masks of ten 12 MP photos, read from
    their files as a job reads them (intake decodes each at its working size): the median of
    ``SPEED_ROUNDS`` rounds, as one round on a shared 2-core machine varies by tens of per cent;
    memory as the growth over the first round."""
    from cadnerf_core.intake.limits import WORKING_PIXELS
    from cadnerf_core.intake.masks import photo_masks
    from cadnerf_core.intake.photos import Photo, load_photos

    folder = Path(tempfile.mkdtemp(prefix="bench_masks_big_"))
    rounds, reads, grown = [], [], 0.0
    try:
        paths = _big_photos(photos, folder)
        photo_masks([Photo("warm.jpg", photos[0].rgb)], "learned")  # model loaded once a process
        for i in range(SPEED_ROUNDS):
            before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            start = time.perf_counter()
            loaded = load_photos(paths)
            reads.append(time.perf_counter() - start)
            photo_masks(loaded, "learned")
            rounds.append(time.perf_counter() - start)
            if i == 0:
                grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    worked = loaded[0].rgb.shape
    load = os.getloadavg()[0]
    seconds, read = float(np.median(rounds)), float(np.median(reads))
    return [f"- Ten 12 MP JPEGs (4000x3000), read and masked as a job does (decoded at the "
            f"working size, at most {WORKING_PIXELS / 1e6:.0f} MP: {worked[1]}x{worked[0]}), "
            f"learned masks, median of {SPEED_ROUNDS} rounds: **{seconds:.1f} s** in all "
            f"({seconds / BIG_COUNT:.2f} s a photo; reading {read:.1f} s; rounds "
            f"{', '.join(f'{r:.1f}' for r in rounds)} s; goal under 10 s on 2 cores); peak "
            f"resident memory grew by **{grown:.0f} MiB** in the first round (``ru_maxrss`` "
            f"delta, the photos and the native allocations of OpenCV and onnxruntime "
            f"included). Load average after the rounds: {load:.1f} on {os.cpu_count()} cores."]


def training(name: str, paths: list[Path], mask_paths: list[Path], library: Any,
             overrides: dict[str, Any] | None = None,
             seeds: tuple[int, ...] = (0,)) -> str:
    """One line: a preview job's training PSNR with the built-in and the shipped masks, for
    each of ``seeds`` and their mean (the set's look-alikes left out of the library;
    ``overrides`` set in both jobs). One seed's difference is mostly chance (the section
    lists each seed's): hence the mean over seeds."""
    from cadnerf_core.config import internal_config

    runs = []
    for seed in seeds:
        psnr, model = {}, {}
        for label, masks in (("built-in", None), ("shipped", mask_paths)):
            job = Path(tempfile.mkdtemp(prefix="bench_masks_job_"))
            try:
                values = {**exclude_overrides(name), "seed": seed, **(overrides or {})}
                run = run_job(job, library, photos=paths, masks=masks,
                              config=internal_config(PRESET, values), device="auto")
                psnr[label] = float(run.metrics["mean_psnr"])
                model[label] = run.summary.model.id
            finally:
                shutil.rmtree(job, ignore_errors=True)
        runs.append((psnr, model))
    each = [f"built-in masks {p['built-in']:.2f} dB ({m['built-in']}), shipped masks "
            f"{p['shipped']:.2f} dB ({m['shipped']}), difference "
            f"{p['built-in'] - p['shipped']:+.2f} dB" for p, m in runs]
    if len(runs) == 1:
        return f"- {name}: {each[0]} (target within 1 dB)"
    built, shipped = (float(np.mean([p[k] for p, _ in runs])) for k in ("built-in", "shipped"))
    seeds_text = "; ".join(f"seed {seed}: {text}" for seed, text in zip(seeds, each,
                                                                          strict=True))
    return (f"- {name}, mean over seeds {', '.join(map(str, seeds))}: built-in masks "
            f"**{built:.2f}** dB, shipped masks **{shipped:.2f}** dB, difference "
            f"**{built - shipped:+.2f} dB** (target within 1 dB). {seeds_text}.")


def _record_iou(name: str, iou: float) -> None:
    """The set's mean IoU of the default (``auto``) masks, as the README's figure."""
    label = SET_LABELS.get(name, name)
    record(Result(f"masks_iou_{label}", f"masks made for real phone photos ({label}), IoU "
                  "with hand-made masks", iou, "", 3, cpu_cores(),
                  ".venv/bin/python -m benchmarks.run --only masks --out docs/benchmarks.md",
                  today()))


def run(quick: bool, library_dir: Path = LIBRARY_DIR) -> str:
    """Run the mask benchmark. Returns its markdown section."""
    head = section_head("Masks", "bench_masks", quick)
    present = [n for n in SETS if (PHOTOS / n / "masks").is_dir()]
    if not present:
        return "\n".join([*head, "Not run: `../shared/eval/photos` is absent.", ""])
    library = None
    if library_dir.is_dir():
        from cadnerf_core.library.format import load_library

        library = load_library(library_dir)
    lines = [*head, f"IoU of the built-in masks against the shipped masks (target >= "
             f"{TARGET_IOU:.2f} on each set):", ""]
    picks, loaded = [], {}
    for name in present:
        shipped, paths, mask_paths = _load(name)
        loaded[name] = (shipped, paths, mask_paths)
        table, found = quality(name, shipped)
        lines += [*table, ""]
        if not quick and "auto" in found:
            _record_iou(name, float(np.mean([_iou(m, p.mask) for m, p in
                                             zip(found["auto"], shipped, strict=True)])))
        if library is not None and "learned" in found:
            picks.append(retrieval(name, shipped, found["learned"], library))
    lines += ["Retrieval, model chosen with each set's masks:", "",
              *(picks or [f"- not run: no library at `{library_dir}`"]), "", "Speed:", "",
              *speed([p for name in present for p in loaded[name][0]]), ""]
    if not quick and library is not None:
        lines += ["Training, `preview` preset, mean training PSNR:", ""]
        lines += [training(name, loaded[name][1], loaded[name][2], library,
                           seeds=TRAINING_SEEDS) for name in present]
        lines.append("")
    return "\n".join(lines)


def training_only(argv: list[str]) -> int:
    """``--training``: the training lines alone, for the sets named (default: every set)."""
    parser = argparse.ArgumentParser(description="CAD-NeRF mask benchmark, training only")
    parser.add_argument("--training", action="store_true")
    parser.add_argument("--sets", nargs="+", choices=SETS, default=list(SETS))
    parser.add_argument("--overrides", type=json.loads, default=None)
    parser.add_argument("--seeds", type=int, nargs="+", default=list(TRAINING_SEEDS))
    parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from cadnerf_core.library.format import load_library

    library = load_library(args.library)
    for name in args.sets:
        paths, mask_paths, _ = real_set_photos(name)
        print(training(name, paths, mask_paths, library, args.overrides, tuple(args.seeds)),
              flush=True)
    return 0


def retrieval_only(argv: list[str]) -> int:
    """``--retrieval``: the retrieval lines alone (each set's learned masks made afresh)."""
    parser = argparse.ArgumentParser(description="CAD-NeRF mask benchmark, retrieval only")
    parser.add_argument("--retrieval", action="store_true")
    parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    args = parser.parse_args(argv)
    from cadnerf_core.intake.masks import photo_masks
    from cadnerf_core.intake.photos import Photo
    from cadnerf_core.library.format import load_library

    library = load_library(args.library)
    for name in SETS:
        if (PHOTOS / name / "masks").is_dir():
            shipped = _load(name)[0]
            learned = [r.mask for r in photo_masks([Photo(p.name, p.rgb) for p in shipped],
                                                   "learned")]
            print(retrieval(name, shipped, learned, library), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Print the section (``--quick``: the short run; ``--training``: ``training_only``;
    ``--retrieval``: ``retrieval_only``)."""
    from benchmarks.run import area_main

    argv = sys.argv[1:] if argv is None else argv
    if "--training" in argv:
        return training_only(argv)
    if "--retrieval" in argv:
        return retrieval_only(argv)
    return area_main(run, "CAD-NeRF mask benchmark", argv)


if __name__ == "__main__":
    sys.exit(main())

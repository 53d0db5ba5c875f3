"""The real captures' neighbouring pairs: how many relative rotations the matches get right.

Each capture of ``bench_captures`` (real photos round an object, reference cameras) is matched
as a job matches it (XFeat features inside the masks, LighterGlue between neighbours and
next-but-one neighbours, an essential matrix by USAC MAGSAC) at the reference focal length (the
espresso photos: their EXIF), so the figure is the matcher's alone. Each of those close pairs
that gets a rotation is right when it is within ``RIGHT_DEG`` of the reference cameras'
relative rotation, else wrong; the rest get none. Counted twice: with the orbit check
(``retrieval.orbit``: both photos must look at one object) and without it, to show what the
check removes. Then every pair a job matches (mutual nearest descriptors between the photos
farther apart), with the check: right / wrong among them, and among those the mapper is given
(``mapper.mapper_pairs``: the geometry explains ``MIN_INLIER_SHARE`` of the matches or more).
Masks: the capture's own, else made as a job makes them. ``--users``: the captures at the
users' spacing instead (``capture_set.users_captures``: photos 30 to 60 degrees apart).

QUICK: not run (matching-only, about 2 minutes on 2 cores).

Usage: ``python -m benchmarks.bench_pairs [--captures NAME ...] [--users] [--set KEY=VALUE]``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_captures import Capture, capture_names, load_capture
from benchmarks.capture_set import users_captures
from benchmarks.harness import ABSENT, section_head

RIGHT_DEG = 10.0
"""Largest error of a pair's rotation counted right."""


def _angle(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _photos(capture: Capture) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """The capture's photos as a job reads them, their masks and intrinsics."""
    from cadnerf_core.intake.masks import photo_masks
    from cadnerf_core.intake.photos import load_photo

    masks_in: list[Path | None] = [*capture.masks] if capture.masks else [None] * len(
        capture.photos)
    photos = [load_photo(p, i, m) for i, (p, m) in enumerate(zip(capture.photos, masks_in,
                                                                   strict=True))]
    masks = [found.mask for found in photo_masks(photos)]
    intrinsics = []
    for i, photo in enumerate(photos):
        height, width = photo.rgb.shape[:2]
        focal = capture.focal[i] if capture.focal is not None else photo.focal_pixels
        focal = focal or 1.2 * max(width, height)
        intrinsics.append(np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0],
                                    [0.0, 0.0, 1.0]]))
    return [p.rgb for p in photos], masks, intrinsics


def count_pairs(capture: Capture, config: Any = None) -> dict[str, Any]:
    """The capture's close pairs, right / wrong / none, without and with the orbit check
    (``config``: the ``MatchesConfig`` matched with, the default's when None)."""
    from cadnerf_core.cameras import learned
    from cadnerf_core.cameras.mapper import mapper_pairs
    from cadnerf_core.cameras.matches import verify_matches
    from cadnerf_core.cameras.orbit import object_centre
    from cadnerf_core.config import MatchesConfig

    images, masks, intrinsics = _photos(capture)
    config = config or MatchesConfig()
    method = learned.learned_method(config)
    features = [learned.detect(image, mask, config.size, config.context, method,
                                config.keypoints)
                for image, mask in zip(images, masks, strict=True)]
    close = learned.close_pairs(len(images))
    indices = learned.match_indices(features, close)
    centres = [object_centre(mask) for mask in masks]
    w2c = np.linalg.inv(capture.c2w)

    def right(pair: Any) -> bool:
        truth = w2c[pair.j][:3, :3] @ capture.c2w[pair.i][:3, :3]
        return _angle(pair.rotation @ truth.T) <= RIGHT_DEG

    row: dict[str, Any] = {"capture": capture.name, "pairs": len(close)}
    plain = [verify_matches(i, j, features[i], features[j], indices[(i, j)], intrinsics[i],
                            intrinsics[j], config) for i, j in sorted(close)]
    every = [verify_matches(i, j, features[i], features[j], found, intrinsics[i],
                            intrinsics[j], config, (centres[i], centres[j]))
             for (i, j), found in sorted(indices.items())]
    checked = [p for p in every if (p.i, p.j) in close]
    for label, pairs in (("plain", plain), ("orbit", checked), ("all", every)):
        _count(row, label, [p for p in pairs if p.rotation is not None], right)
    _count(row, "mapper", mapper_pairs(every, config.min_inliers), right)
    return row


def _count(row: dict[str, Any], label: str, pairs: list[Any],
           right: Callable[[Any], bool]) -> None:
    """Count the right and wrong pairs into ``row`` under ``label``."""
    good = sum(bool(right(p)) for p in pairs)
    row[f"{label}_right"], row[f"{label}_wrong"] = good, len(pairs) - good


def table(rows: list[dict[str, Any]]) -> list[str]:
    """The section's table: one row a capture, then the totals."""
    lines = ["| capture | close pairs | right / wrong, essential matrix alone | right / wrong, "
             "with the orbit check | every pair, right / wrong | given to the mapper, right / "
             "wrong |", "| --- | ---: | ---: | ---: | ---: | ---: |"]
    keys = [f"{label}_{kind}" for label in ("plain", "orbit", "all", "mapper")
            for kind in ("right", "wrong")]
    total = {key: sum(r.get(key, 0) for r in rows) for key in ("pairs", *keys)}
    for r in [*rows, {"capture": "**all**", **total}]:
        cells = [f"{r.get(f'{label}_right', '')} / {r.get(f'{label}_wrong', '')}"
                 for label in ("plain", "orbit", "all", "mapper")]
        lines.append(f"| {r['capture']} | {r['pairs']} | " + " | ".join(cells) + " |")
    return lines


def run(quick: bool, names: list[str] | None = None, users: bool = False,
        settings: Sequence[str] = ()) -> str:
    """The section's markdown (QUICK: not run); ``users``: the captures at the users' spacing;
    ``settings``: ``MatchesConfig`` fields as ``key=value``."""
    return "\n".join(_lines(quick, names, users, settings)) + "\n"


def matches_config(settings: Sequence[str]) -> Any:
    """The ``MatchesConfig`` with ``key=value`` settings (``cadnerf eval --set``'s parser)."""
    from cadnerf_cli.eval_cmd import parse_overrides
    from cadnerf_core.config import MatchesConfig

    return MatchesConfig(**parse_overrides(list(settings)))


def _lines(quick: bool, names: list[str] | None, users: bool = False,
           settings: Sequence[str] = ()) -> list[str]:
    head = section_head("Matches on real captures: relative rotations right and wrong",
                        "bench_pairs" + (" --users" if users else "")
                        + "".join(f" --set {s}" for s in settings), quick,
                        ": close pairs (neighbours and next-but-one) of each capture; a "
                        f"rotation within {RIGHT_DEG:.0f} degrees of the reference cameras' "
                        "is right.")
    if quick:
        return [*head, "Not run under QUICK (matching-only, about 2 minutes)."]
    captures = users_captures(names) if users else [load_capture(name)
                                                    for name in names or capture_names()]
    if not captures:
        return [*head, ABSENT]
    config = matches_config(settings)
    return [*head, *table([count_pairs(capture, config) for capture in captures])]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", nargs="*", default=None)
    parser.add_argument("--users", action="store_true",
                        help="the captures at the users' spacing (30-60 degrees apart)")
    parser.add_argument("--set", dest="settings", action="append", default=[],
                        metavar="KEY=VALUE", help="a MatchesConfig field (repeatable)")
    args = parser.parse_args(argv)
    print(run(False, args.captures, args.users, args.settings), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())

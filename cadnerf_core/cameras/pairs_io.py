"""What a job keeps of the photos' matches: the verified pairs as arrays (so a resumed job does
not match again) and a picture of each neighbouring pair's matches."""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from cadnerf_core.cameras.matches import PairMatch

if TYPE_CHECKING:
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.jobfolder import InputPhoto, JobFolder

log = logging.getLogger(__name__)

PICTURE_HEIGHT = 480
"""Height in pixels of each photo in a pair's picture."""
PICTURE_LINES = 150
"""Most matches drawn in a pair's picture (evenly chosen)."""
CHECKS = "object size, essential matrix, orbit"
"""The checks a stored pair passed (``matches.verify_matches``): part of the cache's key, so a
job rerun after they change matches again."""


def cache_key(photos: Sequence[tuple[str, int]], settings: dict[str, Any],
              focals: Sequence[float | None]) -> str:
    """A key of what the matches depend on: each photo's name and size in bytes, the matching
    settings and the focal lengths used."""
    text = json.dumps([list(photos), settings, list(focals)], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def to_arrays(pairs: Sequence[PairMatch], key: str) -> dict[str, np.ndarray]:
    """The pairs as named arrays (``np.savez``: no pickled objects)."""
    meta = [{"i": p.i, "j": p.j, "matched": p.matched, "inliers": p.inliers,
             "sampson_px": p.sampson_px, "turn_deg": p.turn_deg} for p in pairs]
    arrays = {"key": np.array(key), "meta": np.array(json.dumps(meta))}
    for k, p in enumerate(pairs):
        arrays[f"points_{k}"] = p.points
        if p.rotation is not None:
            arrays[f"rotation_{k}"] = np.asarray(p.rotation)
    return arrays


def from_arrays(arrays: dict[str, np.ndarray], key: str) -> list[PairMatch] | None:
    """The pairs ``to_arrays`` stored, None when they were stored under another key."""
    if "key" not in arrays or str(arrays["key"]) != key:
        return None
    pairs = []
    for k, m in enumerate(json.loads(str(arrays["meta"]))):
        rotation = arrays.get(f"rotation_{k}")
        pairs.append(PairMatch(int(m["i"]), int(m["j"]), int(m["matched"]), int(m["inliers"]),
                               m["sampson_px"], m["turn_deg"],
                               None if rotation is None else np.asarray(rotation),
                               np.asarray(arrays[f"points_{k}"], dtype=np.float64)))
    return pairs


def pair_picture(image_a: np.ndarray, image_b: np.ndarray, pair: PairMatch) -> np.ndarray:
    """The two photos side by side at ``PICTURE_HEIGHT`` with lines joining their verified
    matches (at most ``PICTURE_LINES``). Returns [H, W, 3] uint8 RGB."""
    sides = []
    scales = []
    for image in (image_a, image_b):
        rgb = np.asarray(image)[..., :3]
        if rgb.dtype != np.uint8:
            rgb = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        scale = PICTURE_HEIGHT / rgb.shape[0]
        width = max(1, round(rgb.shape[1] * scale))
        sides.append(cv2.resize(rgb, (width, PICTURE_HEIGHT), interpolation=cv2.INTER_AREA))
        scales.append(scale)
    canvas = np.ascontiguousarray(np.concatenate(sides, axis=1))
    offset = sides[0].shape[1]
    points = pair.points
    if len(points) > PICTURE_LINES:
        points = points[np.linspace(0, len(points) - 1, PICTURE_LINES).round().astype(int)]
    hues = np.linspace(0, 179, max(len(points), 1), endpoint=False).astype(np.uint8)
    colours = cv2.cvtColor(np.stack([hues, np.full_like(hues, 220), np.full_like(hues, 255)],
                                    axis=1)[None], cv2.COLOR_HSV2RGB)[0]
    for (a, b), colour in zip(points, colours, strict=False):
        start = (round(a[0] * scales[0]), round(a[1] * scales[0]))
        end = (round(b[0] * scales[1]) + offset, round(b[1] * scales[1]))
        cv2.line(canvas, start, end, tuple(int(c) for c in colour), 1, cv2.LINE_AA)
    label = (f"photos {pair.i + 1} and {pair.j + 1}: {pair.inliers} verified of "
             f"{pair.matched} matches")
    cv2.putText(canvas, label, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3,
                cv2.LINE_AA)
    cv2.putText(canvas, label, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1,
                cv2.LINE_AA)
    return canvas


def neighbour_pairs(pairs: Sequence[PairMatch], order: Sequence[int]) -> list[PairMatch]:
    """The pairs of photos next to each other in the walking ``order`` (round the loop)."""
    wanted = {tuple(sorted((order[k], order[(k + 1) % len(order)])))
              for k in range(len(order)) if len(order) > 1}
    return [p for p in pairs if (p.i, p.j) in wanted]


def job_pairs(folder: JobFolder, inputs: Sequence[InputPhoto], images: Sequence[np.ndarray],
              masks: Sequence[np.ndarray], focals: Sequence[float | None],
              config: RetrievalConfig, mask_method: str,
              check: Callable[[], None] | None = None) -> list[PairMatch] | None:
    """The photos' verified matches for a job: read from the job folder when stored for the
    same photos, settings and focal lengths, else matched (``retrieve.photo_pairs``), stored,
    and each neighbouring pair's picture written. None when the job does not match photos
    (``matches.enabled`` off, or the paper's solver)."""
    from cadnerf_core.retrieval.search import photo_pairs

    if not config.matches.enabled or config.solver != "dp":
        return None
    key = cache_key([(e.path.name, e.path.stat().st_size) for e in inputs],
                    {"matches": config.matches.model_dump(mode="json"), "masks": mask_method,
                     "checks": CHECKS},
                    focals)
    stored = folder.read_match_cache()
    pairs = None if stored is None else from_arrays(stored, key)
    if pairs is not None:
        log.info("matches: read %d pairs from the job folder", len(pairs))
        return pairs
    start = time.perf_counter()
    pairs = photo_pairs(images, masks, focals, config, check)
    log.info("matches: %d photos, %d pairs, %d with a rotation, in %.1f s", len(images),
             len(pairs), sum(p.rotation is not None for p in pairs),
             time.perf_counter() - start)
    folder.write_match_cache(to_arrays(pairs, key))
    for pair in neighbour_pairs(pairs, list(range(len(images)))):
        folder.write_match_picture(pair.i, pair.j,
                                   pair_picture(images[pair.i], images[pair.j], pair))
    return pairs

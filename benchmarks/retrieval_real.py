"""The retrieval benchmark's real photo sets: retrieved with their shipped and with GrabCut
masks, one picture each (``benchmarks.bench_retrieval``)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import PHOTOS, rotation_error
from benchmarks.lookalikes import excluded


def real_set_photos(name: str) -> tuple[list[Path], list[Path], np.ndarray | None]:
    """Photos in walking order, their shipped masks, and coarse ground truth c2w (or None)."""
    from cadnerf_core.cameras.conventions import orbit_pose

    folder = PHOTOS / name
    photos = sorted((folder / "images").iterdir())
    gt = None
    meta = folder / "metadata.json"
    if meta.is_file():
        data = json.loads(meta.read_text())
        order = sorted(range(len(photos)), key=lambda i: data["azimuths"][i])
        photos = [photos[i] for i in order]
        gt = np.stack([orbit_pose(data["azimuths"][i], data["elevations"][i], 4.0)
                       for i in order])
    masks = [folder / "masks" / f"{p.stem}.png" for p in photos]
    return photos, masks, gt


def _real_lines(name: str, label: str, result: Any, gt: np.ndarray | None) -> list[str]:
    """Markdown lines for one real-photo retrieval."""
    poses = ", ".join(f"{m.azimuth:.0f}/{m.elevation:.0f}{'*' if m.discarded else ''}"
                      for m in result.matches)
    error = "" if gt is None else (f"; median rotation error vs the coarse metadata poses "
                                   f"{rotation_error(result, gt):.1f} deg")
    tops = ", ".join(f"{t['model_id']} ({t['votes']})" for t in result.top_models[:3])
    return [f"- {name}, {label}: model **{result.model_id}** ({result.category}); top 3 by "
            f"votes: {tops}; direction {result.direction:+d}; azimuth/elevation per photo "
            f"(* = discarded): {poses}; silhouette set {result.perspective}; mean IoU "
            f"{np.mean([m.iou for m in result.matches]):.2f}{error}."]


def real_set(name: str, library: Any, picture: Path) -> list[str]:
    """Retrieve one real photo set with shipped and GrabCut masks; write its picture."""
    from cadnerf_cli.retrieve_cmd import match_rows
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.errors import InputError
    from cadnerf_core.intake.masks import photo_masks
    from cadnerf_core.intake.photos import Photo, load_photos
    from cadnerf_core.retrieval.search import retrieve

    paths, mask_paths, gt = real_set_photos(name)
    shipped = load_photos(paths, mask_paths)
    names = [p.name for p in shipped]
    masks = [p.mask for p in shipped if p.mask is not None]
    focals = [p.focal_pixels for p in shipped]  # EXIF, as a job passes them
    result = retrieve(masks, names, library, images=[p.rgb for p in shipped], focals=focals)
    lines = _real_lines(name, "shipped masks", result, gt)
    left_out = excluded(name)
    if left_out:  # the leave-out protocol (``benchmarks.lookalikes``)
        alone = retrieve(masks, names, library, RetrievalConfig(exclude_models=left_out),
                         images=[p.rgb for p in shipped], focals=focals)
        lines += _real_lines(name, f"shipped masks, leave-out ({', '.join(left_out)} "
                             "excluded)", alone, gt)
    rows = match_rows(shipped, masks, library, result)
    bare = [Photo(p.name, p.rgb) for p in shipped]
    start = time.perf_counter()
    try:
        found = [r.mask for r in photo_masks(bare, "grabcut")]
    except InputError as exc:
        lines.append(f"- {name}, GrabCut masks: background removal refused a photo: {exc}.")
        found = None
    seconds = (time.perf_counter() - start) / len(bare)
    if found is not None:
        ious = [float((a & b).sum() / (a | b).sum()) for a, b in zip(found, masks, strict=True)]
        grab = retrieve(found, names, library, images=[p.rgb for p in bare], focals=focals)
        lines += _real_lines(name, f"GrabCut masks (IoU with the shipped masks: mean "
                             f"{np.mean(ious):.2f}, min {min(ious):.2f}; {seconds:.2f} s a "
                             f"photo)", grab, gt)
        rows = [np.concatenate([a, b], axis=1) for a, b in
                zip(rows, match_rows(bare, found, library, grab), strict=True)]
    _save_picture(picture, rows)
    return lines


def _save_picture(path: Path, rows: list[np.ndarray]) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(rows, axis=0)).save(path)

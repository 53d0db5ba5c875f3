"""Real captures as datasets: a folder of photos, masks and ``cameras.json``.

``cameras.json`` holds ``frames``, each with ``image`` (a path relative to the folder), ``K``
([3, 3] in the saved image's pixels), ``c2w`` ([4, 4], OpenCV axes, in the capture's own world:
a calibration's or a COLMAP model's, any origin and scale) and optionally ``mask`` (white =
object; else ``masks/<stem>.png`` when present) and ``upside_down_by_design`` (a rig's frame
taken upside down: given upright here, as a phone's orientation tag gives a photo, its camera
rolled half a turn to match). A capture has no held-out split of its own: ``hold_out_views``
makes one from chosen frames.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cadnerf_core.errors import InputError
from cadnerf_core.evaluation.dataset import Dataset, read_frame

ROLL = np.diag([-1.0, -1.0, 1.0, 1.0])
"""Half a turn about a camera's optical axis (OpenCV axes)."""


def _frames(path: Path) -> list[dict[str, Any]]:
    """The frames of a ``cameras.json``; InputError when it is not one."""
    try:
        frames = json.loads(path.read_text())["frames"]
        for frame in frames:
            str(frame["image"])
            if np.asarray(frame["K"]).shape != (3, 3) or np.asarray(frame["c2w"]).shape != (4, 4):
                raise ValueError("K must be 3 x 3 and c2w 4 x 4")
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"not a capture's cameras file ({exc})", item=str(path)) from None
    if not frames:
        raise InputError("the cameras file has no frames", item=str(path))
    return list(frames)


def upright(rgb: np.ndarray, mask: np.ndarray, c2w: np.ndarray,
            K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A frame turned half a turn in its image plane, its camera rolled to match.

    Args:
        rgb: [H, W, 3]; mask: [H, W]; c2w: [4, 4]; K: [3, 3] (pixel edges at integers, so a
            point at u moves to W - u).
    Returns:
        The turned rgb, mask, c2w and K.
    """
    height, width = mask.shape
    turned = np.array(K, dtype=np.float64, copy=True)
    turned[0, 2], turned[1, 2] = width - K[0, 2], height - K[1, 2]
    return (np.ascontiguousarray(rgb[::-1, ::-1]), np.ascontiguousarray(mask[::-1, ::-1]),
            np.asarray(c2w, dtype=np.float64) @ ROLL, turned)


def load_capture(root: Path) -> Dataset:
    """A capture folder as a Dataset (no test split: see ``hold_out_views``).

    Args:
        root: the folder holding ``cameras.json``.
    Returns:
        Dataset of every frame in the file's order; ``masked`` when every frame has a mask.
    Raises:
        InputError: a broken cameras file, a missing image or mask, or frames of different
            sizes.
    """
    images, masks, c2ws, Ks, names, found = [], [], [], [], [], []
    for frame in _frames(root / "cameras.json"):
        mask_path = root / str(frame["mask"]) if frame.get("mask") else None
        rgb, mask, masked = read_frame(root / str(frame["image"]), mask_path)
        c2w = np.asarray(frame["c2w"], dtype=np.float64)
        K = np.asarray(frame["K"], dtype=np.float64)
        if frame.get("upside_down_by_design"):
            rgb, mask, c2w, K = upright(rgb, mask, c2w, K)
        images.append(rgb)
        masks.append(mask)
        c2ws.append(c2w)
        Ks.append(K)
        names.append(Path(str(frame["image"])).stem)
        found.append(masked)
    shapes = {image.shape for image in images}
    if len(shapes) != 1:
        raise InputError(f"frames have different sizes {sorted(shapes)}",
                         item=str(root / "cameras.json"))
    return Dataset(images=np.stack(images), masks=np.stack(masks), c2w=np.stack(c2ws),
                   K=np.stack(Ks), names=names, root=root, masked=all(found))


def hold_out_views(dataset: Dataset, indices: Sequence[int]) -> Dataset:
    """The dataset with frames ``indices`` moved from training to a new test split.

    Args:
        dataset: a dataset without a test split.
        indices: 0-based frame positions, in any order (the test split keeps the file's).
    Returns:
        Dataset of the other frames, in order, with ``test`` holding those frames.
    Raises:
        ValueError: a position that is not a frame, every frame held out, or a dataset with a
            test split of its own.
    """
    n = len(dataset.names)
    chosen = sorted(set(int(i) for i in indices))
    if dataset.test is not None:
        raise ValueError(f"{dataset.root} has a test split of its own: hold out no frames")
    if not chosen or chosen[0] < 0 or chosen[-1] >= n or len(chosen) == n:
        raise ValueError(f"cannot hold out frames {list(indices)} of {n} (0 to {n - 1}, "
                         "leaving at least one)")
    kept = [i for i in range(n) if i not in chosen]

    def pick(rows: list[int], test: Dataset | None) -> Dataset:
        return Dataset(images=dataset.images[rows], masks=dataset.masks[rows],
                       c2w=dataset.c2w[rows], K=dataset.K[rows],
                       names=[dataset.names[i] for i in rows], root=dataset.root, test=test,
                       masked=dataset.masked)

    return pick(kept, pick(chosen, None))


def with_found_masks(dataset: Dataset) -> Dataset:
    """A dataset without masks, masked as a job masks its photos (``intake.masks``: the
    learned background removal where it is installed, else GrabCut) and composited on white.

    Args:
        dataset: frames with whole-frame placeholder masks (``masked`` False).
    Returns:
        The same frames on white, their found masks; ``masked`` True.
    Raises:
        InputError: a mask covers too little or too much of its photo.
    """
    from dataclasses import replace

    from cadnerf_core.intake.masks import photo_masks
    from cadnerf_core.intake.photos import Photo

    found = photo_masks([Photo(name, rgb) for name, rgb in zip(dataset.names, dataset.images,
                                                               strict=True)])
    masks = np.stack([result.mask for result in found])
    images = np.where(masks[..., None], dataset.images, np.float32(1.0))
    return replace(dataset, images=images.astype(np.float32), masks=masks, masked=True)

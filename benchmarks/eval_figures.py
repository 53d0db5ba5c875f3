"""Pictures beside the evaluation tables, drawn with OpenCV (no plotting library needed).

- A strip per object: the input views, then ground truth and our render of held-out views.
- A top-down plot of the cameras (x right, z down the page = toward the viewer of the
  object's front): ground truth, retrieved and refined, all in the ground truth's frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

# BGR colours of the camera plot.
GT_COLOUR = (60, 160, 60)
RETRIEVED_COLOUR = (40, 40, 220)
REFINED_COLOUR = (220, 110, 30)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _tile(image: np.ndarray, size: int, label: str) -> np.ndarray:
    """RGB float [H, W, 3] -> BGR uint8 [size + 14, size, 3] with a caption strip on top."""
    rgb = np.clip(np.asarray(image, np.float32), 0.0, 1.0)
    tile = cv2.resize((rgb * 255).astype(np.uint8), (size, size), interpolation=cv2.INTER_AREA)
    caption = np.full((14, size, 3), 255, np.uint8)
    cv2.putText(caption, label, (2, 11), _FONT, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([caption, cv2.cvtColor(tile, cv2.COLOR_RGB2BGR)], 0)


def save_strip(path: Path, inputs: Sequence[np.ndarray],
               held_out: Sequence[tuple[np.ndarray, np.ndarray]], size: int = 96) -> Path:
    """Write one row: input views, then (ground truth, ours) per held-out view.

    Args:
        path: PNG to write (folders created).
        inputs: input views [H, W, 3] float in [0, 1].
        held_out: (ground truth, render) pairs, [H, W, 3] float in [0, 1].
        size: tile side in pixels.
    Returns:
        path.
    """
    tiles = [_tile(img, size, f"input {i}") for i, img in enumerate(inputs)]
    gap = np.full((size + 14, 6, 3), 255, np.uint8)
    for j, (gt, ours) in enumerate(held_out):
        tiles += [gap, _tile(gt, size, f"GT test {j}"), _tile(ours, size, f"ours test {j}")]
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate(tiles, 1))
    return path


def _to_pixels(points: np.ndarray, centre: np.ndarray, scale: float, size: int) -> np.ndarray:
    """World x, z -> pixel (column, row), z growing downward."""
    xz = (points[:, [0, 2]] - centre) * scale + size / 2.0
    return np.round(xz).astype(int)


def save_camera_plot(path: Path, gt: np.ndarray, retrieved: np.ndarray, refined: np.ndarray,
                     size: int = 320) -> Path:
    """Top-down plot of three camera sets (seen from +Y: x to the right, z downward).

    Args:
        path: PNG to write (folders created).
        gt, retrieved, refined: [N, 4, 4] c2w in the same (ground truth) frame.
        size: image side in pixels.
    Returns:
        path.
    """
    sets = [(gt, GT_COLOUR, "ground truth"), (retrieved, RETRIEVED_COLOUR, "retrieved"),
            (refined, REFINED_COLOUR, "refined")]
    centres = np.concatenate([c[:, :3, 3] for c, _, _ in sets if len(c)])
    span = float(np.abs(centres[:, [0, 2]]).max()) or 1.0
    scale = 0.42 * size / span
    canvas = np.full((size, size, 3), 255, np.uint8)
    origin = _to_pixels(np.zeros((1, 3)), np.zeros(2), scale, size)[0]
    cv2.drawMarker(canvas, (int(origin[0]), int(origin[1])), (0, 0, 0), cv2.MARKER_CROSS, 10, 1)
    arrow = 0.25 * span
    for c2w, colour, _ in sets:
        heads = c2w[:, :3, 3] + arrow * c2w[:, :3, 2]  # the camera looks along its +z axis
        for i, (p, q) in enumerate(zip(_to_pixels(c2w[:, :3, 3], np.zeros(2), scale, size),
                                       _to_pixels(heads, np.zeros(2), scale, size),
                                       strict=True)):
            cv2.arrowedLine(canvas, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), colour, 1,
                            cv2.LINE_AA, tipLength=0.25)
            # Retrieved cameras as rings, so refined ones drawn on top leave them visible.
            hollow = colour == RETRIEVED_COLOUR
            cv2.circle(canvas, (int(p[0]), int(p[1])), 6 if hollow else 3, colour,
                       1 if hollow else -1, cv2.LINE_AA)
            if colour == GT_COLOUR:
                cv2.putText(canvas, str(i), (int(p[0]) + 4, int(p[1]) - 4), _FONT, 0.35,
                            colour, 1, cv2.LINE_AA)
    for k, (_, colour, name) in enumerate(sets):
        cv2.putText(canvas, name, (6, 14 + 13 * k), _FONT, 0.4, colour, 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), canvas)
    return path

"""Contact sheet of a library: every model shaded from one three-quarter view, with its label."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
from cadnerf_core.library.format import Library
from cadnerf_core.mesh.renderer import MeshRenderer

PREVIEW_AZIMUTH = 35.0  # front-right three-quarter view
PREVIEW_ELEVATION = 25.0
PREVIEW_DISTANCE = 3.2
LABEL_HEIGHT = 22


def render_tile(library: Library, model_id: str, size: int) -> np.ndarray:
    """One labelled tile: the model shaded on white, id and category below.

    Returns:
        [size + LABEL_HEIGHT, size, 3] uint8 RGB.
    """
    renderer = MeshRenderer(library.mesh(model_id))
    K = intrinsics_from_fov(library.spec.fov_deg, size)
    c2w = orbit_pose(PREVIEW_AZIMUTH, PREVIEW_ELEVATION, PREVIEW_DISTANCE)
    rgb = renderer.render(K, c2w, size, size, background=1.0).rgb
    tile = np.full((size + LABEL_HEIGHT, size, 3), 255, dtype=np.uint8)
    tile[:size] = np.round(rgb * 255.0).astype(np.uint8)
    entry = library.models[library.index(model_id)]
    label = entry.id if entry.id == entry.category else f"{entry.id} ({entry.category})"
    scale = min(0.4, 0.4 * size / (8.0 * max(1, len(label))))
    cv2.putText(tile, label, (4, size + 15), cv2.FONT_HERSHEY_SIMPLEX, max(scale, 0.28),
                (20, 20, 20), 1, cv2.LINE_AA)
    return tile


def contact_sheet(library: Library, size: int = 160, columns: int | None = None) -> np.ndarray:
    """Grid of labelled tiles of every model, in library order.

    Args:
        library: the loaded library.
        size: tile side in pixels.
        columns: tiles per row (default: about square).
    Returns:
        [H, W, 3] uint8 RGB image.
    """
    count = len(library.models)
    columns = columns or math.ceil(math.sqrt(count * 1.3))
    rows = math.ceil(count / columns)
    tile_h = size + LABEL_HEIGHT
    sheet = np.full((rows * tile_h, columns * size, 3), 255, dtype=np.uint8)
    for i, entry in enumerate(library.models):
        r, c = divmod(i, columns)
        sheet[r * tile_h:(r + 1) * tile_h, c * size:(c + 1) * size] = render_tile(
            library, entry.id, size)
    # Thin grid lines between tiles.
    sheet[::tile_h, :] = 200
    sheet[:, ::size] = 200
    return sheet


def write_contact_sheet(library: Library, out: Path, size: int = 160) -> Path:
    """Render the contact sheet and write it as a PNG. Returns the path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet = contact_sheet(library, size)
    if not cv2.imwrite(str(out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {out}")
    return out

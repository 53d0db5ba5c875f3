"""The mesh's UV atlas: xatlas in a child process (``child``), a grid of triangles where it
fails.

xatlas takes seconds on a clean 20 000-triangle surface and over twenty on a noisy one, all
with the interpreter held, so it runs in a child; when the child fails or passes
``UNWRAP_LIMIT_S`` every triangle gets a cell of its own in the texture instead
(``grid_atlas``): a coarser texture, never a lost job.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from cadnerf_core.export.child import Arrays, run_child, serve

log = logging.getLogger(__name__)

UNWRAP_LIMIT_S = 120.0
"""Longest wait for xatlas before the triangles are laid out on a grid instead."""

Atlas = tuple[np.ndarray, np.ndarray, np.ndarray]
"""vmapping [V'] (the input vertex of each output vertex: seams split vertices), faces [F, 3]
into the output vertices, uv [V', 2] in [0, 1] with v up."""


def xatlas_atlas(vertices: np.ndarray, faces: np.ndarray, size: int, padding: int) -> Atlas:
    """xatlas's charts packed into a ``size`` x ``size`` texture, ``padding`` texels apart
    (in this process: the child's work)."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(np.asarray(vertices, np.float32), np.asarray(faces, np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = size
    pack.padding = padding
    pack.bilinear = True
    atlas.generate(pack_options=pack)
    vmapping, indices, uv = atlas[0]
    return vmapping.astype(np.int64), indices.astype(np.int64), uv.astype(np.float64)


def grid_atlas(faces: np.ndarray, size: int, padding: int) -> Atlas:
    """Every triangle in a square cell of its own, on a grid filling the texture: its corners
    at the cell's lower-left, lower-right and upper-left, ``padding`` texels inside.

    Every vertex is split per triangle (``vmapping`` is the faces' corners in order).
    """
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    n = len(faces)
    side = max(1, int(np.ceil(np.sqrt(n))))
    cell = size / side
    inset = min(float(padding), cell / 4.0)
    index = np.arange(n)
    x0, y0 = (index % side) * cell + inset, (index // side) * cell + inset
    x1, y1 = x0 + cell - 2.0 * inset, y0 + cell - 2.0 * inset
    corners = np.stack([np.stack([x0, y0], 1), np.stack([x1, y0], 1), np.stack([x0, y1], 1)], 1)
    uv = corners.reshape(-1, 2) / size
    return faces.reshape(-1), np.arange(3 * n, dtype=np.int64).reshape(n, 3), uv


def unwrap(vertices: np.ndarray, faces: np.ndarray, size: int, padding: int,
           check: Callable[[], None] | None = None,
           limit_s: float = UNWRAP_LIMIT_S) -> Atlas:
    """The mesh's atlas for a ``size`` x ``size`` texture: xatlas's, made in a child process,
    or ``grid_atlas`` when the child fails or runs past ``limit_s``.

    Args:
        vertices: [V, 3]; faces: [F, 3].
        check: called while waiting; whatever it raises (a cancel) ends the child and passes on.
    """
    if len(faces) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3), np.int64), np.zeros((0, 2))
    given = {"vertices": np.asarray(vertices, np.float32), "faces": np.asarray(faces, np.uint32),
             "size": size, "padding": padding}
    got = run_child(__name__, given, limit_s, f"xatlas ({len(faces)} triangles)", check)
    if got is None:
        log.warning("each triangle gets a cell of the texture instead of xatlas's charts")
        return grid_atlas(faces, size, padding)
    return got["vmapping"], got["faces"], got["uv"]


def _work(given: Arrays) -> dict[str, np.ndarray]:
    vmapping, faces, uv = xatlas_atlas(given["vertices"], given["faces"], int(given["size"]),
                                       int(given["padding"]))
    return {"vmapping": vmapping, "faces": faces, "uv": uv}


if __name__ == "__main__":
    serve(_work)

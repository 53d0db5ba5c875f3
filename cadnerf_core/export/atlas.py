"""The mesh's UV atlas: xatlas in a child process, a grid of triangles where it fails.

xatlas keeps the interpreter (its binding holds the GIL) for the whole unwrap: seconds on a
clean 20 000-triangle surface, over twenty on a noisy one with many small pieces, and for ever
on the meshes it hangs on. Inside the job's process that silences the worker's heartbeat (the
service then takes the job for orphaned) and a cancel waits for it. In a child process the job
only waits on a pipe: the heartbeat goes on, a cancel or delete ends the child at once, and
past ``UNWRAP_LIMIT_S`` (or when the child fails) every triangle gets a cell of its own in the
texture instead (``grid_atlas``): a coarser texture, never a lost job.

Run as ``python -m cadnerf_core.export.atlas``: reads the mesh as ``.npz`` (``vertices``,
``faces``, ``size``, ``padding``) on stdin, writes the atlas (``vmapping``, ``faces``, ``uv``)
as ``.npz`` on stdout.
"""

from __future__ import annotations

import io
import logging
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np

log = logging.getLogger(__name__)

UNWRAP_LIMIT_S = 120.0
"""Longest wait for xatlas before the triangles are laid out on a grid instead."""

POLL_S = 0.25
"""How often the wait asks whether the job was cancelled."""

Atlas = tuple[np.ndarray, np.ndarray, np.ndarray]
"""vmapping [V'] (the input vertex of each output vertex: seams split vertices), faces [F, 3]
into the output vertices, uv [V', 2] in [0, 1] with v up."""


def child_command() -> list[str]:
    """The command line of the child that runs xatlas (this module, by the same Python)."""
    return [sys.executable, "-m", __name__]


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
    sent = io.BytesIO()
    np.savez(sent, vertices=np.asarray(vertices, np.float32),
             faces=np.asarray(faces, np.uint32), size=size, padding=padding)
    child = subprocess.Popen(child_command(), stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + limit_s
    message: bytes | None = sent.getvalue()
    try:
        while True:
            try:
                out, err = child.communicate(message, timeout=POLL_S)
                break
            except subprocess.TimeoutExpired:
                message = None  # communicate sent it whole the first time
                if check is not None:
                    check()
                if time.monotonic() > deadline:
                    log.warning("xatlas did not unwrap the mesh (%d triangles) in %.0f s; "
                                "each triangle gets a cell of the texture", len(faces), limit_s)
                    return grid_atlas(faces, size, padding)
    finally:
        if child.poll() is None:
            child.kill()
            child.communicate()
    if child.returncode != 0:
        reason = err.decode(errors="replace").strip().splitlines()[-1:] or [
            f"exit status {child.returncode}"]
        log.warning("xatlas failed on the mesh (%d triangles): %s; each triangle gets a cell "
                    "of the texture", len(faces), reason[0])
        return grid_atlas(faces, size, padding)
    answer = np.load(io.BytesIO(out))
    return answer["vmapping"], answer["faces"], answer["uv"]


def _serve() -> None:
    """The child: the mesh on stdin, its xatlas atlas on stdout."""
    given = np.load(io.BytesIO(sys.stdin.buffer.read()))
    vmapping, faces, uv = xatlas_atlas(given["vertices"], given["faces"], int(given["size"]),
                                       int(given["padding"]))
    out = io.BytesIO()
    np.savez(out, vmapping=vmapping, faces=faces, uv=uv)
    sys.stdout.buffer.write(out.getvalue())
    sys.stdout.buffer.flush()


if __name__ == "__main__":
    _serve()

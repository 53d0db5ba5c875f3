"""Occupancy grids of watertight meshes, computed by ray parity, and training samples from them.

A point is inside a closed surface when a ray from it crosses the surface an odd number of
times (the rule the CAD-NeRF paper uses). The grid casts one ray per (x, y) column along +Z and
counts, for every cell centre of the column, the crossings below it: all cells of a 128^3 grid
from 128^2 rays. Rays are shifted by a tiny irrational offset so none passes exactly through a
mesh edge or vertex, where a hit would be counted twice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

# Ray offset in the (x, y) plane, far below a cell and unlikely to meet CAD coordinates exactly.
_RAY_JITTER = np.array([3.1622777e-7, 1.7320508e-7])


@dataclass(frozen=True)
class OccupancyGrid:
    """Boolean occupancy of cell centres over the cube [-1, 1]^3.

    Cell ``(i, j, k)`` (index order x, y, z) has its centre at ``-1 + (index + 0.5) * 2 / G``.
    """

    values: np.ndarray
    """[G, G, G] bool, True inside the object."""

    @property
    def size(self) -> int:
        """Cells per side, G."""
        return int(self.values.shape[0])

    @property
    def cell(self) -> float:
        """Side of one cell."""
        return 2.0 / self.size

    def centres(self) -> np.ndarray:
        """Cell-centre coordinates along one axis. Returns [G]."""
        return -1.0 + (np.arange(self.size) + 0.5) * self.cell

    def query(self, points: np.ndarray, interpolate: bool = True) -> np.ndarray:
        """Occupancy at arbitrary points; anything outside [-1, 1]^3 is empty.

        Args:
            points: [N, 3] coordinates.
            interpolate: trilinear interpolation of the cell values thresholded at 0.5 (smoother
                surface); False picks the nearest cell.
        Returns:
            occupied: [N] bool.
        """
        points = np.asarray(points, dtype=np.float64)
        inside_box = np.all(np.abs(points) <= 1.0, axis=1)
        u = (points + 1.0) / self.cell - 0.5  # continuous cell index
        g = self.size
        if not interpolate:
            idx = np.clip(np.rint(u).astype(np.int64), 0, g - 1)
            return self.values[idx[:, 0], idx[:, 1], idx[:, 2]] & inside_box
        base = np.clip(np.floor(u).astype(np.int64), 0, g - 2)
        frac = np.clip(u - base, 0.0, 1.0)
        total = np.zeros(len(points))
        for corner in np.ndindex(2, 2, 2):
            offset = np.array(corner)
            weight = np.prod(np.where(offset == 1, frac, 1.0 - frac), axis=1)
            idx = base + offset
            total += weight * self.values[idx[:, 0], idx[:, 1], idx[:, 2]]
        return (total > 0.5) & inside_box

    def surface_cells(self) -> np.ndarray:
        """Indices of occupied cells with an empty 6-neighbour (or on the grid's border).

        Returns:
            [K, 3] int64 cell indices.
        """
        occ = self.values
        padded = np.pad(occ, 1, constant_values=False)
        interior = occ.copy()
        for axis in range(3):
            for shift in (-1, 1):
                interior &= np.roll(padded, shift, axis=axis)[1:-1, 1:-1, 1:-1]
        return np.argwhere(occ & ~interior)

    def pack(self) -> dict[str, np.ndarray]:
        """Arrays for storage: ``bits`` (np.packbits of the flattened grid) and ``shape``."""
        return {"bits": np.packbits(self.values.reshape(-1)),
                "shape": np.asarray(self.values.shape, dtype=np.int64)}

    @classmethod
    def unpack(cls, arrays: dict[str, np.ndarray]) -> OccupancyGrid:
        """Inverse of ``pack``."""
        shape = tuple(int(s) for s in arrays["shape"])
        count = int(np.prod(shape))
        bits = np.unpackbits(np.asarray(arrays["bits"], dtype=np.uint8), count=count)
        return cls(bits.astype(bool).reshape(shape))


def _column_hits(triangles: np.ndarray, grid_size: int) -> tuple[np.ndarray, ...]:
    """Where the +Z rays through the (x, y) cell columns cross the triangles.

    Args:
        triangles: [F, 3, 3] vertex coordinates.
        grid_size: G.
    Returns:
        ix [H], iy [H] column indices, z [H] heights of the H crossings, and direction [H]:
        +1 where the ray enters the solid (outward normal toward -Z), -1 where it leaves.
    """
    cell = 2.0 / grid_size
    origin = -1.0 + 0.5 * cell + _RAY_JITTER  # [2] (x, y) of column (0, 0)
    xy = triangles[:, :, :2]
    lo = np.clip(np.ceil((xy.min(1) - origin) / cell), 0, grid_size).astype(np.int64)
    hi = np.clip(np.floor((xy.max(1) - origin) / cell), -1, grid_size - 1).astype(np.int64)
    counts = np.maximum(hi - lo + 1, 0)  # [F, 2] columns spanned along x and y
    per_tri = counts[:, 0] * counts[:, 1]
    tri = np.repeat(np.arange(len(triangles)), per_tri)
    local = np.arange(len(tri)) - np.repeat(np.cumsum(per_tri) - per_tri, per_tri)
    ix = lo[tri, 0] + local % np.maximum(counts[tri, 0], 1)
    iy = lo[tri, 1] + local // np.maximum(counts[tri, 0], 1)
    p = origin + np.stack([ix, iy], axis=1) * cell  # [P, 2] ray positions
    a, b, c = xy[tri, 0], xy[tri, 1], xy[tri, 2]

    def cross(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        return (v[:, 0] - u[:, 0]) * (w[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (w[:, 0] - u[:, 0])

    w_a, w_b, w_c = cross(b, c, p), cross(c, a, p), cross(a, b, p)
    hit = ((w_a > 0) & (w_b > 0) & (w_c > 0)) | ((w_a < 0) & (w_b < 0) & (w_c < 0))
    area = (w_a + w_b + w_c)[hit]
    z = triangles[tri[hit], :, 2]
    height = (w_a[hit] * z[:, 0] + w_b[hit] * z[:, 1] + w_c[hit] * z[:, 2]) / area
    # area is twice the signed projected area: positive when the normal points toward +Z.
    return ix[hit], iy[hit], height, np.where(area > 0, -1, 1).astype(np.int32)


def compute_occupancy(mesh: trimesh.Trimesh, grid_size: int = 128, rule: str = "parity",
                      chunk: int = 200_000) -> OccupancyGrid:
    """Occupancy grid of a closed mesh inside [-1, 1]^3.

    Args:
        mesh: closed triangle mesh (normalised: inside the unit sphere).
        grid_size: G, cells per side.
        rule: "parity" (inside = odd number of crossings, the paper's rule) or "winding"
            (inside = non-zero winding number: overlapping closed parts count as their union;
            needs consistently oriented faces).
        chunk: triangles processed at once (bounds memory on big meshes).
    Returns:
        OccupancyGrid with values [G, G, G].
    """
    if rule not in ("parity", "winding"):
        raise ValueError(f"rule must be 'parity' or 'winding', not {rule!r}")
    g = grid_size
    triangles = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    crossings = np.zeros((g, g, g + 1), dtype=np.int32)
    cell = 2.0 / g
    for start in range(0, len(triangles), chunk):
        ix, iy, z, direction = _column_hits(triangles[start:start + chunk], g)
        # A crossing at height z lies below every cell centre from index k upward.
        k = np.clip(np.ceil((z - (-1.0 + 0.5 * cell)) / cell), 0, g).astype(np.int64)
        np.add.at(crossings, (ix, iy, k), 1 if rule == "parity" else direction)
    below = np.cumsum(crossings[:, :, :g], axis=2)
    return OccupancyGrid((below % 2) == 1 if rule == "parity" else below != 0)


def sample_occupancy(grid: OccupancyGrid, n: int, near_surface: float = 0.5,
                     rng: np.random.Generator | None = None,
                     noise: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """Training points for the density network: near the surface and uniform in the box.

    Near-surface points are centres of surface cells, jittered within the cell, plus gaussian
    noise of ``noise`` cells; labels come from the grid itself (trilinear query), so they agree
    with what the network is asked to fit.

    Args:
        grid: the occupancy grid.
        n: number of points.
        near_surface: fraction of points drawn near the surface; the rest are uniform in
            [-1, 1]^3.
        rng: random generator (a fresh default one when None).
        noise: standard deviation of the near-surface offsets, in cells.
    Returns:
        points: [n, 3] float32; occupancy: [n] float32 in {0, 1}.
    """
    if not 0.0 <= near_surface <= 1.0:
        raise ValueError(f"near_surface must be in [0, 1], not {near_surface}")
    rng = np.random.default_rng() if rng is None else rng
    surface = grid.surface_cells()
    n_near = round(n * near_surface) if len(surface) else 0
    picks = surface[rng.integers(0, len(surface), n_near)] if n_near else np.zeros((0, 3))
    near = -1.0 + (picks + rng.uniform(0.0, 1.0, (n_near, 3))) * grid.cell
    near += rng.normal(0.0, noise * grid.cell, (n_near, 3))
    uniform = rng.uniform(-1.0, 1.0, (n - n_near, 3))
    points = np.clip(np.concatenate([near, uniform]), -1.0, 1.0)
    occupancy = grid.query(points).astype(np.float32)
    return points.astype(np.float32), occupancy

"""Occupancy grids by ray parity / winding number, and the phase-one sampler."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cadnerf_core.library.occupancy import OccupancyGrid, compute_occupancy, sample_occupancy


def _box() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(1.1, 0.7, 0.45))


def _sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=3, radius=0.8)


@pytest.mark.parametrize("make", [_box, _sphere], ids=["box", "sphere"])
def test_grid_agrees_with_contains(make) -> None:  # type: ignore[no-untyped-def]
    mesh = make()
    grid = compute_occupancy(mesh, 64)
    points = np.random.default_rng(0).uniform(-1, 1, (20_000, 3))
    expected = mesh.contains(points)
    assert (grid.query(points) == expected).mean() > 0.99
    assert (grid.query(points, interpolate=False) == expected).mean() > 0.985


def test_box_cells_are_exact_away_from_faces() -> None:
    grid = compute_occupancy(_box(), 32)
    c = grid.centres()
    x, y, z = np.meshgrid(c, c, c, indexing="ij")  # index order x, y, z
    inside = (np.abs(x) < 0.55) & (np.abs(y) < 0.35) & (np.abs(z) < 0.225)
    assert np.array_equal(grid.values, inside)
    assert grid.values.shape == (32, 32, 32) and grid.values.dtype == bool


def test_winding_rule_unites_overlapping_parts_where_parity_cancels() -> None:
    a = trimesh.creation.box(extents=(0.8, 0.8, 0.8))
    b = a.copy()
    b.apply_translation((0.4, 0.0, 0.0))
    both = trimesh.util.concatenate([a, b])
    assert isinstance(both, trimesh.Trimesh)
    overlap = np.array([[0.2, 0.0, 0.0]])
    assert not compute_occupancy(both, 32, "parity").query(overlap)[0]
    assert compute_occupancy(both, 32, "winding").query(overlap)[0]
    single = compute_occupancy(a, 32, "winding").values
    assert np.array_equal(single, compute_occupancy(a, 32, "parity").values)
    with pytest.raises(ValueError):
        compute_occupancy(a, 8, "majority")


def test_query_outside_the_box_is_empty_and_pack_round_trips() -> None:
    grid = OccupancyGrid(np.ones((8, 8, 8), dtype=bool))
    assert not grid.query(np.array([[1.01, 0.0, 0.0], [0.0, -2.0, 0.0]])).any()
    assert grid.query(np.array([[0.99, 0.99, -0.99]])).all()
    values = np.random.default_rng(1).random((9, 9, 9)) > 0.5  # odd size: padding bits
    assert np.array_equal(OccupancyGrid.unpack(OccupancyGrid(values).pack()).values, values)


def test_sampler_labels_and_mix() -> None:
    radius = 0.6
    grid = compute_occupancy(trimesh.creation.icosphere(subdivisions=3, radius=radius), 48)
    points, occ = sample_occupancy(grid, 4000, near_surface=0.5,
                                   rng=np.random.default_rng(0))
    assert points.shape == (4000, 3) and points.dtype == np.float32
    assert occ.shape == (4000,) and occ.dtype == np.float32
    assert set(np.unique(occ)) == {0.0, 1.0}
    assert np.array_equal(occ, grid.query(points).astype(np.float32))
    r = np.linalg.norm(points, axis=1)
    near, uniform = r[:2000], r[2000:]
    assert np.mean(np.abs(near - radius) < 6 * grid.cell) > 0.99
    assert np.mean(np.abs(uniform - radius) < 6 * grid.cell) < 0.5
    clear = np.abs(r - radius) > 2 * grid.cell  # labels right away from the surface
    assert np.array_equal(occ[clear] == 1.0, r[clear] < radius)
    with pytest.raises(ValueError):
        sample_occupancy(grid, 10, near_surface=1.5)

"""The mesh benchmark's scores (``benchmarks.bench_mesh``): distances where the cameras put a
surface and after ICP, the F-score, and its pieces."""

from __future__ import annotations

import numpy as np
import trimesh

from benchmarks.bench_mesh import pieces, surface_scores


def _box() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(1.2, 0.6, 0.9))


def test_a_surface_scored_against_itself_is_perfect() -> None:
    scores = surface_scores(_box(), _box(), samples=5000)
    assert scores["chamfer"] < 0.02 and scores["placed_chamfer"] < 0.02
    assert scores["f_score"] > 0.99 and scores["placed_f_score"] > 0.99


def test_a_scaled_and_shifted_copy_is_off_where_placed_but_right_in_shape() -> None:
    moved = _box().apply_scale(1.3).apply_translation([0.1, 0.05, 0.0])
    scores = surface_scores(moved, _box(), samples=5000)
    assert scores["placed_chamfer"] > 0.08
    assert scores["placed_f_score"] < 0.6
    assert scores["chamfer"] < 0.02 and scores["f_score"] > 0.97


def test_another_shape_stays_off_after_icp() -> None:
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.55)
    scores = surface_scores(ball, _box(), samples=5000)
    assert scores["chamfer"] > 0.04 and scores["f_score"] < 0.8


def test_pieces_are_counted_by_shared_vertices() -> None:
    two = trimesh.util.concatenate([_box(), _box().apply_translation([3.0, 0.0, 0.0])])
    assert pieces(_box()) == 1 and pieces(two) == 2
    assert np.isfinite(list(surface_scores(two, _box(), samples=2000).values())).all()

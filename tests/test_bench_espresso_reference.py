"""The espresso reference check (``benchmarks.bench_espresso_reference``): elevations from a
rectangle on the floor, and the reference's own score."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.bench_espresso_reference import (
    EDGES,
    PHOTOS,
    SET,
    floor_elevation,
    measure,
    reference_gap,
)
from cadnerf_core.cameras.conventions import look_at

K = np.array([[600.0, 0.0, 400.0], [0.0, 600.0, 300.0], [0.0, 0.0, 1.0]])


def _pixel(c2w: np.ndarray, point: np.ndarray) -> tuple[float, float]:
    camera = np.linalg.inv(c2w) @ np.append(point, 1.0)
    uvw = K @ camera[:3]
    return float(uvw[0] / uvw[2]), float(uvw[1] / uvw[2])


@pytest.mark.parametrize(("elevation", "turn"), [(8.0, 20.0), (30.0, 0.0), (55.0, 140.0)])
def test_a_rectangle_on_the_floor_gives_the_cameras_elevation(elevation: float,
                                                              turn: float) -> None:
    # World y up, the floor at y = 0, the object's middle 0.15 above a 0.6 x 0.4 mat turned by
    # `turn` about the vertical; the camera 1.5 away at `elevation`, looking at the middle.
    middle = np.array([0.0, 0.15, 0.0])
    el, az = np.radians(elevation), np.radians(35.0)
    eye = middle + 1.5 * np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
    c2w = look_at(eye, middle)
    t = np.radians(turn)
    axes = np.array([[np.cos(t), 0.0, np.sin(t)], [-np.sin(t), 0.0, np.cos(t)]])
    corners = [_pixel(c2w, sx * 0.3 * axes[0] + sy * 0.2 * axes[1])
               for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    edges = (((corners[0], corners[1]), (corners[3], corners[2])),
             ((corners[0], corners[3]), (corners[1], corners[2])))
    found, corner = floor_elevation(edges, K, _pixel(c2w, middle))
    assert found == pytest.approx(elevation, abs=0.01)
    assert corner == pytest.approx(90.0, abs=0.01)


def test_the_reference_gap_is_zero_for_the_same_cameras_and_grows_with_the_elevations() -> None:
    azimuths = [0.0, 60.0, 120.0, 200.0, 280.0]
    metadata = [30.0, 30.0, 0.0, 30.0, 0.0]
    assert reference_gap(azimuths, metadata, metadata) == pytest.approx(0.0, abs=1e-6)
    off = [35.0, 22.0, 12.0, 38.0, 9.0]
    assert 5.0 < reference_gap(azimuths, metadata, off) < 15.0


@pytest.mark.skipif(not (PHOTOS / SET / "metadata.json").is_file(),
                    reason="../shared/eval/photos is absent")
def test_the_clicked_mat_edges_make_a_rectangle_in_every_photo() -> None:
    result = measure()
    measured = [row for row in result["rows"] if "measured" in row]
    assert len(measured) == len(EDGES)
    assert all(abs(row["corner"] - 90.0) < 10.0 for row in measured)
    assert 0.0 < result["gap"] < 20.0

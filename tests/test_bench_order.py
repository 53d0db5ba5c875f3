"""The order benchmark's table of walks given in order through a phone's wider lens: it counts
the walks ``auto`` moved and names those it made worse than ``walk``."""

from __future__ import annotations

from benchmarks.bench_order import WIDE_FOVS, Walk, _wide_rows


def _walk(mesh: str, views: int, wide: dict[float, dict[str, float]]) -> Walk:
    return Walk(mesh, views, {"walk": 10.0, "auto": 10.0}, {}, {}, [], wide)


def test_wide_rows_name_the_walks_auto_made_worse() -> None:
    same = {fov: {"walk": 12.0, "auto": 12.0} for fov in WIDE_FOVS}
    worse = {fov: {"walk": 15.8, "auto": 41.7 if fov == 70.0 else 15.8} for fov in WIDE_FOVS}
    better = {fov: {"walk": 157.0, "auto": 116.5} for fov in WIDE_FOVS}
    rows = _wide_rows([_walk("fuze", 6, worse), _walk("plane", 6, same),
                       _walk("armchair", 6, better), _walk("fuze", 9, same)])
    by_key = {(r.split(" | ")[0].strip("| "), r.split(" | ")[1]): r for r in rows[2:]}
    assert set(by_key) == {(str(v), f"{f:g} deg") for v in (6, 9) for f in WIDE_FOVS}
    assert by_key[("6", "70 deg")].endswith("| 2 of 3 | 1 of 3 (fuze) |")
    assert by_key[("6", "55 deg")].endswith("| 1 of 3 | 0 of 3 |")  # better is not worse
    assert by_key[("9", "70 deg")].endswith("| 0 of 1 | 0 of 1 |")
    # medians over the three walks: walk of 15.8, 12, 157; auto of 41.7, 12, 116.5
    assert by_key[("6", "70 deg")] == "| 6 | 70 deg | 15.8 | 41.7 | 2 of 3 | 1 of 3 (fuze) |"
    assert by_key[("6", "55 deg")].startswith("| 6 | 55 deg | 15.8 | 15.8 |")


def test_alike_hits_counts_the_walks_neighbours_among_its_most_alike_pairs() -> None:
    import numpy as np

    from benchmarks.bench_order import alike_hits

    n = 6
    ring = np.zeros((n, n))
    for i in range(n):  # neighbours in the walk (the closing pair included) look alike
        ring[i, (i + 1) % n] = ring[(i + 1) % n, i] = 1.0
    assert alike_hits(ring) == n
    opposite = np.full((n, n), -1.0)
    for i in range(n):  # each photo looks like the one across the object and, less, like
        opposite[i, (i + 3) % n] = 1.0  # the one two steps on: no neighbour among those
        opposite[i, (i + 2) % n] = opposite[(i + 2) % n, i] = 0.5
    opposite[0, 1] = opposite[1, 0] = 0.75  # but one
    assert alike_hits(opposite) == 1

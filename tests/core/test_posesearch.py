"""Pose solvers against brute force of the objectives their docstrings define."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cadnerf_core.retrieval.posesearch import cyclic_dp, paper_algorithm1


def _walk_ok(bins: list[int], n_az: int, sign: int) -> bool:
    """The cyclic order constraint: total azimuth travelled one way round < a full turn."""
    return sum((sign * (b - a)) % n_az for a, b in itertools.pairwise(bins)) < n_az


def _spread(bins: list[int], n_az: int, sign: int, weight: float) -> float:
    """The gap-spread term: -weight * sum of squared gaps (steps and the closing gap)."""
    steps = [(sign * (b - a)) % n_az for a, b in itertools.pairwise(bins)]
    gaps = [*steps, n_az - sum(steps)]
    return -weight * sum((g / n_az) ** 2 for g in gaps)


def _dp_objective(iou: np.ndarray, views: tuple[int, ...], penalty: float,
                  az: np.ndarray | None = None, n_az: int = 1, sign: int = 1,
                  weight: float = 0.0) -> float:
    """Kept photos score their view's IoU, discarded ones their own best IoU - penalty, plus
    the spread term of the kept photos' walk."""
    value = float(sum(iou[p, v] if v >= 0 else iou[p].max() - penalty
                      for p, v in enumerate(views)))
    if weight and az is not None:
        value += _spread([int(az[v]) for v in views if v >= 0], n_az, sign, weight)
    return value


def _dp_brute(iou: np.ndarray, az: np.ndarray, n_az: int, penalty: float, max_discard: int,
              both: bool, backward_cost: float = 0.0,
              weight: float = 0.0) -> tuple[float, float]:
    """Optimum of the objective with the backward cost, and the objective without it there."""
    best, plain = -np.inf, -np.inf
    n_photos, n_views = iou.shape
    for views in itertools.product(range(-1, n_views), repeat=n_photos):
        if sum(v < 0 for v in views) > min(max_discard, n_photos - 1):
            continue
        bins = [int(az[v]) for v in views if v >= 0]
        for sign in (1, -1) if both else (1,):
            value = _dp_objective(iou, views, penalty, az, n_az, sign, weight)
            if _walk_ok(bins, n_az, sign) and value - backward_cost * (sign < 0) > best:
                best, plain = value - backward_cost * (sign < 0), value
    return best, plain


def _paper_brute(iou: np.ndarray, az: np.ndarray, top_k: int, max_skip: int) -> float:
    cands = np.argsort(-iou, axis=1, kind="stable")[:, :top_k]
    best = -np.inf
    for views in itertools.product(*[[-1, *c] for c in cands]):
        bins = [int(az[v]) for v in views if v >= 0]
        if sum(v < 0 for v in views) <= max_skip and bins == sorted(bins):
            best = max(best, sum(float(iou[p, v]) for p, v in enumerate(views) if v >= 0))
    return best


@st.composite
def tables(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, int]:
    """A random IoU table [P, V] (IoUs on a coarse grid, so ties happen) and view bins."""
    n_photos = draw(st.integers(1, 4))
    n_az = draw(st.integers(1, 5))
    n_el = draw(st.integers(1, 2))
    values = draw(st.lists(st.integers(0, 10), min_size=n_photos * n_az * n_el,
                           max_size=n_photos * n_az * n_el))
    iou = np.array(values, dtype=np.float64).reshape(n_photos, n_az * n_el) / 10.0
    return iou, np.repeat(np.arange(n_az), n_el), n_az


@settings(max_examples=200, deadline=None)
@given(tables(), st.sampled_from([0.0, 0.15, 0.5]), st.integers(0, 2), st.booleans(),
       st.sampled_from([0.0, 0.05]), st.sampled_from([0.0, 0.7, 3.0]))
def test_cyclic_dp_matches_brute_force(table: tuple[np.ndarray, np.ndarray, int],
                                       penalty: float, max_discard: int, both: bool,
                                       backward_cost: float, weight: float) -> None:
    iou, az, n_az = table
    found = cyclic_dp(iou, az, n_az, penalty, max_discard, both_directions=both,
                      backward_cost=backward_cost, spread_weight=weight)
    best, plain = _dp_brute(iou, az, n_az, penalty, max_discard, both, backward_cost, weight)
    charged = backward_cost * (found.direction < 0)
    assert np.isclose(found.score - charged, best)
    # The returned views reach that score and obey the constraints.
    assert np.isclose(_dp_objective(iou, tuple(found.views), penalty, az, n_az,
                                    found.direction, weight), found.score)
    if backward_cost == 0.0:
        assert np.isclose(found.score, plain)
    assert (found.views < 0).sum() <= max_discard
    assert _walk_ok([int(az[v]) for v in found.views if v >= 0], n_az, found.direction)
    assert both or found.direction == 1


@settings(max_examples=100, deadline=None)
@given(tables(), st.integers(1, 3), st.integers(0, 2))
def test_paper_algorithm_matches_brute_force(table: tuple[np.ndarray, np.ndarray, int],
                                             top_k: int, max_skip: int) -> None:
    iou, az, _ = table
    found = paper_algorithm1(iou, az, top_k=top_k, max_skip=max_skip)
    expected = _paper_brute(iou, az, top_k, max_skip)
    if expected == -np.inf:  # no ordered choice among the candidates: reported as such
        assert found.score == -np.inf and (found.views < 0).all()
        return
    assert np.isclose(found.score, expected)
    kept = [int(v) for v in found.views if v >= 0]
    assert (found.views < 0).sum() <= max_skip
    assert [az[v] for v in kept] == sorted(az[v] for v in kept)  # order follows the photos
    top = np.argsort(-iou, axis=1, kind="stable")[:, :top_k]
    assert all(v in top[p] for p, v in enumerate(found.views) if v >= 0)
    assert np.isclose(found.score, sum(iou[p, v] for p, v in enumerate(found.views) if v >= 0))


def _walk_table(bins: list[int], n_az: int, rng: np.random.Generator) -> np.ndarray:
    """Noisy IoU table [P, n_az] (one elevation) whose true views are ``bins``."""
    iou = rng.uniform(0.0, 0.3, (len(bins), n_az))
    iou[np.arange(len(bins)), bins] = 0.9
    return iou


def test_dp_follows_a_walk_that_wraps_around() -> None:
    bins, n_az = [17, 19, 1, 3, 6], 20
    iou = _walk_table(bins, n_az, np.random.default_rng(0))
    found = cyclic_dp(iou, np.arange(n_az), n_az)
    assert found.views.tolist() == bins and found.direction == 1
    # The paper's order cannot wrap: it must skip or misplace photos of this walk.
    paper = paper_algorithm1(iou, np.arange(n_az))
    assert paper.score < found.score


def test_dp_finds_a_decreasing_walk() -> None:
    bins, n_az = [12, 9, 6, 4, 1], 20
    iou = _walk_table(bins, n_az, np.random.default_rng(1))
    found = cyclic_dp(iou, np.arange(n_az), n_az)
    assert found.views.tolist() == bins and found.direction == -1
    one_way = cyclic_dp(iou, np.arange(n_az), n_az, both_directions=False)
    assert one_way.score < found.score
    # A backward cost larger than the gain makes the increasing walk win after all.
    gain = found.score - one_way.score
    # The lead over the best walk the other way is that gain; one direction has none.
    assert found.direction_lead == pytest.approx(gain) and gain > 0.1
    assert one_way.direction_lead is None
    assert cyclic_dp(iou, np.arange(n_az), n_az, backward_cost=gain + 0.01).direction == 1
    assert cyclic_dp(iou, np.arange(n_az), n_az, backward_cost=gain - 0.01).direction == -1


def test_dp_discards_an_outlier_only_when_worth_it() -> None:
    bins, n_az = [2, 5, 8, 11, 14], 20
    iou = _walk_table(bins, n_az, np.random.default_rng(2))
    iou[2] = 0.5
    iou[2, 1] = 0.95  # photo 2 looks like a view behind the walk: out of order
    # Keeping photo 2 in order costs 0.45 of IoU: more than a 0.3 discard, less than 0.6.
    found = cyclic_dp(iou, np.arange(n_az), n_az, discard_penalty=0.3)
    assert found.views.tolist() == [2, 5, -1, 11, 14]
    assert np.isclose(found.score, 0.9 * 4 + 0.95 - 0.3)
    kept = cyclic_dp(iou, np.arange(n_az), n_az, discard_penalty=0.6)
    assert (kept.views >= 0).all() and kept.views[[0, 1, 3, 4]].tolist() == [2, 5, 11, 14]


def test_dp_without_wrap_or_discards_equals_the_paper_search() -> None:
    # Same feasible set (every view, non-decreasing bins, all photos kept): same optimum.
    rng = np.random.default_rng(3)
    az = np.repeat(np.arange(6), 2)
    for _ in range(20):
        iou = rng.random((5, 12))
        paper = paper_algorithm1(iou, az, top_k=12, max_skip=0)
        dp = cyclic_dp(iou, az, 6, max_discard=0, both_directions=False, cyclic=False)
        assert np.isclose(paper.score, dp.score)
        assert (dp.views >= 0).all()


@settings(max_examples=100, deadline=None)
@given(tables(), st.integers(0, 2), st.booleans(), st.sampled_from([0.0, 1.5]))
def test_dp_without_wrap_matches_brute_force(table: tuple[np.ndarray, np.ndarray, int],
                                             max_discard: int, both: bool,
                                             weight: float) -> None:
    iou, az, n_az = table
    found = cyclic_dp(iou, az, n_az, 0.2, max_discard, both_directions=both, cyclic=False,
                      spread_weight=weight)
    best = -np.inf
    for views in itertools.product(range(-1, iou.shape[1]), repeat=iou.shape[0]):
        if sum(v < 0 for v in views) > min(max_discard, iou.shape[0] - 1):
            continue
        bins = [int(az[v]) for v in views if v >= 0]
        for sign in (1, -1) if both else (1,):
            if bins == sorted(bins, reverse=sign < 0):  # monotone, no wrap
                best = max(best, _dp_objective(iou, views, 0.2, az, n_az, sign, weight))
    assert np.isclose(found.score, best)
    kept = [int(az[v]) for v in found.views if v >= 0]
    assert kept == sorted(kept, reverse=found.direction < 0)


def test_spread_term_prefers_a_walk_round_the_object() -> None:
    # Photos match bin 5 as well as or better than their own views (a symmetric model's look).
    bins, n_az = [0, 4, 8, 12, 16], 20
    iou = np.full((5, n_az), 0.2)
    iou[np.arange(5), bins] = 0.8
    iou[[0, 2, 3, 4], 5] = 0.85
    iou[1, 5] = 0.8
    collapsed = cyclic_dp(iou, np.arange(n_az), n_az)
    assert collapsed.views.tolist() == [5] * 5
    assert np.isclose(collapsed.score, 4 * 0.85 + 0.8)
    spread = cyclic_dp(iou, np.arange(n_az), n_az, spread_weight=3.0)
    assert spread.views.tolist() == bins and spread.direction == 1
    # Evenly spread gaps of 4 bins cost 5 * (4 / 20) ** 2 of the weight; the collapsed walk
    # (one gap of 20 bins) would cost all of it.
    assert np.isclose(spread.score, 4.0 - 3.0 * 5 * 0.04)

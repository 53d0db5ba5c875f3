"""Photos in any order: the exact order search, the auto rule, and whole retrievals."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pytest

from cadnerf_core.config import RetrievalConfig
from cadnerf_core.job_warnings import reorder_warning
from cadnerf_core.retrieval.ordering import (
    any_order,
    choose_order,
    neighbour_similarity,
    runner_up,
    same_cycle,
    walk_score,
)
from cadnerf_core.retrieval.search import retrieve
from tests.core.test_retrieval import _walk


def _random_tables(seed: int, n_photos: int,
                   n_az: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random IoU [P, 3 * n_az] (three elevations a bin), the views' azimuth bins and a
    symmetric likeness [P, P]."""
    rng = np.random.default_rng(seed)
    iou = rng.random((n_photos, n_az * 3))
    similarity = rng.random((n_photos, n_photos))
    return iou, np.repeat(np.arange(n_az), 3), (similarity + similarity.T) / 2


@pytest.mark.parametrize("n_photos", [3, 4, 5, 6])
def test_the_order_search_is_the_best_walk_over_every_order(n_photos: int) -> None:
    """Against brute force: every order of the photos walked by the ordinary walk solver."""
    n_az = 12
    iou, az, similarity = _random_tables(n_photos, n_photos, n_az)
    found = any_order(iou, az, n_az, 10.0, similarity, 0.3)
    brute = max(walk_score(iou, az, n_az, [0, *rest], 10.0, similarity, 0.3)
                for rest in itertools.permutations(range(1, n_photos)))
    assert found.score == pytest.approx(brute, abs=1e-4)
    assert sorted(found.order) == list(range(n_photos)) and found.order[0] == 0
    assert walk_score(iou, az, n_az, found.order, 10.0, similarity, 0.3) == pytest.approx(
        found.score, abs=1e-4)
    # Along the walk, the photos' azimuth bins never turn back (one way round, from photo 0).
    relative = (az[found.views[found.order]] - az[found.views[0]]) % n_az
    assert (np.diff(relative) >= 0).all()


@pytest.mark.parametrize("n_photos", [4, 5, 6])
def test_the_runner_up_is_the_best_walk_of_another_cycle(n_photos: int) -> None:
    """Against brute force: the best walk score over every order whose cycle differs from the
    found walk's; three photos make one cycle and have none."""
    n_az = 12
    iou, az, similarity = _random_tables(10 + n_photos, n_photos, n_az)
    found = any_order(iou, az, n_az, 10.0, similarity, 0.3)
    others = [walk_score(iou, az, n_az, [0, *rest], 10.0, similarity, 0.3)
              for rest in itertools.permutations(range(1, n_photos))
              if not same_cycle([0, *rest], found.order)]
    second = runner_up(iou, az, n_az, 10.0, found.order, similarity, 0.3)
    assert second == pytest.approx(max(others), abs=1e-4)
    assert second <= found.score + 1e-4
    assert runner_up(iou[:3], az, n_az, 10.0, [0, 1, 2]) == float("-inf")


def test_same_cycle_reads_a_walk_either_way_from_any_start() -> None:
    assert same_cycle([0, 1, 2, 3, 4], [2, 3, 4, 0, 1])
    assert same_cycle([0, 1, 2, 3, 4], [3, 2, 1, 0, 4])
    assert not same_cycle([0, 1, 2, 3, 4], [0, 2, 1, 3, 4])
    assert not same_cycle([0, 1, 2], [0, 1, 3])
    assert same_cycle([0, 2, 1], [0, 1, 2])  # three photos: one cycle either way


def _clear_walk(order: list[int], n_az: int = 36) -> tuple[np.ndarray, np.ndarray]:
    """An IoU table where photo ``order[k]`` matches azimuth bin ``k * n_az / P`` best (one
    elevation), with a weaker mirrored match as silhouettes have: (iou [P, V], az [V])."""
    n = len(order)
    iou = np.full((n, n_az), 0.2)
    for k, p in enumerate(order):
        a = k * n_az // n
        iou[p, a] = 0.95
        iou[p, (n_az // 2 - a) % n_az] = 0.85
    return iou, np.arange(n_az)


def test_any_finds_a_shuffled_walk_and_auto_keeps_a_walk_given_in_order() -> None:
    walk = [3, 0, 5, 1, 4, 2]  # the photos, as they were taken
    iou, az = _clear_walk(walk)
    table = iou[:, None, :]
    found = choose_order(table, [0], az, 36, "any", 0.08, 10.0)
    assert same_cycle(found.order, walk) and found.reordered
    assert choose_order(table, [0], az, 36, "auto", 0.08, 10.0).reordered
    in_order = iou[walk][:, None, :]  # the same photos given in walking order
    kept = choose_order(in_order, [0], az, 36, "auto", 0.08, 10.0)
    assert kept.order == list(range(6)) and not kept.reordered
    # A margin above what the shuffled order loses keeps it as given.
    loss = (found.found_score - found.given_score) / 6
    assert not choose_order(table, [0], az, 36, "auto", loss + 0.01, 10.0).reordered
    # The order found leads every other order clearly; kept as given, none was needed.
    assert found.lead is not None and found.lead > 0.1  # one photo at its mirror bin: -0.2
    assert kept.lead is None


def test_an_order_the_silhouettes_cannot_tell_has_no_lead() -> None:
    """Each photo matches its own bin and the mirrored one equally well (a symmetric object
    without texture): another order fits as well as the one found."""
    walk = [3, 0, 5, 1, 4, 2]
    iou, az = _clear_walk(walk)
    iou = np.maximum(iou, iou[:, (36 // 2 - np.arange(36)) % 36])  # the mirror bin as good
    choice = choose_order(iou[:, None, :], [0], az, 36, "any", 0.08, 10.0)
    assert choice.lead is not None and choice.lead < 0.003 * 6


def test_neighbour_similarity_is_standardised_and_silent_without_a_cue() -> None:
    rng = np.random.default_rng(0)
    masks = [np.zeros((32, 32), bool) for _ in range(4)]
    for i, mask in enumerate(masks):
        mask[4:28, 4 + i * 2:12 + i * 4] = True  # outlines that grow apart
    grey = [np.full((32, 32, 3), 0.5) for _ in range(4)]
    sim = neighbour_similarity(grey, masks)
    assert sim.shape == (4, 4) and np.allclose(sim, sim.T)
    off = sim[~np.eye(4, dtype=bool)]
    assert abs(off.mean()) < 1e-9 and sim[0, 1] > sim[0, 3]  # outlines alike: neighbours
    same = neighbour_similarity(grey, [masks[0]] * 4)  # every photo alike: no cue at all
    assert np.allclose(same, 0.0)
    colours = [np.clip(rng.random((32, 32, 3)) * 0.1 + c, 0, 1) for c in (0.0, 0.05, 0.6, 0.65)]
    by_colour = neighbour_similarity(colours, [masks[0]] * 4)
    assert by_colour[0, 1] > by_colour[0, 2] and by_colour[2, 3] > by_colour[1, 2]


def test_a_shuffled_walk_is_retrieved_in_any_order(tiny_library: Any) -> None:
    """The chair walked round in four steps, given shuffled: the poses are those of the walk
    in order, each reported for its photo as given, with the walking order found."""
    views, masks = _walk(tiny_library, "chair", (1, 3, 5, 7))
    shuffle = [2, 0, 3, 1]
    names = ["a", "b", "c", "d"]
    given = [masks[i] for i in shuffle]
    result = retrieve(given, names, tiny_library, RetrievalConfig(order="any"))
    assert [m.index for m in result.matches] == [0, 1, 2, 3]
    assert [m.name for m in result.matches] == names
    assert [m.view for m in result.matches] == [views[i] for i in shuffle]
    assert same_cycle([shuffle[i] for i in result.order], [0, 1, 2, 3]) and result.reordered
    data = result.to_json()
    assert data["order"] == result.order and data["order_mode"] == "any" and data["reordered"]
    assert data["order_lead"] == result.order_lead and result.order_lead is not None
    assert data["order_ambiguous"] == (result.order_lead < 0.003 * 4)
    walked = retrieve(masks, names, tiny_library, RetrievalConfig(order="walk"))
    assert walked.to_json()["order"] == [0, 1, 2, 3] and not walked.reordered
    auto = retrieve(masks, names, tiny_library, RetrievalConfig())  # "auto", given in order
    assert [m.view for m in auto.matches] == [m.view for m in walked.matches]
    assert not auto.reordered and auto.order == [0, 1, 2, 3]


def test_the_reorder_warning_names_the_order_and_the_way_back() -> None:
    text = reorder_warning(["c.jpg", "a.jpg", "b.jpg"])
    assert "c.jpg, a.jpg, b.jpg" in text and '"walk"' in text


def test_matched_pairs_follow_the_photos_into_the_walking_order() -> None:
    from cadnerf_core.cameras.matches import PairMatch, inlier_table, reindexed

    rotation = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    points = np.arange(8, dtype=float).reshape(2, 2, 2)
    pairs = [PairMatch(0, 1, 40, 30, 0.5, 25.0, rotation, points),
             PairMatch(0, 2, 10, 0, None, None, None, np.zeros((0, 2, 2)))]
    moved = reindexed(pairs, [2, 0, 1])  # photo 0 walks last, 1 first, 2 second
    swapped = moved[0]  # (0, 1) became (2, 0): stored as (0, 2), turned round
    assert (swapped.i, swapped.j, swapped.turn_deg) == (0, 2, -25.0)
    assert np.allclose(swapped.rotation, rotation.T)
    assert np.array_equal(swapped.points[:, 0], points[:, 1])
    assert (moved[1].i, moved[1].j, moved[1].turn_deg) == (1, 2, None)
    table = inlier_table(moved, 3)
    assert table[0, 2] == table[2, 0] == 30 and table.trace() == 0

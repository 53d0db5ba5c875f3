"""Retrieved cameras fused with the rotations the photos' matches measured (``retrieval.fusion``):
exact pairs bring noisy cameras near the truth, a wrong pair is dropped, and too few pairs
change nothing."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from cadnerf_core.cameras.conventions import orbit_pose, project, rotation_angle_deg, scale_focal
from cadnerf_core.cameras.fusion import (
    SET_ASIDE,
    anchor,
    average_rotations,
    focal_factor,
    fuse,
    fuse_hypotheses,
    pairs_at_focal,
)
from cadnerf_core.cameras.matches import PairMatch
from cadnerf_core.cameras.prior import MIN_TURN_DEG, PRIOR_DEG, plausible, plausible_at, vouched
from cadnerf_core.cameras.viewgraph import consistent_edges
from cadnerf_core.intake.crop import CropBox
from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult

N = 8


def _truth() -> np.ndarray:
    return np.stack([orbit_pose(45.0 * k, 20.0 + 5.0 * (k % 2), 4.0) for k in range(N)])


def _noisy(c2w: np.ndarray, degrees: float, seed: int = 0) -> np.ndarray:
    """Each camera turned about a random axis through its centre by ``degrees``."""
    rng = np.random.default_rng(seed)
    out = c2w.copy()
    for pose in out:
        axis = rng.normal(size=3)
        turn = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(degrees))[0]
        pose[:3, :3] = pose[:3, :3] @ turn
    return out


def _relative(c2w: np.ndarray, i: int, j: int) -> np.ndarray:
    """Camera i's axes to camera j's: ``x_j = R x_i + t``."""
    return c2w[j, :3, :3].T @ c2w[i, :3, :3]


def _pair(c2w: np.ndarray, i: int, j: int, inliers: int = 200,
          rotation: np.ndarray | None = None) -> PairMatch:
    R = _relative(c2w, i, j) if rotation is None else rotation
    return PairMatch(i, j, inliers, inliers, 0.3, 0.0, R, np.zeros((0, 2, 2)))


def _retrieval(c2w: np.ndarray, pairs: list[PairMatch]) -> RetrievalResult:
    K = np.array([[100.0, 0, 64], [0, 100.0, 64], [0, 0, 1]])
    matches = [PhotoMatch(k, f"p{k}", k, 0.0, 0.0, 0.9, False, pose, K, CropBox(0, 0, 128, 128),
                          K) for k, pose in enumerate(c2w)]
    return RetrievalResult("m", "c", [], matches, "dp", 1, 1.0, pairs=pairs)


def _errors(c2w: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return rotation_angle_deg(np.swapaxes(c2w[:, :3, :3], 1, 2) @ truth[:, :3, :3])


def _walk_pairs(truth: np.ndarray) -> list[PairMatch]:
    return [_pair(truth, i, j) for i in range(N) for j in (i + 1, i + 2) if j < N]


def test_exact_pairs_bring_noisy_cameras_near_the_truth() -> None:
    truth = _truth()
    retrieved = _noisy(truth, 20.0)
    fused, summary = fuse(_retrieval(retrieved, []), _walk_pairs(truth), 20)
    assert summary is not None and summary.photos == list(range(N))
    poses = np.stack([m.c2w for m in fused.matches])
    before, after = _errors(retrieved, truth), _errors(poses, truth)
    assert np.median(before) == pytest.approx(20.0)
    assert np.median(after) < 0.5 * np.median(before)  # the noise averages out
    # The set moved as one: every relative rotation is the measured one.
    for i in range(N - 1):
        assert rotation_angle_deg((_relative(poses, i, i + 1).T
                                   @ _relative(truth, i, i + 1))[None])[0] < 0.1
    assert summary.residual_deg < 0.1
    # Each fused camera keeps its distance and looks at the object's centre.
    for pose, old in zip(poses, retrieved, strict=True):
        assert np.linalg.norm(pose[:3, 3]) == pytest.approx(np.linalg.norm(old[:3, 3]))
        assert np.allclose(-pose[:3, 3] / np.linalg.norm(pose[:3, 3]), pose[:3, 2])
    assert all(m.c2w_retrieved is not None for m in fused.matches)
    assert "c2w_retrieved" in fused.to_json()["matches"][0]
    assert fused.to_json()["fusion"]["photos"] == list(range(N))


def _wrong(truth: np.ndarray, i: int, j: int) -> PairMatch:
    """The pair's rotation turned 40 degrees off (a set of consistent wrong matches)."""
    turn = cv2.Rodrigues(np.array([0.0, np.radians(40.0), 0.0]))[0]
    return _pair(truth, i, j, rotation=turn @ _relative(truth, i, j))


def test_a_pair_its_triangles_contradict_is_dropped() -> None:
    truth = _truth()
    pairs = [_pair(truth, i, j) if (i, j) != (1, 3) else _wrong(truth, 1, 3)
             for i in range(5) for j in range(i + 1, 5)]
    edges = {(p.i, p.j): np.asarray(p.rotation) for p in pairs}
    assert consistent_edges(edges) == set(edges) - {(1, 3)}


def test_a_wrong_pair_in_a_walk_does_not_bend_the_fused_cameras() -> None:
    truth = _truth()
    pairs = [p if (p.i, p.j) != (2, 3) else _wrong(truth, 2, 3) for p in _walk_pairs(truth)]
    fused, summary = fuse(_retrieval(_noisy(truth, 10.0), []), pairs, 20)
    assert summary is not None
    poses = np.stack([m.c2w for m in fused.matches])
    for i, j in ((2, 3), (1, 2), (3, 4)):
        assert rotation_angle_deg((_relative(poses, i, j).T
                                   @ _relative(truth, i, j))[None])[0] < 1.0


def _still(truth: np.ndarray, i: int, j: int) -> PairMatch:
    """The pair's rotation a turn of 3 degrees, as features that travel with the camera give
    two photos 90 degrees apart (next-but-one in the walk)."""
    return _pair(truth, i, j, rotation=cv2.Rodrigues(np.array([0.0, np.radians(3.0), 0.0]))[0])


def test_pairs_far_from_the_retrieved_cameras_are_not_plausible() -> None:
    truth = _truth()
    retrieval = _retrieval(_noisy(truth, 20.0), [])
    right, still = _pair(truth, 0, 1), _still(truth, 1, 3)
    unknown = dataclasses.replace(_pair(truth, 2, 3), rotation=None)
    assert plausible(retrieval, [right, still, unknown]) == [right, unknown]
    # The prior is the retrieved cameras, not those fused since.
    moved = dataclasses.replace(retrieval, matches=[
        dataclasses.replace(m, c2w=truth[0], c2w_retrieved=m.c2w) for m in retrieval.matches])
    assert plausible(moved, [right]) == [right]


def test_implausible_pairs_are_left_out_of_the_fusion() -> None:
    truth = _truth()
    retrieved = _noisy(truth, 15.0)
    pairs = [p if (p.i, p.j) not in ((0, 2), (3, 5)) else _still(truth, p.i, p.j)
             for p in _walk_pairs(truth)]
    fused, summary = fuse(_retrieval(retrieved, []), pairs, 20)
    assert summary is not None and summary.implausible == 2
    assert summary.to_json()["implausible"] == 2
    poses = np.stack([m.c2w for m in fused.matches])
    assert np.median(_errors(poses, truth)) < 0.5 * np.median(_errors(retrieved, truth))


def test_the_anchor_ignores_one_camera_retrieval_got_wrong() -> None:
    truth = _truth()
    world_to_camera = np.swapaxes(truth[:, :3, :3], 1, 2)
    retrieved = world_to_camera.copy()
    retrieved[3] = cv2.Rodrigues(np.array([np.pi * 0.9, 0.0, 0.0]))[0] @ retrieved[3]
    G = anchor(world_to_camera, retrieved)
    assert rotation_angle_deg(G[None])[0] < 2.0


def test_averaging_recovers_rotations_from_a_rotated_start() -> None:
    truth = _truth()
    W = np.swapaxes(truth[:, :3, :3], 1, 2)
    edges = {(p.i, p.j): np.asarray(p.rotation) for p in _walk_pairs(truth)}
    solved = average_rotations(N, edges, {e: 1.0 for e in edges},
                               np.swapaxes(_noisy(truth, 30.0, seed=2)[:, :3, :3], 1, 2))
    G = anchor(solved, W)
    assert rotation_angle_deg(np.swapaxes(solved @ G, 1, 2) @ W).max() < 0.1


def test_too_few_connected_photos_change_nothing() -> None:
    truth = _truth()
    retrieval = _retrieval(_noisy(truth, 15.0), [])
    same, summary = fuse(retrieval, [_pair(truth, 0, 1), _pair(truth, 4, 5, inliers=5)], 20)
    assert summary is None
    assert all(np.array_equal(a.c2w, b.c2w) for a, b in zip(same.matches, retrieval.matches,
                                                            strict=True))
    assert same.to_json()["fusion"]["photos"] == []  # the job warns: silhouettes alone


def test_discarded_photos_keep_their_cameras_and_alternatives_are_fused() -> None:
    truth = _truth()
    retrieved = _noisy(truth, 20.0)
    retrieval = _retrieval(retrieved, _walk_pairs(truth))
    retrieval.matches[5].discarded = True
    retrieval = retrieval.__class__(**{**retrieval.__dict__,
                                       "alternatives": [_retrieval(_noisy(truth, 25.0, 1),
                                                                   [])]})
    fused = fuse_hypotheses(retrieval, 20)
    assert np.array_equal(fused.matches[5].c2w, retrieved[5])
    assert fused.matches[5].c2w_retrieved is None
    assert fused.fusion is not None and 5 not in fused.fusion["photos"]
    assert fused.alternatives[0].fusion is not None
    # The retrieval as it was stays a hypothesis, for the start's fit to weigh ...
    assert len(fused.alternatives) == 2 and fused.alternatives[1].fusion == SET_ASIDE
    assert np.array_equal(fused.alternatives[1].matches[0].c2w, retrieved[0])
    # ... where the job weighs hypotheses at all.
    alone = fuse_hypotheses(dataclasses.replace(retrieval, alternatives=[]), 20)
    assert alone.fusion is not None and alone.fusion["photos"] and alone.alternatives == []


def _projected_pairs(truth: np.ndarray, K: np.ndarray) -> list[PairMatch]:
    """Pairs whose inliers are points on a ball projected by the true cameras (``K``), their
    rotations left as the matcher would give them (any: they are refitted)."""
    rng = np.random.default_rng(5)
    ball = rng.normal(size=(400, 3))
    ball = 0.8 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    pairs = []
    for i in range(N):
        for j in (i + 1, i + 2):
            if j >= N:
                continue
            seen = [(ball - truth[k, :3, 3]) @ truth[k, :3, 2] for k in (i, j)]
            facing = [(ball @ (truth[k, :3, 3] / np.linalg.norm(truth[k, :3, 3]))) > 0.2
                      for k in (i, j)]
            keep = facing[0] & facing[1] & (seen[0] > 0) & (seen[1] > 0)
            points = np.stack([project(ball[keep], K, truth[k]) for k in (i, j)], axis=1)
            pairs.append(PairMatch(i, j, len(points), len(points), 0.1, 0.0,
                                   _relative(truth, i, j), points))
    return pairs


def test_an_unknown_focal_length_is_the_one_that_fuses_nearest_the_retrieved_cameras() -> None:
    truth = _truth()
    K_true = np.array([[420.0, 0.0, 128.0], [0.0, 420.0, 128.0], [0.0, 0.0, 1.0]])
    retrieval = _retrieval(_noisy(truth, 5.0), [])
    K_guess = scale_focal(K_true, 0.6)  # silhouettes told a wider field of view
    retrieval = dataclasses.replace(retrieval, matches=[
        dataclasses.replace(m, K_photo=K_guess, K_canon=K_guess) for m in retrieval.matches])
    pairs = _projected_pairs(truth, K_true)
    factor, at_best, at_one = focal_factor(retrieval, pairs, 20)
    assert factor == pytest.approx(1.0 / 0.6, rel=0.1)
    assert at_best < at_one
    fused, summary = fuse(retrieval, pairs, 20, search_focal=True)
    assert summary is not None and summary.focal_factor == factor
    assert fused.matches[0].K_photo[0, 0] == pytest.approx(0.6 * 420.0 * factor)
    assert fused.matches[0].K_photo[0, 2] == 128.0  # the principal point stays
    poses = np.stack([m.c2w for m in fused.matches])
    assert np.median(_errors(poses, truth)) < 4.0


def test_pairs_measured_at_a_guessed_focal_length_are_measured_again_at_the_found_one() -> None:
    truth = _truth()
    K_true = np.array([[420.0, 0.0, 128.0], [0.0, 420.0, 128.0], [0.0, 0.0, 1.0]])
    guessed = [dataclasses.replace(p, rotation=np.eye(3)) for p in _projected_pairs(truth, K_true)]
    retrieval = _retrieval(truth, guessed)
    retrieval = dataclasses.replace(retrieval, matches=[
        dataclasses.replace(m, K_photo=K_true) for m in retrieval.matches],
        alternatives=[_retrieval(truth, guessed)])
    again = pairs_at_focal(retrieval)
    for p in again.pairs:
        assert rotation_angle_deg((np.asarray(p.rotation).T
                                   @ _relative(truth, p.i, p.j))[None])[0] < 0.5
    assert again.alternatives[0].pairs == again.pairs


def test_pairs_the_averaged_cameras_cannot_explain_are_left_out() -> None:
    truth = _truth()
    rng = np.random.default_rng(4)
    pairs = []
    for p in _walk_pairs(truth):
        if (p.i + p.j) % 3 == 0:  # a third of the pairs: a random wrong rotation
            turn = cv2.Rodrigues(rng.normal(size=3))[0]
            p = dataclasses.replace(p, rotation=turn @ np.asarray(p.rotation))
        pairs.append(p)
    fused, summary = fuse(_retrieval(_noisy(truth, 10.0), []), pairs, 20)
    assert summary is not None and summary.residual_deg < 1.0
    assert summary.pairs + summary.dropped + summary.implausible == len(pairs)
    poses = np.stack([m.c2w for m in fused.matches])
    kept = summary.photos
    for i, j in zip(kept[:-1], kept[1:], strict=True):
        assert rotation_angle_deg((_relative(poses, i, j).T @ _relative(truth, i, j))[None])[
            0] < 1.0


def test_each_connected_set_of_photos_is_fused_on_its_own() -> None:
    """Photos 0-3 and 5-7 are held together by their pairs, nothing joins the two sets: each
    is fused, anchored by its own retrieved cameras; photo 4 keeps its retrieved camera."""
    truth = _truth()
    retrieved = _noisy(truth, 15.0, seed=3)
    pairs = [_pair(truth, i, j) for i, j in ((0, 1), (1, 2), (0, 2), (2, 3), (1, 3),
                                             (5, 6), (6, 7), (5, 7))]
    fused, summary = fuse(_retrieval(retrieved, []), pairs, 20)
    assert summary is not None and summary.sets == 2
    assert summary.photos == [0, 1, 2, 3, 5, 6, 7] and summary.pairs == len(pairs)
    poses = np.stack([m.c2w for m in fused.matches])
    assert np.array_equal(poses[4], retrieved[4])
    for i, j in ((0, 3), (5, 7)):  # within a set, the pairs' relative rotation
        assert rotation_angle_deg((_relative(poses, i, j).T @ _relative(truth, i, j))[None])[
            0] < 0.5


def test_two_photos_joined_by_one_pair_alone_are_not_fused() -> None:
    truth = _truth()
    retrieved = _noisy(truth, 15.0, seed=3)
    pairs = [_pair(truth, i, j) for i, j in ((0, 1), (1, 2), (0, 2), (5, 6))]
    fused, summary = fuse(_retrieval(retrieved, []), pairs, 20)
    assert summary is not None and summary.sets == 1 and summary.photos == [0, 1, 2]
    assert np.array_equal(fused.matches[5].c2w, retrieved[5])


def test_a_chain_of_pairs_far_from_the_retrieved_cameras_is_fused_whole() -> None:
    """Five photos joined by a chain of exact pairs (no triangle), each retrieved camera 20 to
    45 degrees off: every pair holds after fusing. Averaged from the retrieved cameras
    themselves, the robust weights judged a right pair of this draw an outlier and the chain
    fell apart into sets too small to fuse."""
    truth = _truth()[:5]
    rng = np.random.default_rng(53)
    retrieved = truth.copy()
    for pose in retrieved:
        axis = rng.normal(size=3)
        turn = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(rng.uniform(20, 45)))[0]
        pose[:3, :3] = turn @ pose[:3, :3]
    chain = [_pair(truth, k, k + 1) for k in range(4)]
    fused, summary = fuse(_retrieval(retrieved, []), chain, 20)
    assert summary is not None and summary.photos == list(range(5))
    assert summary.implausible == 0
    poses = np.stack([m.c2w for m in fused.matches])
    for p in chain:
        assert rotation_angle_deg((_relative(poses, p.i, p.j) @ p.rotation.T)[None])[0] < 0.5


def _turned(c2w: np.ndarray, photos: tuple[int, ...], degrees: float, seed: int) -> np.ndarray:
    """The cameras with the given photos' turned by ``degrees`` about random axes (as
    retrieval places a look-alike's photos on its other side)."""
    rng = np.random.default_rng(seed)
    out = c2w.copy()
    for k in photos:
        axis = rng.normal(size=3)
        out[k, :3, :3] = cv2.Rodrigues(axis / np.linalg.norm(axis)
                                       * np.radians(degrees))[0] @ out[k, :3, :3]
    return out


def test_a_triangle_of_pairs_that_all_contradict_the_retrieved_cameras_vouches_for_them() -> None:
    """Photos 0 to 2 retrieved 100 degrees off, every pair exact: their pairs are far from the
    retrieved cameras (``PRIOR_DEG``) but agree among themselves, so they are plausible and
    the fusion brings the three cameras back to the others'."""
    truth = _truth()
    retrieved = _turned(truth, (0, 1, 2), 100.0, seed=4)
    pairs = _walk_pairs(truth)
    triangle = [p for p in pairs if p.j <= 2]
    prior = {m.index: m.c2w for m in _retrieval(retrieved, []).matches}
    assert all(rotation_angle_deg((_relative(retrieved, p.i, p.j)
                                   @ np.asarray(p.rotation).T)[None])[0] > PRIOR_DEG
               for p in triangle)
    kept = {(p.i, p.j) for p in plausible_at(prior, pairs)}
    # Photo 2's pair with photo 4 is far too, but closes no triangle of far pairs (2-3-4
    # holds the right camera 3's pair with 4): it stays out.
    assert {(p.i, p.j) for p in pairs} - kept == {(2, 4)}
    fused, summary = fuse(_retrieval(retrieved, []), pairs, 20)
    assert summary is not None and summary.implausible == 1
    poses = np.stack([m.c2w for m in fused.matches])
    # The rigid set, anchored on the five right cameras: every camera within a degree.
    assert _errors(poses, truth).max() < 1.0
    assert _errors(retrieved, truth)[:3].min() > 50.0


@pytest.mark.parametrize("kind", ["still", "one wrong"])
def test_a_triangle_does_not_vouch_for_turns_of_a_few_degrees_or_for_a_pair_that_breaks_it(
        kind: str) -> None:
    """Three pairs of features that travel with the camera compose into a closed triangle
    whatever the photos' angles (``MIN_TURN_DEG``); a triangle with one pair matched wrongly
    does not close. Neither makes a pair far from the retrieved cameras plausible."""
    truth = _truth()
    retrieved = _turned(truth, (0, 1, 2), 100.0, seed=4)
    if kind == "still":
        triangle = [_still(truth, 0, 1), _still(truth, 1, 2), _still(truth, 0, 2)]
        turns = rotation_angle_deg(np.stack([np.asarray(p.rotation) for p in triangle]))
        assert turns.max() < MIN_TURN_DEG
    else:
        flip = cv2.Rodrigues(np.array([0.0, np.pi, 0.0]))[0]
        triangle = [_pair(truth, 0, 1), _pair(truth, 1, 2),
                    _pair(truth, 0, 2, rotation=flip @ _relative(truth, 0, 2))]
    prior = {k: pose for k, pose in enumerate(retrieved)}
    assert vouched(triangle) == set()
    assert plausible_at(prior, triangle) == []

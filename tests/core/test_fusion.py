"""Retrieved cameras fused with the rotations the photos' matches measured (``retrieval.fusion``):
exact pairs bring noisy cameras near the truth, a wrong pair is dropped, and too few pairs
change nothing."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cadnerf_core.cameras import orbit_pose, rotation_angle_deg
from cadnerf_core.intake.crop import CropBox
from cadnerf_core.retrieval.fusion import (
    anchor,
    average_rotations,
    consistent_edges,
    fuse,
    fuse_hypotheses,
)
from cadnerf_core.retrieval.matches import PairMatch
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

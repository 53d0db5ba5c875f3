"""Geometry first (``retrieval.mapper``, ``placement.place``): COLMAP's mapper on verified matches
of points a walk round a ball sees recovers the cameras and an unknown focal length, and the
job's start takes them into the CAD frame."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from cadnerf_core.cameras.conventions import orbit_pose, pose_errors, project, rotation_angle_deg
from cadnerf_core.cameras.fusion import fuse
from cadnerf_core.cameras.mapper import (
    MIN_INLIER_SHARE,
    MIN_POINTS_PER_PHOTO,
    Mapped,
    _keypoints,
    accept,
    complete,
    map_photos,
    mapper_pairs,
)
from cadnerf_core.cameras.matches import PairMatch
from cadnerf_core.cameras.placement import place
from cadnerf_core.intake.crop import CropBox
from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult

N = 8
SIZE = (640, 480)
K_TRUE = np.array([[560.0, 0.0, 320.0], [0.0, 560.0, 240.0], [0.0, 0.0, 1.0]])


def _truth() -> np.ndarray:
    return np.stack([orbit_pose(30.0 * k, 20.0 + 4.0 * (k % 2), 4.0) for k in range(N)])


def _pairs(truth: np.ndarray) -> list[PairMatch]:
    """Neighbours and next-but-one, their inliers the projections of points on a ball that
    both cameras face (a feature seen in several pairs has the same pixel in each)."""
    rng = np.random.default_rng(1)
    ball = rng.normal(size=(1500, 3))
    ball = 0.9 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    pixels = [project(ball, K_TRUE, c2w) + rng.normal(0.0, 0.3, (len(ball), 2)) for c2w in truth]
    facing = [ball @ (c2w[:3, 3] / np.linalg.norm(c2w[:3, 3])) > 0.3 for c2w in truth]
    pairs = []
    for i in range(N):
        for j in (i + 1, i + 2):
            if j < N:
                keep = facing[i] & facing[j]
                points = np.stack([pixels[i][keep], pixels[j][keep]], axis=1)
                R = truth[j, :3, :3].T @ truth[i, :3, :3]
                pairs.append(PairMatch(i, j, len(points), len(points), 0.3, 0.0, R, points))
    return pairs


def test_a_feature_in_several_pairs_is_one_keypoint() -> None:
    a, b, c = np.array([1.0, 2.0]), np.array([3.0, 4.0]), np.array([5.0, 6.0])
    pairs = [PairMatch(0, 1, 1, 1, 0.1, 0.0, np.eye(3), np.array([[a, b]])),
             PairMatch(1, 2, 1, 1, 0.1, 0.0, np.eye(3), np.array([[b, c]]))]
    points, matches = _keypoints(pairs, 3)
    assert [len(p) for p in points] == [1, 1, 1]
    assert matches[(0, 1)].tolist() == [[0, 0]] and matches[(1, 2)].tolist() == [[0, 0]]


def test_the_mapper_finds_the_cameras_and_an_unknown_focal_length() -> None:
    truth = _truth()
    mapped = map_photos(_pairs(truth), [SIZE] * N, 0.7 * K_TRUE[0, 0], False, 20)
    assert mapped is not None and mapped.photos == list(range(N))
    assert mapped.focal == pytest.approx(K_TRUE[0, 0], rel=0.03)
    assert mapped.reprojection_px < 1.0 and mapped.points > 100
    assert np.median(pose_errors(mapped.c2w, truth)[0]) < 1.0
    assert accept(mapped, max(SIZE))
    assert not accept(dataclasses.replace(mapped, radial=0.9), max(SIZE))
    assert not accept(dataclasses.replace(mapped, reprojection_px=3.0), max(SIZE))
    assert not accept(dataclasses.replace(mapped, points=MIN_POINTS_PER_PHOTO * N - 1),
                      max(SIZE))
    assert not accept(None, max(SIZE))


def test_the_same_matches_give_the_same_cameras() -> None:
    truth = _truth()
    runs = [map_photos(_pairs(truth), [SIZE] * N, 0.7 * K_TRUE[0, 0], False, 20)
            for _ in range(2)]
    assert runs[0] is not None and runs[1] is not None
    assert np.array_equal(runs[0].c2w, runs[1].c2w) and runs[0].focal == runs[1].focal


def test_a_pair_whose_geometry_explains_few_of_its_matches_is_not_mapped() -> None:
    pairs = _pairs(_truth())
    good = pairs[0]
    chance = dataclasses.replace(good, i=0, j=5, matched=int(good.inliers / MIN_INLIER_SHARE) + 1)
    few = dataclasses.replace(good, i=0, j=6, inliers=19, matched=19)
    unverified = dataclasses.replace(good, i=0, j=7, rotation=None)
    assert mapper_pairs([good, chance, few, unverified], 20) == [good]


def test_photos_that_share_nothing_are_not_registered_and_the_rest_kept() -> None:
    truth = _truth()
    pairs = [p for p in _pairs(truth) if p.j <= 3]  # photos 4-7 share nothing
    mapped = map_photos(pairs, [SIZE] * N, K_TRUE[0, 0], True, 20)
    assert mapped is not None and mapped.photos == [0, 1, 2, 3]
    assert not complete(mapped, N) and complete(mapped, 5)
    assert np.median(pose_errors(mapped.c2w, truth[:4])[0]) < 1.0
    two = [p for p in pairs if p.j == 1]  # two photos: no walk to register
    assert map_photos(two, [SIZE] * N, K_TRUE[0, 0], True, 20) is None
    assert map_photos(_pairs(truth), [SIZE] * (N - 1) + [(480, 640)], K_TRUE[0, 0], True,
                      20) is None  # photos of another size share no camera


def test_the_start_takes_the_mapped_cameras_into_the_cad_frame() -> None:
    truth = _truth()
    K_guess = np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(2)
    retrieved = []
    for pose in truth:  # retrieval: each camera 10 degrees off, at its distance
        noisy = orbit_pose(0.0, 0.0, 4.0)
        axis = rng.normal(size=3)
        angle = np.radians(10.0)
        turn = cv2.Rodrigues(axis / np.linalg.norm(axis) * angle)[0]
        noisy[:3, :3] = pose[:3, :3] @ turn
        noisy[:3, 3] = -4.0 * noisy[:3, 2]
        retrieved.append(noisy)
    matches = [PhotoMatch(k, f"p{k}", k, 0.0, 0.0, 0.9, False, c2w, K_guess,
                          CropBox(0, 0, 480, 128), K_guess) for k, c2w in enumerate(retrieved)]
    retrieval = RetrievalResult("m", "c", [], matches, "dp", 1, 1.0)
    # The mapper's frame: the truth turned, scaled and moved.
    frame = np.eye(4)
    frame[:3, :3] = cv2.Rodrigues(np.array([0.3, -1.2, 0.5]))[0]
    frame[:3, 3] = [5.0, -2.0, 1.0]
    mapped_c2w = np.stack([frame @ c for c in truth])
    mapped_c2w[:, :3, 3] *= 0.25
    mapped = Mapped(list(range(N)), mapped_c2w, 560.0, 0.0, 500, 0.5)
    placed = place(retrieval, mapped, focal_known=False)
    poses = np.stack([m.c2w for m in placed.matches])
    assert rotation_angle_deg(np.swapaxes(poses[:, :3, :3], 1, 2) @ truth[:, :3, :3]).max() < 6.0
    for i in range(N - 1):  # the mapper's relative rotations, exactly
        rel = poses[i + 1, :3, :3].T @ poses[i, :3, :3]
        assert np.allclose(rel, truth[i + 1, :3, :3].T @ truth[i, :3, :3], atol=1e-9)
    assert np.allclose(np.linalg.norm(poses[:, :3, 3], axis=1), 4.0, atol=0.1)
    assert placed.matches[0].K_photo[0, 0] == pytest.approx(560.0)
    assert placed.matches[0].K_photo[0, 2] == 320.0
    assert placed.fusion is not None and placed.fusion["start"] == "mapper"
    assert all(m.c2w_retrieved is not None for m in placed.matches)
    kept_focal = place(retrieval, mapped, focal_known=True)
    assert kept_focal.matches[0].K_photo[0, 0] == 400.0


def test_one_photo_the_mapper_leaves_out_is_left_out_of_training() -> None:
    truth = _truth()
    pairs = [p for p in _pairs(truth) if N - 1 not in (p.i, p.j)]  # the last photo shares nothing
    mapped = map_photos(pairs, [SIZE] * N, K_TRUE[0, 0], True, 20)
    assert mapped is not None and mapped.photos == list(range(N - 1))
    assert np.median(pose_errors(mapped.c2w, truth[:-1])[0]) < 1.0
    matches = [PhotoMatch(k, f"p{k}", k, 0.0, 0.0, 0.9, False, c2w, K_TRUE,
                          CropBox(0, 0, 480, 128), K_TRUE) for k, c2w in enumerate(truth)]
    placed = place(RetrievalResult("m", "c", [], matches, "dp", 1, 1.0), mapped, True)
    assert [m.discarded for m in placed.matches] == [False] * (N - 1) + [True]
    assert placed.fusion is not None and placed.fusion["unplaced"] == [N - 1]
    assert np.array_equal(placed.matches[-1].c2w, truth[-1])


def _noisy(truth: np.ndarray, degrees: float, seed: int) -> list[np.ndarray]:
    """Each camera turned ``degrees`` about a random axis, at its distance, looking at the
    centre's side: retrieval's error."""
    rng = np.random.default_rng(seed)
    out = []
    for pose in truth:
        axis = rng.normal(size=3)
        turn = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(degrees))[0]
        noisy = np.eye(4)
        noisy[:3, :3] = pose[:3, :3] @ turn
        noisy[:3, 3] = -np.linalg.norm(pose[:3, 3]) * noisy[:3, 2]
        out.append(noisy)
    return out


def test_the_photos_a_partial_mapper_registered_join_the_fusion_as_one_rigid_set() -> None:
    truth = _truth()
    pairs = [p for p in _pairs(truth) if p.j <= 3]  # photos 4-7 share nothing
    mapped = map_photos(pairs, [SIZE] * N, K_TRUE[0, 0], True, 20)
    assert mapped is not None and mapped.photos == [0, 1, 2, 3]
    matches = [PhotoMatch(k, f"p{k}", k, 0.0, 0.0, 0.9, False, c2w, K_TRUE,
                          CropBox(0, 0, 480, 128), K_TRUE)
               for k, c2w in enumerate(_noisy(truth, 12.0, 3))]
    retrieval = RetrievalResult("m", "c", [], matches, "dp", 1, 1.0)
    alone, _ = fuse(retrieval, [], 20)  # no pairs: the retrieved cameras stay
    fused, summary = fuse(retrieval, [], 20, mapped=mapped)
    assert summary is not None and list(summary.mapped) == [0, 1, 2, 3]
    assert fused.fusion is not None and fused.fusion["mapped"] == [0, 1, 2, 3]
    poses = np.stack([m.c2w for m in fused.matches])
    for i in range(3):  # the mapper's relative rotations, kept
        rel = poses[i + 1, :3, :3].T @ poses[i, :3, :3]
        truth_rel = truth[i + 1, :3, :3].T @ truth[i, :3, :3]
        assert rotation_angle_deg((rel.T @ truth_rel)[None])[0] < 1.0
    assert np.array_equal(poses[5], matches[5].c2w)  # a photo nothing places keeps its own
    start = [m.c2w for m in alone.matches[:4]]
    before = rotation_angle_deg(np.stack([c[:3, :3].T @ t[:3, :3]
                                          for c, t in zip(start, truth[:4], strict=True)]))
    after = rotation_angle_deg(np.stack([p[:3, :3].T @ t[:3, :3]
                                         for p, t in zip(poses[:4], truth[:4], strict=True)]))
    assert np.median(after) < 0.6 * np.median(before)  # four errors average in the anchor

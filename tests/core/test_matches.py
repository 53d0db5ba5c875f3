"""Matches between photos (ALIKED with LightGlue by default, XFeat with LighterGlue or SIFT on
request): the turn between two rendered photos of a textured ball, and nothing from a plain
one."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import pytest
import trimesh

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
from cadnerf_core.cameras.matches import (
    Features,
    PairMatch,
    detect,
    large_enough,
    match_photos,
    mutual_matches,
    sampson_errors,
    vertical_turn_deg,
    walk_evidence,
)
from cadnerf_core.config import MatchesConfig, RetrievalConfig
from cadnerf_core.mesh.renderer import MeshRenderer
from cadnerf_core.retrieval.search import retrieve

SIZE = 256
FOV = 40.0


def _ball(textured: bool) -> trimesh.Trimesh:
    """A sphere (the same silhouette from everywhere) with random blotches of grey, or plain."""
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.8)
    rng = np.random.default_rng(3)
    grey = rng.integers(30, 230, len(mesh.vertices)) if textured \
        else np.full(len(mesh.vertices), 150)
    colours = np.stack([grey, grey, grey, np.full_like(grey, 255)], axis=1).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
    return mesh


def _photos(mesh: trimesh.Trimesh, azimuths: list[float],
            elevation: float = 15.0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    renderer = MeshRenderer(mesh)
    K = intrinsics_from_fov(FOV, SIZE)
    shots = [renderer.render(K, orbit_pose(a, elevation, 3.0), SIZE, SIZE) for a in azimuths]
    return [s.rgb for s in shots], [s.mask for s in shots]


def _intrinsics(n: int) -> list[np.ndarray]:
    return [intrinsics_from_fov(FOV, SIZE)] * n


@pytest.mark.parametrize(("turn", "method"), [(25.0, "aliked"), (-25.0, "aliked"),
                                              (25.0, "xfeat"), (-25.0, "xfeat"), (25.0, "sift")])
def test_the_turn_between_two_photos_has_its_sign_and_about_its_size(turn: float,
                                                                     method: str) -> None:
    images, masks = _photos(_ball(True), [40.0, 40.0 + turn])
    (pair,) = match_photos(images, masks, _intrinsics(2), MatchesConfig(method=method))
    assert pair.inliers >= MatchesConfig().min_inliers
    assert pair.turn_deg is not None
    assert abs(pair.turn_deg - turn) < 5.0
    assert pair.sampson_px is not None and pair.sampson_px < 1.0
    assert 0.0 < pair.inlier_ratio <= 1.0


@pytest.mark.parametrize("direction", [1, -1])
def test_matched_turns_tell_the_walking_direction(direction: int) -> None:
    images, masks = _photos(_ball(True), [100.0 + direction * 30.0 * i for i in range(3)])
    config = MatchesConfig()
    pairs = match_photos(images, masks, _intrinsics(3), config)
    assert [(p.i, p.j) for p in pairs] == [(0, 1), (0, 2), (1, 2)]
    assert walk_evidence(pairs, 12, config) == pytest.approx(
        2 * direction * config.evidence_per_pair)


def test_a_plain_object_gives_no_turn_and_no_evidence() -> None:
    images, masks = _photos(_ball(False), [0.0, 25.0, 50.0])
    pairs = match_photos(images, masks, _intrinsics(3), MatchesConfig())
    assert all(p.turn_deg is None and p.rotation is None for p in pairs)
    assert walk_evidence(pairs, 12, MatchesConfig()) == 0.0


@pytest.mark.parametrize("method", ["aliked", "xfeat", "sift"])
def test_an_object_too_small_in_its_photos_is_not_matched(method: str) -> None:
    """The textured ball whose turn is found at 256 px spans under ``MIN_SEARCH_SIDE`` pixels
    when the photos are shrunk to 128 px: no features, so no pair, turn or evidence."""
    images, masks = _photos(_ball(True), [40.0, 65.0, 90.0])
    small = [cv2.resize(image, (SIZE // 2, SIZE // 2), interpolation=cv2.INTER_AREA)
             for image in images]
    small_masks = [cv2.resize(mask.astype(np.uint8), (SIZE // 2, SIZE // 2),
                              interpolation=cv2.INTER_NEAREST) > 0 for mask in masks]
    assert all(large_enough(mask) for mask in masks)
    assert not any(large_enough(mask) for mask in small_masks)
    K = intrinsics_from_fov(FOV, SIZE // 2)
    config = MatchesConfig(method=method)
    pairs = match_photos(small, small_masks, [K] * 3, config)
    assert len(pairs) == 3
    assert all(p.inliers == 0 and p.rotation is None for p in pairs)
    assert walk_evidence(pairs, 12, config) == 0.0
    # The same photos at 256 px are matched: the size, not the texture, made the difference.
    assert any(p.rotation is not None for p in match_photos(images, masks, _intrinsics(3),
                                                               config))


def _blob(centre: tuple[float, float, float], radius: float, seed: int) -> trimesh.Trimesh:
    """A small sphere with coarse blotches of grey (fewer vertices: blotches SIFT can see)."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    grey = np.random.default_rng(seed).integers(30, 230, len(mesh.vertices))
    colours = np.stack([grey, grey, grey, np.full_like(grey, 255)], axis=1).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
    mesh.apply_translation(centre)
    return mesh


def _among_things(turn: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """An object without features of its own (a white ball, radius 0.3) among eight blotchy
    things standing still in a ring round it at several heights, seen from two azimuths
    ``turn`` apart; the masks are the ball's."""
    things = [_blob((0.7 * math.cos(k * math.pi / 4), -0.5 + 0.9 * ((0.37 * k) % 1.0),
                     0.7 * math.sin(k * math.pi / 4)), 0.15, k) for k in range(8)]
    azimuths = [40.0, 40.0 + turn]
    images, _ = _photos(trimesh.util.concatenate(things), azimuths, 25.0)
    _, masks = _photos(trimesh.creation.icosphere(subdivisions=3, radius=0.3), azimuths, 25.0)
    for image, mask in zip(images, masks, strict=True):
        image[mask] = 1.0
    return images, masks


@pytest.mark.parametrize("turn", [25.0, -25.0])
def test_what_stands_round_a_plain_object_gives_the_turn(turn: float) -> None:
    images, masks = _among_things(turn)
    (alone,) = match_photos(images, masks, _intrinsics(2), MatchesConfig(context=0.0))
    assert alone.turn_deg is None
    (pair,) = match_photos(images, masks, _intrinsics(2), MatchesConfig(context=1.0))
    assert pair.inliers >= MatchesConfig().min_inliers
    assert pair.turn_deg is not None and abs(pair.turn_deg - turn) < 5.0


def test_an_outline_on_a_plain_background_gives_no_features_round_it() -> None:
    # The notches of a star against white look like features just outside its mask, but
    # they move with the view; only patches clear of the object are kept, so none is.
    points = [(160 + (100 if k % 2 == 0 else 40) * math.cos(math.pi * k / 5),
               160 + (100 if k % 2 == 0 else 40) * math.sin(math.pi * k / 5))
              for k in range(10)]
    mask = np.zeros((320, 320), np.uint8)
    cv2.fillPoly(mask, [np.round(np.array(points)).astype(np.int32)], 255)
    image = np.ones((320, 320, 3), np.float32)
    image[mask > 0] = 0.3
    alone = detect(image, mask > 0, 640, 0.0)
    around = detect(image, mask > 0, 640, 0.5)
    assert len(alone.points) > 0
    assert len(around.points) == len(alone.points)


def test_the_object_keeps_its_own_features_with_context() -> None:
    images, masks = _photos(_ball(True), [40.0])
    alone = detect(images[0], masks[0], 640, 0.0)
    around = detect(images[0], masks[0], 640, 0.5)
    # On white round the object nothing more is found, and the object's own are the same.
    np.testing.assert_allclose(around.points[:len(alone.points)], alone.points)
    assert around.scale == alone.scale


def test_vertical_turn_of_orbiting_cameras_follows_the_azimuth() -> None:
    for elevation in (0.0, 30.0):
        a, b = orbit_pose(10.0, elevation, 3.0), orbit_pose(40.0, elevation, 3.0)
        R = np.linalg.inv(b)[:3, :3] @ a[:3, :3]  # camera a to camera b
        assert vertical_turn_deg(R) == pytest.approx(30.0, abs=1e-6)
        assert vertical_turn_deg(R.T) == pytest.approx(-30.0, abs=1e-6)


def test_mutual_matches_keep_only_distinct_agreeing_nearest_neighbours() -> None:
    a = np.array([[0, 0], [10, 0], [0, 10]], np.float32)
    b = np.array([[0.1, 0], [10, 0.2], [5, 5], [0, 9.9]], np.float32)
    assert mutual_matches(a, b).tolist() == [[0, 0], [1, 1], [2, 3]]
    b_ambiguous = np.array([[0.1, 0], [-0.1, 0], [10, 0]], np.float32)
    assert mutual_matches(a, b_ambiguous).tolist() == [[1, 2]]


def test_sampson_error_is_the_distance_to_a_horizontal_epipolar_line() -> None:
    F = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # a sideways shift
    x_a = np.array([[5.0, 3.0], [1.0, 2.0]])
    x_b = np.array([[9.0, 3.0], [4.0, 6.0]])  # on its line, 4 px off it
    assert sampson_errors(F, x_a, x_b) == pytest.approx([0.0, 4.0 / np.sqrt(2.0)])


def test_retrieval_records_the_pairs_and_plain_photos_change_nothing(tiny_library: Any) -> None:
    images, masks = _photos(_ball(False), [0.0, 120.0, 240.0])
    names = ["a", "b", "c"]
    on = retrieve(masks, names, tiny_library, images=images)
    off = retrieve(masks, names, tiny_library,
                   RetrievalConfig(matches=MatchesConfig(enabled=False)), images=images)
    assert [(p["i"], p["j"]) for p in on.to_json()["photo_pairs"]] == [(0, 1), (0, 2), (1, 2)]
    assert "photo_pairs" not in off.to_json()
    assert on.direction_evidence == off.direction_evidence
    assert [m.view for m in on.matches] == [m.view for m in off.matches]


def _pair(i: int, turn: float | None) -> PairMatch:
    return PairMatch(i, i + 1, 50, 40, 0.2, turn, None, np.zeros((0, 2, 2)))


def test_only_walking_sized_turns_that_mostly_agree_count() -> None:
    config = MatchesConfig()  # 6 photos: an even step is 60 degrees, turns 24-120 count
    per_pair = config.evidence_per_pair
    assert walk_evidence([_pair(0, 50.0), _pair(1, 70.0), _pair(2, None)], 6, config) \
        == pytest.approx(2 * per_pair)
    assert walk_evidence([_pair(0, -50.0), _pair(3, 5.0), _pair(4, 150.0)], 6, config) \
        == pytest.approx(-per_pair)  # a 5-degree turn (camera-fixed features) and a 150
    assert walk_evidence([_pair(0, 50.0), _pair(1, -50.0)], 6, config) == 0.0
    three_to_one = [_pair(0, -50.0), _pair(1, -40.0), _pair(2, -60.0), _pair(3, 45.0)]
    assert walk_evidence(three_to_one, 6, config) == pytest.approx(-2 * per_pair)
    assert walk_evidence(three_to_one[1:], 6, config) == 0.0  # two to one: split
    far = PairMatch(0, 2, 50, 40, 0.2, 60.0, None, np.zeros((0, 2, 2)))
    assert walk_evidence([far], 6, config) == 0.0  # not consecutive


def test_lighterglue_matches_the_close_pairs_and_nearest_descriptors_the_rest(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from cadnerf_core.cameras import learned

    # Five photos round a loop: every pair is within two steps.
    assert learned.close_pairs(5) == {(i, j) for i in range(5) for j in range(i + 1, 5)}
    assert learned.close_pairs(6) == {(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (0, 5), (0, 2),
                                      (1, 3), (2, 4), (3, 5), (0, 4), (1, 5)}
    used: dict[tuple[int, int], str] = {}
    features = [learned.CropFeatures(np.full((3, 2), float(k)), np.eye(3, 64, dtype=np.float32))
                for k in range(6)]

    def glue(a: Any, b: Any) -> np.ndarray:
        used[(int(a.points[0, 0]), int(b.points[0, 0]))] = "glue"
        return np.zeros((0, 2), np.int64)

    def mutual(a: Any, b: Any) -> np.ndarray:
        used[(int(a.points[0, 0]), int(b.points[0, 0]))] = "mutual"
        return np.zeros((0, 2), np.int64)

    monkeypatch.setattr(learned, "match_glue", glue)
    monkeypatch.setattr(learned, "match_mutual", mutual)
    found = learned.match_indices(features, learned.close_pairs(6))
    assert list(found) == [(i, j) for i in range(6) for j in range(i + 1, 6)]
    assert {e for e, how in used.items() if how == "glue"} == learned.close_pairs(6)
    assert {e for e, how in used.items() if how == "mutual"} == {(0, 3), (1, 4), (2, 5)}


def test_mutual_nearest_descriptors_need_agreement_and_similarity() -> None:
    from cadnerf_core.cameras.learned import match_mutual

    a = np.eye(4, 8, dtype=np.float32)
    b = np.eye(4, 8, dtype=np.float32)[[2, 0, 3, 1]]
    b[3] = np.eye(1, 8, 7, dtype=np.float32)  # b's last matches nothing in a
    found = match_mutual(Features(np.zeros((4, 2)), a), Features(np.zeros((4, 2)), b))
    assert found.tolist() == [[0, 1], [2, 0], [3, 2]]

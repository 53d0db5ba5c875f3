"""The capture benchmark's pieces (``benchmarks.bench_captures`` and its modules,
``benchmarks.textured_walks``): reading a capture, the users' spacing, scoring pairs, the
mirrored-walk check, the phone lens, the textured floor, the tables."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from trimesh.visual import TextureVisuals

from benchmarks import capture_set
from benchmarks.capture_jobs import registered_photos, score_row, start_kind
from benchmarks.capture_set import Capture, load_capture, users_capture
from benchmarks.capture_spacing import (
    choose_walk,
    object_centre,
    ring_angles,
    score_pairs,
    spacing_deg,
    up_axis,
)
from benchmarks.capture_tables import table, worse_than_silhouettes
from benchmarks.textured_walks import floor_mesh, mirrored, phone_focal_35mm
from cadnerf_core.cameras.conventions import orbit_pose


@pytest.fixture()
def roots(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Captures under ``tmp_path/shared`` (none imported)."""
    monkeypatch.setattr(capture_set, "CAPTURES", tmp_path / "shared")
    monkeypatch.setattr(capture_set, "LOCAL_CAPTURES", tmp_path / "local")
    return tmp_path / "shared"


def _ring(azimuths: list[float], elevation: float = 20.0) -> np.ndarray:
    return np.stack([orbit_pose(a, elevation, 4.0) for a in azimuths])


def test_a_capture_reads_its_cameras_and_its_masks_when_it_ships_them(roots: Path) -> None:
    folder = roots / "thing"
    (folder / "images").mkdir(parents=True)
    frames = []
    for k in range(3):
        Image.new("RGB", (8, 6)).save(folder / "images" / f"{k:03d}.jpg")
        frames.append({"image": f"images/{k:03d}.jpg", "c2w": orbit_pose(40.0 * k, 20, 4).tolist(),
                       "K": [[7.0 + k, 0, 4], [0, 7.0, 3], [0, 0, 1]]})
    (folder / "cameras.json").write_text(json.dumps({"frames": frames}))
    capture = load_capture("thing")
    assert [p.name for p in capture.photos] == ["000.jpg", "001.jpg", "002.jpg"]
    assert capture.masks is None  # no masks/ folder: the job makes them
    assert capture.exif_35mm is None and capture.overrides == {}
    assert capture.focal is not None and capture.focal.tolist() == [7.0, 8.0, 9.0]
    assert np.allclose(capture.c2w[1], orbit_pose(40.0, 20, 4))
    (folder / "masks").mkdir()
    for k in range(3):
        Image.new("L", (8, 6)).save(folder / "masks" / f"{k:03d}.png")
    (folder / "cameras.json").write_text(json.dumps({"frames": frames, "focal_35mm": 26}))
    again = load_capture("thing")
    assert again.masks == [folder / "masks" / f"{k:03d}.png" for k in range(3)]
    assert again.exif_35mm == 26.0 and again.overrides == {"retrieval.focal_35mm": 26.0}


def test_a_frame_a_rig_took_upside_down_is_given_upright_with_its_camera_rolled(
        roots: Path) -> None:
    folder = roots / "rig"
    (folder / "images").mkdir(parents=True)
    pixels = np.arange(6 * 8 * 3, dtype=np.uint8).reshape(6, 8, 3)
    frames = []
    for k in range(2):
        Image.fromarray(pixels).save(folder / "images" / f"{k:03d}.png")
        frames.append({"image": f"images/{k:03d}.png", "c2w": orbit_pose(40.0 * k, 20, 4).tolist(),
                       "K": [[7.0, 0, 4], [0, 7.0, 3], [0, 0, 1]],
                       "upside_down_by_design": k == 1})
    (folder / "cameras.json").write_text(json.dumps({"frames": frames}))
    capture = load_capture("rig")
    assert capture.photos[0] == folder / "images" / "000.png"
    turned = np.asarray(Image.open(capture.photos[1]))
    assert np.array_equal(turned, pixels[::-1, ::-1])
    assert np.allclose(capture.c2w[0], orbit_pose(0.0, 20, 4))
    rolled = capture.c2w[1]
    original = orbit_pose(40.0, 20, 4)
    assert np.allclose(rolled[:3, 3], original[:3, 3])  # the camera stays where it was
    assert np.allclose(rolled[:3, 2], original[:3, 2])  # looking the same way
    assert np.allclose(rolled[:3, :2], -original[:3, :2])  # half a turn about its axis


def test_the_centre_and_the_vertical_of_a_ring_are_found_whatever_the_roll() -> None:
    c2w = _ring([5.0 * k for k in range(72)])
    c2w[:, :3, 3] += [1.0, 2.0, 3.0]
    assert np.allclose(object_centre(c2w), [1.0, 2.0, 3.0], atol=1e-6)
    assert np.allclose(up_axis(c2w), [0.0, 1.0, 0.0], atol=1e-6)
    sideways = c2w.copy()
    sideways[:, :3, :2] = np.stack([-c2w[:, :3, 1], c2w[:, :3, 0]], axis=2)  # rolled 90 deg
    assert np.allclose(up_axis(sideways), [0.0, 1.0, 0.0], atol=1e-6)
    azimuth, elevation = ring_angles(c2w, object_centre(c2w), up_axis(c2w))
    assert np.allclose(elevation, 20.0) and np.allclose(np.diff(azimuth) % 360.0, 5.0)


def test_photos_facing_the_object_from_one_side_are_no_ring() -> None:
    # A wall of cameras in front of the object at several heights: its plane's normal is the
    # way they look, not the vertical.
    c2w = np.stack([orbit_pose(a, e, 4.0) for a in (-20.0, 0.0, 20.0) for e in (-20, 0, 20)])
    assert np.allclose(up_axis(c2w), -c2w[:, :3, 1].mean(axis=0) / np.linalg.norm(
        c2w[:, :3, 1].mean(axis=0)))


def test_a_dense_ring_gives_eight_photos_45_degrees_apart_the_way_it_was_taken() -> None:
    azimuth = np.arange(72) * 5.0
    walk = choose_walk(azimuth, np.full(72, 20.0))
    assert len(walk) == 8 and walk[0] == 0
    assert np.allclose(np.diff(azimuth[walk]) % 360.0, 45.0)
    backwards = choose_walk(azimuth[::-1].copy(), np.full(72, 20.0))
    assert len(backwards) == 8 and backwards == sorted(backwards)  # the order it was taken


def test_an_arc_gives_photos_every_second_frame_and_a_tight_ring_none() -> None:
    dtu = np.array([193, 204, 228, 239, 263, 274, 298, 309], dtype=float)  # a DTU camera row
    walk = choose_walk(dtu, np.zeros(8))
    assert walk == [0, 2, 4, 6]  # every second frame
    steps = np.diff(dtu[walk])
    assert steps.min() >= 30.0 and steps.max() <= 60.0
    alternating = np.cumsum([0.0] + [46.0, 24.0] * 5)[:10] % 360.0  # 46 or 24 apart: no walk
    assert choose_walk(alternating, np.zeros(10)) == []


def test_the_walk_keeps_to_one_height_and_measures_the_angle_between_the_photos() -> None:
    azimuth = np.tile(np.arange(36) * 10.0, 2)
    elevation = np.repeat([10.0, 70.0], 36)
    elevation[:10] = 70.0  # the median is the high ring
    walk = choose_walk(azimuth, elevation)
    assert all(elevation[k] == 70.0 for k in walk)
    # Seen from the object, photos 45 degrees of azimuth apart at 70 degrees up stand 15 apart.
    c2w = np.stack([orbit_pose(a, e, 4.0) for a, e in zip(azimuth, elevation, strict=True)])
    rays = c2w[:, :3, 3] / np.linalg.norm(c2w[:, :3, 3], axis=1, keepdims=True)
    walk = choose_walk(azimuth, elevation, rays=rays)
    assert len(walk) >= 3 and 30.0 <= spacing_deg(c2w[walk]) <= 60.0


def test_a_dense_capture_is_subsampled_to_the_users_spacing() -> None:
    c2w = _ring([22.5 * k for k in range(16)])
    dense = Capture("ring", [Path(f"{k}.jpg") for k in range(16)], None, c2w,
                    np.arange(16.0))
    walk = users_capture(dense)
    assert walk is not None and len(walk.photos) == 8
    assert walk.frames == tuple(range(0, 16, 2))
    assert walk.focal is not None and walk.focal.tolist() == list(range(0, 16, 2))
    assert walk.spacing == pytest.approx(45.0 * np.cos(np.radians(20.0)), abs=1.0)
    already = Capture("ring8", dense.photos[::2], None, c2w[::2], None)
    kept = users_capture(already)
    assert kept is not None and kept.frames == tuple(range(8))


def test_a_pair_is_right_when_its_rotation_is_the_reference_s() -> None:
    c2w = _ring([0.0, 45.0, 90.0])
    true = c2w[1][:3, :3].T @ c2w[0][:3, :3]  # camera 0's axes to camera 1's
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.35), -np.sin(0.35)],
                     [0.0, np.sin(0.35), np.cos(0.35)]])  # 20 degrees off
    score = score_pairs([(0, 1, true), (1, 2, tilt @ true), (0, 2, true.T)], c2w)
    assert (score.right, score.wrong) == (1, 2)
    assert score.errors_deg[0] == pytest.approx(0.0, abs=1e-6)
    assert score.errors_deg[1] == pytest.approx(20.05, abs=0.1)


def test_a_row_counts_the_pairs_the_cameras_stage_uses() -> None:
    from cadnerf_core.cameras.matches import PairMatch

    c2w = _ring([0.0, 45.0, 90.0])

    def pair(i: int, j: int, R: np.ndarray) -> PairMatch:
        return PairMatch(i, j, 100, 100, 0.3, 0.0, R, np.zeros((0, 2, 2)))

    right = pair(0, 1, c2w[1][:3, :3].T @ c2w[0][:3, :3])
    still = pair(0, 2, np.eye(3))  # 90 degrees apart, seen as no turn at all: wrong, far off
    near = pair(1, 2, right.rotation @ np.array(  # 20 degrees off: wrong, but near enough
        [[1.0, 0.0, 0.0], [0.0, np.cos(0.35), -np.sin(0.35)], [0.0, np.sin(0.35), np.cos(0.35)]]))
    capture = Capture("ring", [Path(f"{k}.jpg") for k in range(3)], None, c2w, None)
    row = score_row(capture, [0, 1, 2], c2w, c2w, None, np.ones(3), [right, still, near])
    assert (row["pairs_right"], row["pairs_wrong"]) == (1, 2)
    assert (row["used_right"], row["used_wrong"]) == (1, 1)
    assert "1 / 2 (1 / 1)" in table([{**row, "capture": "ring", "variant": "matches",
                                      "photos": 3}])[2]


def test_the_registered_photos_come_from_the_job_s_log() -> None:
    lines = ["matches: 8 photos, 28 pairs", "mapper: 3 of 8 photos registered",
             "mapper: not used in 1.2 s"]
    assert registered_photos(lines, None) == 3
    assert registered_photos(["mapper: not used in 0.1 s"], None) == 0
    assert registered_photos([], {"start": "mapper", "photos": [0, 1, 2, 3]}) == 4
    assert registered_photos([], None) is None
    assert start_kind({"start": "mapper", "photos": [0, 1]}) == "mapper"
    assert start_kind({"photos": [0, 1], "pairs": 3}) == "fused"
    assert start_kind({"photos": []}) == start_kind(None) == "retrieved"


def test_a_walk_the_other_way_round_is_mirrored_whatever_its_frame() -> None:
    walk = np.stack([orbit_pose(45.0 * k, 20.0, 4.0) for k in range(8)])
    other_way = np.stack([orbit_pose(-45.0 * k, 20.0, 4.0) for k in range(8)])
    assert not mirrored(walk, walk)
    assert mirrored(other_way, walk)
    turned = walk.copy()
    turned[:, :3, :] = np.diag([-1.0, 1.0, -1.0]) @ walk[:, :3, :]  # the same walk, turned
    assert not mirrored(turned, walk)


def test_the_phone_lens_is_about_a_phone_main_camera() -> None:
    assert phone_focal_35mm() == pytest.approx(27.2, abs=0.1)
    assert phone_focal_35mm(90.0, 400, 300) < phone_focal_35mm(40.0, 400, 300)


def test_the_floor_is_a_textured_square_under_the_object() -> None:
    floor = floor_mesh(-0.7, np.random.default_rng(0))
    assert isinstance(floor.visual, TextureVisuals)
    assert np.allclose(floor.vertices[:, 1], -0.7)
    assert floor.visual.uv.shape == (4, 2)
    texture = np.asarray(floor.visual.material.image)
    assert texture.shape == (1024, 1024, 3) and texture.std() > 20


def _row(name: str, variant: str, final: float | None, **extra: object) -> dict[str, object]:
    return {"capture": name, "variant": variant, "model": "m", "kept": 8, "photos": 8,
            "spacing": 44.6, "exif": True, "registered": 3, "pairs_right": 5, "pairs_wrong": 2,
            "start": "fused",
            "retrieved": 30.0, "started": 10.0, "refined": final, "focal": 0.05,
            "psnr": 20.0, "seconds": 100.0, "mirrored": False, **extra}


def test_the_table_states_each_variant_s_median_and_share_over_textured_captures() -> None:
    rows = [_row("dino_ring", "matches", 90.0), _row("a", "matches", 2.0),
            _row("b", "matches", 14.0, mirrored=True), _row("a", "silhouettes", 30.0)]
    lines = table(rows)
    assert len([line for line in lines if line.startswith("| ")]) == 1 + len(rows)
    assert ("| a | matches | m | 8/8 | 45 | yes | 3/8 | 5 / 2 | fused | 30.0 | 10.0 | **2.0** | "
            "no | +5 % | 20.00 | 100 |") in lines
    assert ("- matches: median refined rotation error over the 2 textured captures "
            "**8.0 deg**; within 10 deg: 1 of 2 (50 %); mirrored walks: 1.") in lines
    assert any(line.startswith("- silhouettes: median refined rotation error over the 1 "
                               "textured captures **30.0 deg**") for line in lines)


def test_without_training_the_table_scores_the_started_cameras() -> None:
    rows = [_row("a", "matches", None, started=4.0, psnr=None, registered=None),
            _row("a", "silhouettes", None, started=40.0)]
    lines = table(rows)
    assert ("| a | matches | m | 8/8 | 45 | yes | - | 5 / 2 | fused | 30.0 | **4.0** | - | no | "
            "+5 % | - | 100 |") in lines
    assert any(line.startswith("- matches: median started rotation error over the 1 textured "
                               "captures **4.0 deg**") for line in lines)


def test_the_table_names_the_captures_the_matches_left_worse_than_silhouettes() -> None:
    rows = [_row("a", "matches", 3.0), _row("a", "silhouettes", 30.0),
            _row("b", "matches", 12.5), _row("b", "silhouettes", 10.0),
            _row("dino_ring", "matches", 90.0), _row("dino_ring", "silhouettes", 10.0)]
    assert worse_than_silhouettes(rows) == [("b", 2.5)]
    assert table(rows)[-1] == ("- matches worse than silhouettes alone by more than 2 degrees: "
                               "b (+2.5).")
    assert worse_than_silhouettes(rows[:1]) is None

"""The capture benchmark's pieces (``benchmarks.bench_captures``, ``benchmarks.textured_walks``):
reading a capture, the mirrored-walk check, the phone lens, the textured floor, the table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from benchmarks import bench_captures
from benchmarks.bench_captures import load_capture, table
from benchmarks.textured_walks import floor_mesh, mirrored, phone_focal_35mm
from cadnerf_core.cameras.conventions import orbit_pose


def test_a_capture_reads_its_cameras_and_its_masks_when_it_ships_them(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "thing"
    (folder / "images").mkdir(parents=True)
    frames = []
    for k in range(3):
        Image.new("RGB", (8, 6)).save(folder / "images" / f"{k:03d}.jpg")
        frames.append({"image": f"images/{k:03d}.jpg", "c2w": orbit_pose(40.0 * k, 20, 4).tolist(),
                       "K": [[7.0 + k, 0, 4], [0, 7.0, 3], [0, 0, 1]]})
    (folder / "cameras.json").write_text(json.dumps({"frames": frames}))
    monkeypatch.setattr(bench_captures, "CAPTURES", tmp_path)
    capture = load_capture("thing")
    assert [p.name for p in capture.photos] == ["000.jpg", "001.jpg", "002.jpg"]
    assert capture.masks is None  # no masks/ folder: the job makes them
    assert capture.focal is not None and capture.focal.tolist() == [7.0, 8.0, 9.0]
    assert np.allclose(capture.c2w[1], orbit_pose(40.0, 20, 4))
    (folder / "masks").mkdir()
    for k in range(3):
        Image.new("L", (8, 6)).save(folder / "masks" / f"{k:03d}.png")
    assert load_capture("thing").masks == [folder / "masks" / f"{k:03d}.png" for k in range(3)]


def test_a_frame_a_rig_took_upside_down_is_given_upright_with_its_camera_rolled(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "rig"
    (folder / "images").mkdir(parents=True)
    pixels = np.arange(6 * 8 * 3, dtype=np.uint8).reshape(6, 8, 3)
    frames = []
    for k in range(2):
        Image.fromarray(pixels).save(folder / "images" / f"{k:03d}.png")
        frames.append({"image": f"images/{k:03d}.png", "c2w": orbit_pose(40.0 * k, 20, 4).tolist(),
                       "K": [[7.0, 0, 4], [0, 7.0, 3], [0, 0, 1]],
                       "upside_down_by_design": k == 1})
    (folder / "cameras.json").write_text(json.dumps({"frames": frames}))
    monkeypatch.setattr(bench_captures, "CAPTURES", tmp_path)
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
    assert np.allclose(floor.vertices[:, 1], -0.7)
    assert floor.visual.uv.shape == (4, 2)
    texture = np.asarray(floor.visual.material.image)
    assert texture.shape == (1024, 1024, 3) and texture.std() > 20


def test_the_table_states_each_variant_s_median_over_textured_captures() -> None:
    def row(name: str, variant: str, refined: float, flip: bool = False) -> dict[str, object]:
        return {"capture": name, "variant": variant, "model": "m", "kept": 8, "photos": 8,
                "retrieved": 30.0, "started": 10.0, "refined": refined, "focal": 0.05,
                "psnr": 20.0, "pairs": 7, "fused": 8, "seconds": 100.0, "mirrored": flip}
    rows = [row("dino_ring", "matches", 90.0), row("a", "matches", 2.0),
            row("b", "matches", 4.0, flip=True), row("a", "silhouettes", 30.0)]
    lines = table(rows)
    assert len([line for line in lines if line.startswith("| ")]) == 1 + len(rows)
    assert "| a | matches | m | 8/8 | 30.0 | 10.0 | **2.0** | no | +5 % | 20.00 | 7 | 8 | 100 |" \
        in lines
    assert any("matches: median refined rotation error over the 2 textured captures **3.0 deg**;"
               " mirrored walks: 1." in line for line in lines)
    assert any("silhouettes: median refined rotation error over the 1 textured captures "
               "**30.0 deg**" in line for line in lines)


def test_the_table_names_the_captures_the_matches_left_worse_than_silhouettes() -> None:
    def row(name: str, variant: str, refined: float) -> dict[str, object]:
        return {"capture": name, "variant": variant, "model": "m", "kept": 8, "photos": 8,
                "retrieved": 30.0, "started": 20.0, "refined": refined, "focal": None,
                "psnr": 20.0, "seconds": 100.0, "pairs": 3, "fused": 2}

    rows = [row("a", "matches", 3.0), row("a", "silhouettes", 30.0),
            row("b", "matches", 12.5), row("b", "silhouettes", 10.0),
            row("dino_ring", "matches", 90.0), row("dino_ring", "silhouettes", 10.0)]
    assert bench_captures.worse_than_silhouettes(rows) == [("b", 2.5)]
    assert table(rows)[-1] == ("- matches worse than silhouettes alone by more than 2 degrees: "
                               "b (+2.5).")
    assert bench_captures.worse_than_silhouettes(rows[:1]) is None

"""Synthetic datasets: rendering, the files written, reading them back (and NeRF-synthetic)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from typer.testing import CliRunner

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose, to_transforms_json
from cadnerf_core.evaluation.dataset import load_dataset, render_dataset, walking_angles

EVAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "eval"
SPOT = EVAL / "meshes" / "spot" / "spot_triangulated.obj"


def _expected_poses(meta: dict, prefix: str = "") -> np.ndarray:
    angles = zip(meta[f"{prefix}azimuths"], meta[f"{prefix}elevations"], strict=True)
    return np.stack([orbit_pose(az, el, meta["distance"]) for az, el in angles])


@pytest.fixture()
def box_path(tmp_path: Path) -> Path:
    box = trimesh.creation.box((1.0, 0.6, 0.4))
    box.visual.face_colors = (200, 30, 30, 255)
    path = tmp_path / "box.ply"
    box.export(path)
    return path


def test_box_dataset_files_poses_and_test_split(box_path: Path, tmp_path: Path) -> None:
    out = render_dataset(box_path, tmp_path / "ds", n_views=5, size=32, seed=3, test_views=2)
    meta = json.loads((out / "dataset.json").read_text())
    assert meta["seed"] == 3 and meta["direction"] in (-1, 1)
    data = load_dataset(out)
    assert data.images.shape == (5, 32, 32, 3) and data.images.dtype == np.float32
    assert data.masks.shape == (5, 32, 32) and data.masks.dtype == bool
    assert data.names == ["000", "001", "002", "003", "004"]
    assert np.allclose(data.c2w, _expected_poses(meta), atol=1e-9)
    np.testing.assert_allclose(data.K, np.broadcast_to(intrinsics_from_fov(40.0, 32), (5, 3, 3)))
    with Image.open(out / "images" / "000.png") as image:
        assert image.mode == "RGBA"
        alpha = np.asarray(image)[..., 3] > 127
    with Image.open(out / "masks" / "000.png") as mask:
        assert np.array_equal(np.asarray(mask) > 127, alpha)
    assert np.array_equal(alpha, data.masks[0])
    assert (data.images[~data.masks] == 1.0).all()  # composited on white
    inside = data.images[data.masks]
    assert (inside[:, 0] > inside[:, 1] + 0.2).all()  # the box's red survives shading
    fill = [max(np.ptp(np.nonzero(m)[0]), np.ptp(np.nonzero(m)[1])) + 1 for m in data.masks]
    assert 0.55 * 32 <= max(fill) <= 0.85 * 32  # auto distance: the object fills ~72%
    assert data.test is not None and data.test.images.shape == (2, 32, 32, 3)
    assert np.allclose(data.test.c2w, _expected_poses(meta, "test_"), atol=1e-9)
    assert (out / "test" / "masks" / "001.png").is_file()


def test_walking_angles_go_round_once_in_the_direction() -> None:
    rng = np.random.default_rng(0)
    for direction in (1, -1):
        azimuths, elevations = walking_angles(10, rng, direction, (10.0, 50.0))
        steps = np.mod(direction * np.diff(azimuths), 360.0)
        assert ((steps > 20.0) & (steps < 52.0)).all()  # 36 degrees +- jitter
        assert ((elevations >= 10.0) & (elevations <= 50.0)).all()
        assert elevations.std() > 1.0


def test_same_seed_same_dataset(box_path: Path, tmp_path: Path) -> None:
    a = render_dataset(box_path, tmp_path / "a", n_views=3, size=16, seed=7)
    b = render_dataset(box_path, tmp_path / "b", n_views=3, size=16, seed=7)
    assert (a / "transforms.json").read_text() == (b / "transforms.json").read_text()


def test_load_dataset_reads_a_nerf_synthetic_folder(tmp_path: Path) -> None:
    (tmp_path / "train").mkdir()
    c2w = np.stack([orbit_pose(a, 20.0, 3.0) for a in (0.0, 90.0)])
    K = intrinsics_from_fov(50.0, 16)
    data = to_transforms_json(c2w, K, 16, 16, ["./train/r_0", "./train/r_1"])
    for frame in data["frames"]:  # Blender scenes have only camera_angle_x
        for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            del frame[key]
    (tmp_path / "transforms_train.json").write_text(json.dumps(data))
    rgba = np.zeros((16, 16, 4), dtype=np.uint8)
    rgba[4:12, 4:12] = (0, 0, 255, 255)
    for i in range(2):
        Image.fromarray(rgba).save(tmp_path / "train" / f"r_{i}.png")
    loaded = load_dataset(tmp_path)
    assert loaded.names == ["r_0", "r_1"] and loaded.test is None
    assert np.allclose(loaded.c2w, c2w, atol=1e-12)
    np.testing.assert_allclose(loaded.K[0], K, atol=1e-9)
    assert loaded.masks[0].sum() == 64
    np.testing.assert_allclose(loaded.images[0, 0, 0], [1.0, 1.0, 1.0])
    np.testing.assert_allclose(loaded.images[0, 8, 8], [0.0, 0.0, 1.0])


def test_cli_writes_a_dataset_and_reports_bad_meshes(box_path: Path, tmp_path: Path) -> None:
    from cadnerf_cli.main import app

    runner = CliRunner()
    ok = runner.invoke(app, ["render-dataset", str(box_path), "--out", str(tmp_path / "cli"),
                             "--views", "3", "--size", "16", "--seed", "1", "--test-views", "1"])
    assert ok.exit_code == 0, ok.output
    assert str(tmp_path / "cli") in ok.output
    assert (tmp_path / "cli" / "transforms_test.json").is_file()
    bad = tmp_path / "broken.obj"
    bad.write_text("this is not an obj file\n")
    failed = runner.invoke(app, ["render-dataset", str(bad), "--out", str(tmp_path / "x")])
    assert failed.exit_code == 2
    assert "broken.obj" in failed.output and "Traceback" not in failed.output
    assert not (tmp_path / "x").exists()


@pytest.mark.skipif(not SPOT.is_file(), reason="shared eval meshes absent")
def test_spot_dataset_is_textured_and_its_poses_round_trip(tmp_path: Path) -> None:
    out = render_dataset(SPOT, tmp_path / "spot", n_views=12, size=128, seed=0)
    meta = json.loads((out / "dataset.json").read_text())
    data = load_dataset(out)
    assert len(list((out / "images").glob("*.png"))) == 12
    assert np.allclose(data.c2w, _expected_poses(meta), atol=1e-9)
    for image, mask in zip(data.images, data.masks, strict=True):
        assert mask.sum() > 0.1 * mask.size
        inside = image[mask]
        assert inside.std(axis=0).mean() > 0.1  # black patches on white: a real texture
        chroma = inside.max(axis=1) - inside.min(axis=1)
        assert chroma.max() > 0.2  # coloured somewhere (nose, horns), not grey

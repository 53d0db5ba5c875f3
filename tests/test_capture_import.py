"""Importing a capture at the users' spacing (``benchmarks.capture_import``) from a source's
reference cameras (``benchmarks.capture_sources``), on sources made in code."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from benchmarks.capture_import import (
    SHRUNK_SIDE,
    find_mask,
    import_capture,
    photo,
    quarter_turns,
    reprojection_px,
    scaled_intrinsics,
    turn_clockwise,
)
from benchmarks.capture_sources import (
    OPENGL_TO_OPENCV,
    Frame,
    SourceTree,
    find_model,
    read_frames,
)
from cadnerf_core.cameras import orbit_pose

WIDTH, HEIGHT = 24, 16
K = np.array([[20.0, 0.0, 11.5], [0.0, 20.0, 7.5], [0.0, 0.0, 1.0]])


def _project(K: np.ndarray, c2w: np.ndarray, point: np.ndarray) -> np.ndarray:
    w2c = np.linalg.inv(c2w)
    p = K @ (w2c[:3, :3] @ point + w2c[:3, 3])
    return np.asarray(p[:2] / p[2])


def test_a_turned_photo_keeps_every_point_where_its_pixels_went() -> None:
    c2w = orbit_pose(30.0, 20.0, 4.0)
    image = np.zeros((HEIGHT, WIDTH), np.uint8)
    point = np.array([0.3, 0.2, -0.1])
    u, v = np.round(_project(K, c2w, point)).astype(int)
    image[v, u] = 255
    turned, c2w_turned, K_turned = turn_clockwise(image, c2w, K)
    assert turned.shape == (WIDTH, HEIGHT)
    u2, v2 = np.round(_project(K_turned, c2w_turned, point)).astype(int)
    assert turned[v2, u2] == 255
    assert np.isclose(np.linalg.det(c2w_turned[:3, :3]), 1.0)


def test_a_photo_taken_sideways_is_turned_so_up_is_its_top() -> None:
    upright = orbit_pose(0.0, 20.0, 4.0)
    assert quarter_turns(upright, np.array([0.0, 1.0, 0.0])) == 0
    sideways = upright.copy()
    sideways[:3, :2] = np.stack([upright[:3, 1], -upright[:3, 0]], axis=1)  # rolled a quarter
    turns = quarter_turns(sideways, np.array([0.0, 1.0, 0.0]))
    c2w, K_turned = sideways, K
    image = np.zeros((HEIGHT, WIDTH))
    for _ in range(turns):
        image, c2w, K_turned = turn_clockwise(image, c2w, K_turned)
    assert np.allclose(c2w[:3, 1], upright[:3, 1])  # its y axis points down the world again


def test_intrinsics_follow_a_resize_with_pixel_centres_at_integers() -> None:
    half = scaled_intrinsics(K, 0.5, 0.5)
    assert half[0, 0] == 10.0 and half[0, 2] == pytest.approx((11.5 + 0.5) * 0.5 - 0.5)


def test_a_mask_is_found_by_its_photo_s_stem() -> None:
    files = ["m/1-removebg-preview.png", "m/10-removebg-preview.png", "m/2.png"]
    assert find_mask(files, "m", "images/1.jpg") == "m/1-removebg-preview.png"
    assert find_mask(files, "m", "images/2.jpg") == "m/2.png"
    assert find_mask(files, "m", "images/3.jpg") is None


def _source(root: Path, frames: int = 40, masks: bool = True) -> Path:
    """A nerfstudio-style capture: a ring of look-at cameras (OpenGL axes), one frame in four
    taken sideways, each photo marking the object's centre."""
    (root / "images").mkdir(parents=True)
    (root / "masks").mkdir()
    entries = []
    for k in range(frames):
        c2w = orbit_pose(360.0 * k / frames, 25.0, 4.0)
        if k % 4 == 1:
            c2w[:3, :2] = np.stack([c2w[:3, 1], -c2w[:3, 0]], axis=1)
        pixels = np.full((HEIGHT, WIDTH, 3), 40, np.uint8)
        u, v = np.round(_project(K, c2w, np.zeros(3))).astype(int)
        pixels[v - 1:v + 2, u - 1:u + 2] = 255
        Image.fromarray(pixels).save(root / "images" / f"f{k:02d}.png")
        if masks:
            Image.fromarray((pixels[..., 0] > 100).astype(np.uint8) * 255).save(
                root / "masks" / f"f{k:02d}.png")
        entries.append({"file_path": f"./images/f{k:02d}.png",
                        "transform_matrix": (c2w @ OPENGL_TO_OPENCV).tolist()})
    (root / "transforms.json").write_text(json.dumps(
        {"fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "w": WIDTH,
         "h": HEIGHT, "k1": 0.01, "frames": entries}))
    return root


def test_a_capture_is_imported_upright_at_the_users_spacing(tmp_path: Path) -> None:
    tree = SourceTree(_source(tmp_path / "source"))
    assert find_model(tree) == "transforms.json"
    frames = read_frames(tree, "transforms.json")
    assert len(frames) == 40 and frames[0].distortion == {"k1": 0.01}
    meta = {"source": "someone/thing", "licence": "CC0", "object": "a dot", "caveats": ""}
    folder = import_capture(tree, "dot", tmp_path / "out", meta, masks="masks")
    cameras = json.loads((folder / "cameras.json").read_text())
    assert len(cameras["frames"]) == 8
    azimuths = [f["azimuth_deg"] for f in cameras["frames"]]
    assert np.allclose(np.diff(azimuths) % 360.0, 45.0, atol=1e-6)
    assert cameras["focal_35mm"] == round(20.0 * np.hypot(36, 24) / np.hypot(WIDTH, HEIGHT))
    for frame in cameras["frames"]:
        image = np.asarray(Image.open(folder / frame["image"]))
        mask = np.asarray(Image.open(folder / frame["mask"]))
        assert image.shape[:2] == (frame["height"], frame["width"]) == mask.shape
        u, v = np.round(_project(np.array(frame["K"]), np.array(frame["c2w"]),
                                 np.zeros(3))).astype(int)
        assert image[v, u, 0] > 150 and mask[v, u] == 255  # the centre is where it was drawn
        assert np.array(frame["c2w"])[1, 1] < 0  # upright: the camera's y points down
    assert "someone/thing" in (folder / "README.md").read_text()


def test_llff_and_middlebury_cameras_read_back_as_written(tmp_path: Path) -> None:
    (tmp_path / "images").mkdir()
    c2w = [orbit_pose(40.0 * k, 10.0, 3.0) for k in range(3)]
    rows = []
    for k, pose in enumerate(c2w):
        Image.new("RGB", (WIDTH, HEIGHT)).save(tmp_path / "images" / f"{k}.jpg")
        llff = np.stack([pose[:3, 1], pose[:3, 0], -pose[:3, 2], pose[:3, 3],
                         [HEIGHT, WIDTH, 20.0]], axis=1)
        rows.append(np.concatenate([llff.ravel(), [1.0, 5.0]]))
    np.save(tmp_path / "poses_bounds.npy", np.stack(rows))
    lines = ["3"] + [f"images/{k}.jpg " + " ".join(
        str(v) for v in [*K.ravel(), *np.linalg.inv(p)[:3, :3].ravel(),
                         *np.linalg.inv(p)[:3, 3]]) for k, p in enumerate(c2w)]
    (tmp_path / "thing_par.txt").write_text("\n".join(lines) + "\n")
    tree = SourceTree(tmp_path)
    for model in ("poses_bounds.npy", "thing_par.txt"):
        frames = read_frames(tree, model)
        assert [f.image for f in frames] == [f"images/{k}.jpg" for k in range(3)]
        assert np.allclose(np.stack([f.c2w for f in frames]), np.stack(c2w), atol=1e-9)
    (tmp_path / "images" / "extra.jpg").write_bytes((tmp_path / "images" / "0.jpg").read_bytes())
    with pytest.raises(ValueError, match="3 poses for 4 images"):
        read_frames(tree, "poses_bounds.npy")


def test_the_source_s_points_reproject_into_a_turned_and_shrunk_photo(tmp_path: Path) -> None:
    width, height = 2400, 1800  # over MAX_SIDE: shrunk to a phone's size
    K_big = np.array([[2000.0, 0.0, 1199.5], [0.0, 2000.0, 899.5], [0.0, 0.0, 1.0]])
    c2w = orbit_pose(10.0, 30.0, 4.0)
    c2w[:3, :2] = np.stack([c2w[:3, 1], -c2w[:3, 0]], axis=1)  # taken sideways
    points = np.random.default_rng(0).uniform(-0.5, 0.5, (20, 3))
    seen = np.array([[*x, *_project(K_big, c2w, x)] for x in points])
    Image.new("RGB", (width, height)).save(tmp_path / "big.jpg")
    frame = Frame("big.jpg", c2w, K_big, width, height, seen=seen)
    rgb, _, c2w_out, K_out, turns, error = photo(SourceTree(tmp_path), frame,
                                                 np.array([0.0, 1.0, 0.0]), None)
    assert turns in (1, 3) and max(rgb.shape[:2]) == SHRUNK_SIDE
    assert error is not None and error < 1e-6
    assert reprojection_px(seen, c2w, K_big) == pytest.approx(0.0, abs=1e-9)

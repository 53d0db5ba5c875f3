"""Artifacts: H.264 video, GIF, marching-cubes mesh as GLB, transforms, atomic writes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cadnerf_core.cameras.conventions import from_transforms_json, intrinsics_from_fov, orbit_pose
from cadnerf_core.export.bundle import nerfstudio_transforms
from cadnerf_core.export.media import gif_durations, write_gif, write_video
from cadnerf_core.export.mesh import extract_mesh
from cadnerf_core.export.renders import orbit_intrinsics, orbit_poses
from cadnerf_core.jobfolder import TRANSFORMS, JobFolder


def _frames(n: int = 6, size: int = 32) -> list[np.ndarray]:
    frames = []
    for i in range(n):
        frame = np.full((size, size, 3), 255, np.uint8)
        frame[:, i * 4:(i + 1) * 4] = (200, 30, 30)
        frames.append(frame)
    return frames


def test_video_is_h264_yuv420p_bt709_faststart_with_every_frame(tmp_path: Path) -> None:
    import subprocess

    import imageio_ffmpeg

    write_video(tmp_path / "orbit.mp4", _frames(), fps=10)
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "orbit.mp4"))
    meta = next(reader)
    assert meta["codec"].startswith("h264") and "yuv420p" in meta["pix_fmt"]
    assert meta["size"] == (32, 32) and len(list(reader)) == 6
    assert not [p for p in tmp_path.iterdir() if p.name != "orbit.mp4"]  # no temporary left
    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i",
                            str(tmp_path / "orbit.mp4")], capture_output=True, text=True)
    assert "yuv420p(tv, bt709" in probe.stderr  # range and matrix/primaries/transfer tagged
    data = (tmp_path / "orbit.mp4").read_bytes()
    assert data.index(b"moov") < data.index(b"mdat")  # faststart: the index first


def test_video_colours_survive_the_bt709_round_trip(tmp_path: Path) -> None:
    import imageio_ffmpeg

    frame = np.zeros((32, 32, 3), np.uint8)
    frame[:] = (200, 60, 30)  # a saturated colour: a BT.601/709 mismatch moves it by ~10 levels
    write_video(tmp_path / "orbit.mp4", [frame] * 4, fps=10)
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "orbit.mp4"),
                                        output_params=["-vf", "scale=in_color_matrix=bt709:"
                                                       "in_range=tv"])
    next(reader)
    back = np.frombuffer(next(reader), np.uint8).reshape(32, 32, 3)
    assert np.abs(back[8:24, 8:24].astype(int) - frame[8:24, 8:24]).max() <= 4


def test_gif_loops_as_long_as_the_video(tmp_path: Path) -> None:
    write_gif(tmp_path / "orbit.gif", _frames(), fps=10)
    gif = Image.open(tmp_path / "orbit.gif")
    assert getattr(gif, "n_frames", 1) == 6 and gif.info.get("loop") == 0
    durations = []
    for i in range(6):
        gif.seek(i)
        durations.append(gif.info["duration"])
    assert sum(durations) == 600
    # 30 fps: every other frame kept at 15 fps, delays in whole centiseconds adding to 6 s.
    distinct = [np.full((32, 32, 3), i, np.uint8) for i in range(180)]
    write_gif(tmp_path / "fast.gif", distinct, fps=30)
    fast = Image.open(tmp_path / "fast.gif")
    assert getattr(fast, "n_frames", 1) == 90
    assert sum(gif_durations(90, 15)) == 6000 and set(gif_durations(90, 15)) == {60, 70}


def test_mesh_from_a_sphere_occupancy() -> None:
    G = 40
    axis = np.linspace(-1.1, 1.1, G)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    occ = (np.sqrt(x**2 + y**2 + z**2) < 0.6).astype(np.float32)
    mesh = extract_mesh(occ, 1.1, 0.5)
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert radius.mean() == pytest.approx(0.6, abs=0.04)
    assert mesh.volume > 0  # outward winding
    outward = np.einsum("ij,ij->i", mesh.vertex_normals, mesh.vertices)
    assert (outward > 0).mean() > 0.95


def test_mesh_of_a_constant_field_is_refused() -> None:
    with pytest.raises(ValueError, match="constant"):
        extract_mesh(np.zeros((8, 8, 8)), 1.0, 0.5)


def test_transforms_round_trip_per_photo_sizes(tmp_path: Path) -> None:
    c2w = np.stack([orbit_pose(a, 20.0, 4.0) for a in (0, 120)])
    Ks = [intrinsics_from_fov(40.0, 64), intrinsics_from_fov(50.0, 64)]
    data = nerfstudio_transforms(c2w, Ks, [(64, 64), (64, 64)], ["images/a.png", "images/b.png"],
                                 ["masks/000.png", None])
    assert data["camera_model"] == "OPENCV" and "mask_path" not in data["frames"][1]
    JobFolder(tmp_path).write_transforms(data)
    back_c2w, back_K = from_transforms_json(json.loads(JobFolder(tmp_path).file(TRANSFORMS)
                                                       .read_text()), 64)
    assert np.allclose(back_c2w, c2w) and np.allclose(back_K, np.stack(Ks))


def test_orbit_cameras_look_at_the_object() -> None:
    poses = orbit_poses(8, 20.0, 3.0)
    assert np.allclose(np.linalg.norm(poses[:, :3, 3], axis=1), 3.0)
    forward = poses[:, :3, 2]
    assert np.allclose(np.einsum("ij,ij->i", forward, -poses[:, :3, 3] / 3.0), 1.0)
    K = orbit_intrinsics(np.stack([intrinsics_from_fov(40.0, 64)] * 2), 64, 128)
    assert K[0, 2] == 64.0 and K[0, 0] == pytest.approx(2 * intrinsics_from_fov(40.0, 64)[0, 0])

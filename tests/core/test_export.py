"""Artifacts: H.264 video, GIF, marching-cubes mesh as GLB, transforms, atomic writes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from cadnerf_core.cameras import from_transforms_json, intrinsics_from_fov, orbit_pose
from cadnerf_core.export.artifacts import (
    extract_mesh,
    orbit_intrinsics,
    orbit_poses,
    transforms_json,
    write_gif,
    write_mesh,
    write_video,
)
from cadnerf_core.jobfolder import TRANSFORMS, JobFolder


def _frames(n: int = 6, size: int = 32) -> list[np.ndarray]:
    frames = []
    for i in range(n):
        frame = np.full((size, size, 3), 255, np.uint8)
        frame[:, i * 4:(i + 1) * 4] = (200, 30, 30)
        frames.append(frame)
    return frames


def test_video_is_h264_yuv420p_with_every_frame(tmp_path: Path) -> None:
    import imageio_ffmpeg

    write_video(tmp_path / "orbit.mp4", _frames(), fps=10)
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "orbit.mp4"))
    meta = next(reader)
    assert meta["codec"].startswith("h264") and "yuv420p" in meta["pix_fmt"]
    assert meta["size"] == (32, 32) and len(list(reader)) == 6
    assert not [p for p in tmp_path.iterdir() if p.name != "orbit.mp4"]  # no temporary left


def test_gif_loops_through_every_frame(tmp_path: Path) -> None:
    write_gif(tmp_path / "orbit.gif", _frames(), fps=10)
    gif = Image.open(tmp_path / "orbit.gif")
    assert getattr(gif, "n_frames", 1) == 6 and gif.info.get("loop") == 0


def test_mesh_from_a_sphere_occupancy(tmp_path: Path) -> None:
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
    write_mesh(tmp_path / "mesh.glb", mesh, np.full((len(mesh.vertices), 3), 0.5))
    loaded = trimesh.load(tmp_path / "mesh.glb", force="mesh")
    assert isinstance(loaded, trimesh.Trimesh)
    assert len(loaded.faces) == len(mesh.faces)
    visual = loaded.visual
    assert isinstance(visual, trimesh.visual.ColorVisuals)
    assert visual.vertex_colors[:, :3].mean() == pytest.approx(128, abs=1)


def test_mesh_of_a_constant_field_is_refused() -> None:
    with pytest.raises(ValueError, match="constant"):
        extract_mesh(np.zeros((8, 8, 8)), 1.0, 0.5)


def test_transforms_round_trip_per_photo_sizes(tmp_path: Path) -> None:
    c2w = np.stack([orbit_pose(a, 20.0, 4.0) for a in (0, 120)])
    Ks = [intrinsics_from_fov(40.0, 64), intrinsics_from_fov(50.0, 64)]
    data = transforms_json(c2w, Ks, [(64, 64), (64, 64)], ["inputs/a.png", "inputs/b.png"])
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

"""Rendered outputs: views at the photos' poses and at new poses, and the orbit.

Everything a person looks at is rendered at the preset's output size (``export.orbit_size``),
whatever the training resolution: the field is continuous, so a larger render is sharper, not
just bigger. The training-view scores are still taken at the training size, against the crops
the NeRF was fitted to.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cadnerf_core.cameras.conventions import look_at, spherical_position
from cadnerf_core.export.media import to_uint8, write_gif, write_png, write_video
from cadnerf_core.jobfolder import ORBIT_GIF, ORBIT_VIDEO, JobFolder
from cadnerf_core.progress import Progress

if TYPE_CHECKING:
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.nerf.state import TrainData

NOVEL_ELEVATION_OFFSET = 10.0
"""New views sit this many degrees above the orbit, so they show what the orbit does not."""

NOVEL_START_DEG = 45.0
"""Azimuth of the first new view: halfway between the library's front and side views."""


def orbit_poses(n: int, elevation_deg: float, distance: float,
                start_deg: float = 0.0) -> np.ndarray:
    """``n`` cameras on a circle around the origin, looking at it. Returns [n, 4, 4]."""
    return np.stack([look_at(spherical_position(start_deg + 360.0 * i / n, elevation_deg,
                                                distance)) for i in range(n)])


def orbit_intrinsics(K_train: np.ndarray, train_size: int, size: int) -> np.ndarray:
    """A centred camera with the training crops' mean focal length, at ``size`` pixels.

    Args:
        K_train: [N, 3, 3] intrinsics of the training crops (``train_size`` pixels).
    Returns:
        K: [3, 3].
    """
    focal = float(np.mean(K_train[:, 0, 0])) * size / train_size
    return np.array([[focal, 0.0, size / 2.0], [0.0, focal, size / 2.0], [0.0, 0.0, 1.0]])


def camera_distance(c2w: np.ndarray) -> float:
    """Mean distance of the refined cameras from the object's centre. c2w: [N, 4, 4]."""
    return float(np.mean(np.linalg.norm(c2w[:, :3, 3], axis=-1)))


def novel_cameras(model: TrainedModel, data: TrainData) -> tuple[np.ndarray, np.ndarray]:
    """The new views' poses and intrinsics at the output size.

    Returns:
        c2w [M, 4, 4] (M = ``export.novel_views``), K [3, 3].
    """
    ecfg = model.state.config.export
    K = orbit_intrinsics(data.K.cpu().numpy().astype(np.float64), data.width, ecfg.orbit_size)
    if not ecfg.novel_views:
        return np.zeros((0, 4, 4)), K
    poses = orbit_poses(ecfg.novel_views, ecfg.orbit_elevation + NOVEL_ELEVATION_OFFSET,
                        camera_distance(model.c2w), NOVEL_START_DEG)
    return poses, K


def render_views(job_dir: Path, model: TrainedModel, data: TrainData, progress: Progress,
                 total: int) -> tuple[list[str], list[dict[str, float]]]:
    """views/NNN.png at the output size: the kept photos' views at their refined poses, then
    the new views (``novel_cameras``).

    Returns:
        The written names, and PSNR/SSIM of each photo's render (at the training size) against
        its training crop.
    """
    from cadnerf_core.evaluation.metrics import psnr, ssim

    size = model.state.config.export.orbit_size
    c2w = model.c2w
    K = data.K.cpu().numpy().astype(np.float64)
    scale = np.diag([size / data.width, size / data.width, 1.0])
    novel, K_novel = novel_cameras(model, data)
    gt = data.images.cpu().numpy()
    names: list[str] = []
    scores: list[dict[str, float]] = []
    for i, pose in enumerate([*c2w, *novel]):
        if i < len(c2w):
            rgb, _ = model.render_image(pose, K[i], data.width, data.width)
            scores.append({"psnr": psnr(rgb, gt[i]), "ssim": ssim(rgb, gt[i])})
            if size != data.width:
                rgb, _ = model.render_image(pose, scale @ K[i], size, size)
        else:
            rgb, _ = model.render_image(pose, K_novel, size, size)
        path = JobFolder(job_dir).view_path(i)
        progress.check()  # before any output: a cancelled or deleted job writes nothing more
        write_png(path, rgb)
        names.append(path.relative_to(job_dir).as_posix())
        progress.step("render", i + 1, total)
    return names, scores


def render_orbit(job_dir: Path, model: TrainedModel, data: TrainData, progress: Progress,
                 done: int, total: int) -> list[str]:
    """orbit.mp4 (H.264) and orbit.gif around the object. Returns the written names."""
    ecfg = model.state.config.export
    K = orbit_intrinsics(data.K.cpu().numpy().astype(np.float64), data.width, ecfg.orbit_size)
    frames = []
    poses = orbit_poses(ecfg.orbit_frames, ecfg.orbit_elevation, camera_distance(model.c2w))
    for i, pose in enumerate(poses):
        rgb, _ = model.render_image(pose, K, ecfg.orbit_size, ecfg.orbit_size)
        frames.append(to_uint8(rgb))
        progress.step("render", done + i + 1, total)
    folder = JobFolder(job_dir)
    progress.check()
    write_video(folder.file(ORBIT_VIDEO), frames, ecfg.orbit_fps)
    write_gif(folder.file(ORBIT_GIF), frames, ecfg.orbit_fps)
    return [ORBIT_VIDEO, ORBIT_GIF]

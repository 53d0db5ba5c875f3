"""Everything a user downloads: rendered views, the orbit video and GIF, the mesh, and JSON.

Names and places come from ``cadnerf_core.jobfolder``. Every file is written atomically (a
temporary file beside it, then a rename), so a reader never sees half a file and a killed job
leaves no truncated artifact.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh
from PIL import Image

from cadnerf_core.cameras import look_at, rotation_angle_deg, spherical_position, to_transforms_json
from cadnerf_core.jobfolder import (
    CONFIG,
    LOG,
    MASK_SOURCES,
    MESH,
    METRICS,
    ORBIT_GIF,
    ORBIT_VIDEO,
    POSES,
    RETRIEVAL,
    TRANSFORMS,
    JobFolder,
    atomic_path,
)
from cadnerf_core.progress import Progress

if TYPE_CHECKING:
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.nerf.state import TrainData
    from cadnerf_core.retrieval.result import RetrievalResult


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> uint8."""
    return np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Write an [H, W, 3] float image as PNG, atomically."""
    with atomic_path(path) as tmp:
        Image.fromarray(to_uint8(rgb), "RGB").save(tmp, format="PNG")


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


def write_video(path: Path, frames: Sequence[np.ndarray], fps: int) -> None:
    """H.264 MP4 (yuv420p, moov atom first so browsers start playing at once), atomically.

    Args:
        frames: [H, W, 3] uint8 each, H and W even.
    """
    import imageio_ffmpeg

    height, width = frames[0].shape[:2]
    with atomic_path(path) as tmp:
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (width, height), fps=fps, codec="libx264", pix_fmt_out="yuv420p",
            macro_block_size=2, quality=7, output_params=["-movflags", "+faststart"])
        writer.send(None)
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
        writer.close()


def write_gif(path: Path, frames: Sequence[np.ndarray], fps: int) -> None:
    """Looping animated GIF, atomically. frames: [H, W, 3] uint8 each."""
    images = [Image.fromarray(f, "RGB") for f in frames]
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=max(1, round(1000 / fps)), loop=0)


def extract_mesh(occupancy: np.ndarray, bound: float, level: float) -> trimesh.Trimesh:
    """Marching cubes (scikit-image) on an occupancy grid over [-bound, bound]^3.

    A field that never crosses ``level`` (barely trained) is cut halfway between its extremes
    instead, so there is always a surface unless the field is constant.

    Args:
        occupancy: [G, G, G] values, index order x, y, z.
    Returns:
        The mesh in world coordinates (no colours yet).
    Raises:
        ValueError: the field is constant (nothing to extract).
    """
    from skimage.measure import marching_cubes

    lo, hi = float(occupancy.min()), float(occupancy.max())
    if hi - lo < 1e-6:
        raise ValueError("the density field is constant: no surface to extract")
    if not lo < level < hi:
        level = (lo + hi) / 2.0
    # Pad with empty space so the surface closes at the grid's border.
    padded = np.pad(occupancy, 1, constant_values=min(lo, 0.0))
    G = occupancy.shape[0]
    spacing = 2.0 * bound / (G - 1)
    verts, faces, _, _ = marching_cubes(padded, level=level, spacing=(spacing,) * 3)
    verts = verts - bound - spacing
    # Occupancy grows inward, so scikit-image's triangles face into the object: flip them
    # (vertex normals then follow from the faces).
    return trimesh.Trimesh(vertices=verts, faces=faces[:, ::-1], process=False)


def write_mesh(path: Path, mesh: trimesh.Trimesh, vertex_colors: np.ndarray | None) -> None:
    """Write a GLB (binary glTF) with optional vertex colours [V, 3] in [0, 1], atomically."""
    if vertex_colors is not None:
        rgba = np.concatenate([to_uint8(vertex_colors),
                               np.full((len(vertex_colors), 1), 255, np.uint8)], 1)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=rgba)
    with atomic_path(path) as tmp:
        data = mesh.export(file_type="glb")
        assert isinstance(data, bytes)
        tmp.write_bytes(data)


def transforms_json(c2w: np.ndarray, K_photo: Sequence[np.ndarray],
                    sizes: Sequence[tuple[int, int]], paths: Sequence[str]) -> dict[str, Any]:
    """NeRF-synthetic transforms of the kept photos at their refined poses, in photo pixels.

    Args:
        c2w: [N, 4, 4] refined OpenCV poses; K_photo: N [3, 3] intrinsics in photo pixels;
        sizes: N (width, height); paths: N file paths relative to the job folder.
    """
    out: dict[str, Any] = {}
    for pose, K, (width, height), path in zip(c2w, K_photo, sizes, paths, strict=True):
        one = to_transforms_json(pose[None], np.asarray(K), width, height, [path])
        out.setdefault("camera_angle_x", one["camera_angle_x"])
        out.setdefault("frames", []).extend(one["frames"])
    return out



def render_views(job_dir: Path, model: TrainedModel, data: TrainData, progress: Progress,
                 total: int) -> tuple[list[str], list[dict[str, float]]]:
    """views/NNN.png: the kept photos' views at their refined poses, then new views.

    Returns:
        The written names, and PSNR/SSIM of each photo's render against its training crop.
    """
    from cadnerf_core.evaluation.metrics import psnr, ssim

    cfg = model.state.config
    c2w = model.c2w
    K = data.K.cpu().numpy().astype(np.float64)
    size = data.width
    distance = float(np.mean(np.linalg.norm(c2w[:, :3, 3], axis=-1)))
    novel = orbit_poses(cfg.export.novel_views, cfg.export.orbit_elevation + 10.0, distance, 45.0) \
        if cfg.export.novel_views else np.zeros((0, 4, 4))
    K_novel = orbit_intrinsics(K, size, size)
    names: list[str] = []
    scores: list[dict[str, float]] = []
    gt = data.images.cpu().numpy()
    for i, pose in enumerate([*c2w, *novel]):
        rgb, _ = model.render_image(pose, K[i] if i < len(c2w) else K_novel, size, size)
        path = JobFolder(job_dir).view_path(i)
        progress.check()  # before any output: a cancelled or deleted job writes nothing more
        write_png(path, rgb)
        names.append(path.relative_to(job_dir).as_posix())
        if i < len(c2w):
            scores.append({"psnr": psnr(rgb, gt[i]), "ssim": ssim(rgb, gt[i])})
        progress.step("render", i + 1, total)
    return names, scores


def render_orbit(job_dir: Path, model: TrainedModel, data: TrainData, progress: Progress,
                 done: int, total: int) -> list[str]:
    """orbit.mp4 (H.264) and orbit.gif around the object. Returns the written names."""
    ecfg = model.state.config.export
    c2w = model.c2w
    distance = float(np.mean(np.linalg.norm(c2w[:, :3, 3], axis=-1)))
    K = orbit_intrinsics(data.K.cpu().numpy().astype(np.float64), data.width, ecfg.orbit_size)
    frames = []
    for i, pose in enumerate(orbit_poses(ecfg.orbit_frames, ecfg.orbit_elevation, distance)):
        rgb, _ = model.render_image(pose, K, ecfg.orbit_size, ecfg.orbit_size)
        frames.append(to_uint8(rgb))
        progress.step("render", done + i + 1, total)
    folder = JobFolder(job_dir)
    progress.check()
    write_video(folder.file(ORBIT_VIDEO), frames, ecfg.orbit_fps)
    write_gif(folder.file(ORBIT_GIF), frames, ecfg.orbit_fps)
    return [ORBIT_VIDEO, ORBIT_GIF]


def export_mesh(job_dir: Path, model: TrainedModel, progress: Progress | None = None) -> None:
    """mesh.glb: marching cubes on the learned occupancy, vertex colours from the colour net."""
    cfg = model.state.config
    G, bound = cfg.export.mesh_resolution, cfg.render.bound
    axis = np.linspace(-bound, bound, G, dtype=np.float32)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    check = None if progress is None else progress.check
    values = model.occupancy(points, check=check).reshape(G, G, G)
    mesh = extract_mesh(values, bound, cfg.export.mesh_level)
    normals = np.asarray(mesh.vertex_normals, dtype=np.float32)
    colors = model.colors(np.asarray(mesh.vertices, np.float32), -normals, check=check)
    if progress is not None:
        progress.check()  # before any output: a cancelled or deleted job writes nothing more
    write_mesh(JobFolder(job_dir).file(MESH), mesh, colors)


def poses_json(model: TrainedModel, retrieval: RetrievalResult,
               scales: Sequence[float] | None = None) -> list[dict[str, Any]]:
    """Per photo: name, refined and initial c2w, IoU, discarded, K (crop and photo pixels).

    ``scales``: per photo index, uploaded pixels per working pixel (``Photo.scale``), so that
    ``K_photo`` holds for the photo as uploaded; None: 1.
    """
    from cadnerf_core.intake.crop import uncrop_intrinsics

    refined = dict(zip([m.index for m in retrieval.kept], model.c2w, strict=True))
    out = []
    for m in retrieval.matches:
        pose = refined.get(m.index)
        out.append({"name": m.name, "index": m.index, "discarded": m.discarded, "iou": m.iou,
                    "c2w": None if pose is None else pose.tolist(),
                    "c2w_initial": m.c2w.tolist(), "library_view": m.view,
                    "K_canonical": m.K_canon.tolist(), "canonical_size": m.box.size,
                    "K_photo": _scaled(uncrop_intrinsics(m.K_canon, m.box),
                                       1.0 if scales is None else scales[m.index]).tolist()})
    return out


def _scaled(K: np.ndarray, scale: float) -> np.ndarray:
    """Intrinsics [3, 3] in pixels ``scale`` times larger (focal lengths and principal point)."""
    out = np.array(K, dtype=np.float64)
    out[:2] *= scale
    return out


def metrics_json(model: TrainedModel, retrieval: RetrievalResult,
                 scores: list[dict[str, float]]) -> dict[str, Any]:
    """Training-view PSNR/SSIM per photo, pose change from retrieval, timings, peak memory."""
    kept = retrieval.kept
    init = np.stack([m.c2w for m in kept])
    refined = model.c2w
    rot = rotation_angle_deg(np.swapaxes(init[:, :3, :3], -1, -2) @ refined[:, :3, :3])
    trans = np.linalg.norm(init[:, :3, 3] - refined[:, :3, 3], axis=-1)
    photos = [{"name": m.name, **s, "pose_change_deg": float(r), "pose_change_translation":
               float(t)} for m, s, r, t in zip(kept, scores, rot, trans, strict=True)]
    return {"photos": photos,
            "mean_psnr": float(np.mean([s["psnr"] for s in scores])),
            "mean_ssim": float(np.mean([s["ssim"] for s in scores])),
            "mean_pose_change_deg": float(np.mean(rot)),
            "focal_scale": float(model.extra.get("focal_scale", 1.0)),
            "timings_s": model.extra.get("timings", {}),
            "peak_memory_mb": model.extra.get("memory", {}),
            "resumed_after_phase": model.extra.get("resumed_after_phase", 0),
            "device": str(model.state.device)}


def export_job(job_dir: Path, model: TrainedModel, retrieval: RetrievalResult,
               photos: list[Any], data: TrainData, progress: Progress) -> dict[str, Any]:
    """Write every artifact of a trained job and return the service's summary.

    Args:
        photos: the job's photos (cadnerf_core.intake.photos.Photo), for their pixel sizes as
            uploaded (working size times ``scale``).
    """
    import time

    start = time.perf_counter()
    ecfg = model.state.config.export
    n_views = data.n_images + ecfg.novel_views
    total = n_views + ecfg.orbit_frames
    views, scores = render_views(job_dir, model, data, progress, total)
    artifacts = views + render_orbit(job_dir, model, data, progress, n_views, total)
    progress.step("export", 1, 3)
    export_mesh(job_dir, model, progress)
    progress.step("export", 2, 3)
    kept = retrieval.kept
    scales = [float(p.scale) for p in photos]
    sizes = [photos[m.index].size for m in kept]
    poses = poses_json(model, retrieval, scales)
    folder = JobFolder(job_dir)
    progress.check()
    folder.write_poses(retrieval.model_id, poses)
    K_photo = [np.asarray(p["K_photo"]) for p in poses if not p["discarded"]]
    folder.write_transforms(transforms_json(model.c2w, K_photo, sizes,
                                            [folder.photo_ref(m.name) for m in kept]))
    model.extra.setdefault("timings", {})["export_s"] = time.perf_counter() - start
    metrics = metrics_json(model, retrieval, scores)
    progress.check()
    folder.write_metrics(metrics)
    progress.step("export", 3, 3)
    artifacts += [MESH, POSES, TRANSFORMS, METRICS, RETRIEVAL, MASK_SOURCES, CONFIG, LOG]
    psnr_by_name = {p["name"]: p for p in metrics["photos"]}
    return {"model_id": retrieval.model_id, "category": retrieval.category,
            "photos": [{"name": p["name"], "iou": p["iou"], "discarded": p["discarded"],
                        "c2w": p["c2w"], "psnr": psnr_by_name.get(p["name"], {}).get("psnr")}
                       for p in poses],
            "metrics": {k: v for k, v in metrics.items() if k != "photos"},
            "artifacts": artifacts}

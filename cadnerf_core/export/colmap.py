"""A COLMAP text model (``cameras.txt``, ``images.txt``, ``points3D.txt``) of the refined cameras.

Pose-free tools (Gaussian splatting, nerfstudio's COLMAP parser, COLMAP itself) start from this
layout: ``images/`` beside ``sparse/0/``. COLMAP's cameras use OpenCV axes and pixel centres at
+0.5, as ours do, so the poses are only inverted (world-to-camera) and written as quaternions.
Each camera is ``PINHOLE`` in its photo's pixels (no distortion is estimated). The 3D points are
sampled on the textured mesh, coloured from its texture, and observed by the cameras that see
them (projected inside the image and not hidden by the mesh).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from cadnerf_core.export.texture import TexturedMesh

POINTS = 5000
"""Points sampled on the mesh for ``points3D.txt`` (enough to seed a splatting run)."""

VISIBLE_TOLERANCE = 1e-3
"""How much nearer than a point (world units) the first hit may be and still count as it."""


@dataclass(frozen=True)
class ColmapCamera:
    """One registered photo: its file name under ``images/``, pose and intrinsics."""

    name: str
    c2w: np.ndarray  # [4, 4] OpenCV camera-to-world
    K: np.ndarray  # [3, 3] in photo pixels
    width: int
    height: int


def w2c_quaternion(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's pose of a camera: world-to-camera rotation as a quaternion (w, x, y, z) and
    translation. c2w: [4, 4]. Returns q [4], t [3]."""
    from scipy.spatial.transform import Rotation

    w2c = np.linalg.inv(c2w)
    x, y, z, w = Rotation.from_matrix(w2c[:3, :3]).as_quat()
    q = np.array([w, x, y, z])
    return (q if w >= 0 else -q), w2c[:3, 3]


def sample_points(mesh: TexturedMesh, n: int = POINTS,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the mesh surface (area-weighted) and their texture colours.

    Returns:
        points [n, 3], rgb [n, 3] uint8.
    """
    tri = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    points, face = trimesh.sample.sample_surface(tri, n, seed=seed)
    bary = trimesh.triangles.points_to_barycentric(tri.triangles[face], points)
    uv = np.einsum("nk,nkd->nd", bary, mesh.uv[mesh.faces[face]])
    size = mesh.texture.shape[0]
    col = np.clip((uv[:, 0] * size).astype(int), 0, size - 1)
    row = np.clip(((1.0 - uv[:, 1]) * size).astype(int), 0, size - 1)
    return np.asarray(points), mesh.texture[row, col]


def observations(camera: ColmapCamera, points: np.ndarray,
                 surface: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Which points a camera sees and where: in front, inside the image, first hit on a ray.

    Returns:
        point indices [M], pixel coordinates [M, 2].
    """
    w2c = np.linalg.inv(camera.c2w)
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]
    uvw = cam @ camera.K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = uvw[:, :2] / uvw[:, 2:3]
    inside = ((cam[:, 2] > 1e-6) & (xy[:, 0] >= 0) & (xy[:, 0] < camera.width)
              & (xy[:, 1] >= 0) & (xy[:, 1] < camera.height))
    index = np.flatnonzero(inside)
    if not len(index):
        return index, np.zeros((0, 2))
    origin = camera.c2w[:3, 3]
    offset = points[index] - origin
    distance = np.linalg.norm(offset, axis=1)
    hits, rays, _ = surface.ray.intersects_location(
        np.broadcast_to(origin, offset.shape), offset / distance[:, None], multiple_hits=False)
    first = np.full(len(index), np.inf)
    if len(rays):
        np.minimum.at(first, rays, np.linalg.norm(hits - origin, axis=1))
    seen = first >= distance - VISIBLE_TOLERANCE
    return index[seen], xy[index[seen]]


def colmap_text(cameras: Sequence[ColmapCamera], mesh: TexturedMesh,
                n_points: int = POINTS) -> tuple[str, str, str]:
    """The three files of a COLMAP text model. Returns (cameras, images, points3D) text."""
    points, rgb = sample_points(mesh, n_points)
    surface = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    tracks: list[list[str]] = [[] for _ in range(len(points))]
    cam_lines = ["# Camera list with one line of data per camera:",
                 "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
                 f"# Number of cameras: {len(cameras)}"]
    img_lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
                 "#   POINTS2D[] as (X, Y, POINT3D_ID)",
                 f"# Number of images: {len(cameras)}"]
    for i, camera in enumerate(cameras, start=1):
        K = camera.K
        cam_lines.append(f"{i} PINHOLE {camera.width} {camera.height} "
                         f"{K[0, 0]:.10g} {K[1, 1]:.10g} {K[0, 2]:.10g} {K[1, 2]:.10g}")
        q, t = w2c_quaternion(camera.c2w)
        img_lines.append(f"{i} {' '.join(f'{v:.12g}' for v in (*q, *t))} {i} {camera.name}")
        seen, xy = observations(camera, points, surface)
        img_lines.append(" ".join(f"{x:.3f} {y:.3f} {p + 1}" for p, (x, y) in zip(seen, xy,
                                                                                   strict=True)))
        for k, p in enumerate(seen):
            tracks[p].append(f"{i} {k}")
    pt_lines = ["# 3D point list with one line of data per point:",
                "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
                f"# Number of points: {len(points)}"]
    for p, (xyz, colour) in enumerate(zip(points, rgb, strict=True)):
        pt_lines.append(f"{p + 1} {xyz[0]:.6f} {xyz[1]:.6f} {xyz[2]:.6f} "
                        f"{colour[0]} {colour[1]} {colour[2]} 0 {' '.join(tracks[p])}".rstrip())
    return ("\n".join(cam_lines) + "\n", "\n".join(img_lines) + "\n",
            "\n".join(pt_lines) + "\n")


_COLMAP_FOCALS = {"SIMPLE_PINHOLE": 1, "SIMPLE_RADIAL": 1, "RADIAL": 1, "SIMPLE_RADIAL_FISHEYE": 1,
                  "RADIAL_FISHEYE": 1, "PINHOLE": 2, "OPENCV": 2, "OPENCV_FISHEYE": 2,
                  "FULL_OPENCV": 2, "FOV": 2, "THIN_PRISM_FISHEYE": 2}
"""COLMAP's camera models by how many focal lengths lead their parameters (then cx, cy; any
distortion after them is not rendered)."""


def _colmap_intrinsics(line: str) -> tuple[int, np.ndarray, int, int]:
    """One ``cameras.txt`` line: camera id, K [3, 3], width, height."""
    parts = line.split()
    model, width, height = parts[1], int(parts[2]), int(parts[3])
    if model not in _COLMAP_FOCALS:
        raise ValueError(f"unknown COLMAP camera model {model!r}")
    params = [float(v) for v in parts[4:]]
    focals = _COLMAP_FOCALS[model]
    fx, fy = params[0], params[focals - 1]
    cx, cy = params[focals], params[focals + 1]
    return int(parts[0]), np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), width, height


def read_colmap_text(cameras_text: str, images_text: str) -> list[ColmapCamera]:
    """The registered images of a COLMAP text model (``cameras.txt``, ``images.txt``).

    Args:
        cameras_text, images_text: the two files' text.
    Returns:
        One camera per image, in the file's order (``name`` as the file gives it).
    Raises:
        ValueError: a line that does not parse, or an image of a camera not listed.
    """
    from scipy.spatial.transform import Rotation

    intrinsics = {}
    for line in cameras_text.splitlines():
        if line.strip() and not line.startswith("#"):
            cam_id, K, width, height = _colmap_intrinsics(line)
            intrinsics[cam_id] = (K, width, height)
    lines = [line for line in images_text.splitlines() if not line.startswith("#")]
    out, i = [], 0
    while i < len(lines):
        if not lines[i].strip():
            i += 1
            continue
        parts = lines[i].split()  # IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME; points next
        qw, qx, qy, qz, tx, ty, tz = (float(v) for v in parts[1:8])
        if int(parts[8]) not in intrinsics:
            raise ValueError(f"image {parts[9]!r} names camera {parts[8]}, which is not listed")
        K, width, height = intrinsics[int(parts[8])]
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        w2c[:3, 3] = (tx, ty, tz)
        out.append(ColmapCamera(" ".join(parts[9:]), np.linalg.inv(w2c), K, width, height))
        i += 2
    return out

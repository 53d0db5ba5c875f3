"""Camera conventions, in one place.

- Pinhole cameras, OpenCV axes: x right, y down, z forward (the camera looks along +z).
- Poses are 4x4 camera-to-world matrices (``c2w``) in a world with +Y up and the object inside
  the unit sphere at the origin. ``w2c`` is its inverse.
- Azimuth 0 puts the camera on the +Z axis (the object's front); azimuth grows counter-clockwise
  seen from above (toward +X). Elevation is positive above the equator.
- The NeRF-synthetic ``transforms.json`` uses OpenGL camera axes (y up, z backward):
  ``c2w_gl = c2w_cv @ diag(1, -1, -1, 1)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # torch is imported lazily: most users of this module never need it.
    import torch

# OpenCV <-> OpenGL camera axes (its own inverse).
CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def intrinsics_from_fov(fov_x_deg: float, width: int, height: int | None = None) -> np.ndarray:
    """Intrinsics of a centred pinhole camera with square pixels.

    Args:
        fov_x_deg: horizontal field of view in degrees.
        width: image width in pixels.
        height: image height in pixels (defaults to ``width``).
    Returns:
        K: [3, 3] float64.
    """
    height = width if height is None else height
    focal = 0.5 * width / math.tan(0.5 * math.radians(fov_x_deg))
    return np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])


def scale_focal(K: np.ndarray, factor: float) -> np.ndarray:
    """``K`` [3, 3] with its focal lengths times ``factor``, the principal point kept."""
    out = np.array(K, dtype=np.float64, copy=True)
    out[0, 0] *= factor
    out[1, 1] *= factor
    return out


def fov_from_intrinsics(K: np.ndarray, width: int) -> float:
    """Horizontal field of view in radians of ``K`` for an image ``width`` pixels wide."""
    return float(2.0 * math.atan(0.5 * width / K[0, 0]))


def spherical_position(azimuth_deg: float, elevation_deg: float, distance: float) -> np.ndarray:
    """Camera centre on a sphere around the origin. Returns [3]."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return distance * np.array(
        [math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)]
    )


def look_at(eye: np.ndarray, target: np.ndarray | None = None,
            up: np.ndarray | None = None) -> np.ndarray:
    """Camera-to-world pose (OpenCV axes) of a camera at ``eye`` looking at ``target``.

    Args:
        eye: [3] camera centre.
        target: [3] point looked at (origin by default).
        up: [3] world up (+Y by default); straight up or down falls back to +Z as reference.
    Returns:
        c2w: [4, 4] float64.
    """
    eye = np.asarray(eye, dtype=np.float64)
    target = np.zeros(3) if target is None else np.asarray(target, dtype=np.float64)
    up = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, dtype=np.float64)
    forward = target - eye
    forward /= np.linalg.norm(forward)
    if abs(float(np.dot(forward, up))) > 1.0 - 1e-9:
        # Looking straight down or up: any horizontal reference will do; -Z keeps az=0 images
        # upright when seen from above.
        up = np.array([0.0, 0.0, -1.0]) if forward[1] < 0 else np.array([0.0, 0.0, 1.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, eye
    return c2w


def orbit_pose(azimuth_deg: float, elevation_deg: float, distance: float) -> np.ndarray:
    """c2w of a camera on a sphere looking at the origin. Returns [4, 4]."""
    return look_at(spherical_position(azimuth_deg, elevation_deg, distance))


def library_azimuths(n_azimuths: int) -> np.ndarray:
    """The library's azimuths in degrees, evenly spaced from 0. Returns [n_azimuths]."""
    return np.arange(n_azimuths) * (360.0 / n_azimuths)


def library_poses(n_azimuths: int = 36, elevations_deg: Sequence[float] = (0, 15, 30, 45, 60),
                  distance: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """The library pose set: rings of azimuths at a few elevations, azimuth-major.

    Index ``i = a * len(elevations) + e`` is azimuth ``a`` at elevation ``e``.

    Returns:
        c2w: [n_azimuths * n_elevations, 4, 4]; az_el: [n, 2] degrees.
    """
    poses, angles = [], []
    for az in library_azimuths(n_azimuths):
        for el in elevations_deg:
            poses.append(orbit_pose(float(az), float(el), distance))
            angles.append((float(az), float(el)))
    return np.stack(poses), np.array(angles)


def project(points: np.ndarray, K: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Project world points to pixel coordinates. points [N, 3] -> uv [N, 2]."""
    w2c = np.linalg.inv(c2w)
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]
    uv = cam @ K.T
    return uv[:, :2] / uv[:, 2:3]


def to_transforms_json(c2w: np.ndarray, K: np.ndarray, width: int, height: int,
                       file_paths: Sequence[str]) -> dict[str, Any]:
    """NeRF-synthetic ``transforms.json`` content (OpenGL axes) for cameras sharing ``K``.

    Args:
        c2w: [N, 4, 4] OpenCV camera-to-world poses.
        K: [3, 3] shared intrinsics, or [N, 3, 3] per frame (then written per frame too).
        width, height: image size in pixels.
        file_paths: N frame paths, relative to the json file, without or with extension.
    """
    Ks = np.broadcast_to(K, (len(c2w), 3, 3))
    out: dict[str, Any] = {"camera_angle_x": fov_from_intrinsics(Ks[0], width), "frames": []}
    for path, pose, k in zip(file_paths, c2w, Ks, strict=True):
        frame: dict[str, Any] = {"file_path": path,
                                 "transform_matrix": (pose @ CV_TO_GL).tolist()}
        frame.update(fl_x=float(k[0, 0]), fl_y=float(k[1, 1]), cx=float(k[0, 2]),
                     cy=float(k[1, 2]), w=width, h=height)
        out["frames"].append(frame)
    return out


def from_transforms_json(data: dict[str, Any], width: int,
                         height: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read poses and intrinsics from NeRF-synthetic ``transforms.json`` content.

    Per-frame ``fl_x``/``cx`` win over the global ``camera_angle_x`` when present.

    Returns:
        c2w: [N, 4, 4] OpenCV poses; K: [N, 3, 3].
    """
    height = width if height is None else height
    default_K = intrinsics_from_fov(math.degrees(float(data["camera_angle_x"])), width, height)
    poses, Ks = [], []
    for frame in data["frames"]:
        poses.append(np.asarray(frame["transform_matrix"], dtype=np.float64) @ CV_TO_GL)
        K = default_K.copy()
        if "fl_x" in frame:
            K[0, 0], K[1, 1] = frame["fl_x"], frame.get("fl_y", frame["fl_x"])
            K[0, 2], K[1, 2] = frame.get("cx", width / 2), frame.get("cy", height / 2)
        Ks.append(K)
    return np.stack(poses), np.stack(Ks)


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices. v [..., 3] -> [..., 3, 3]."""
    import torch

    zero = torch.zeros_like(v[..., 0])
    return torch.stack([
        torch.stack([zero, -v[..., 2], v[..., 1]], -1),
        torch.stack([v[..., 2], zero, -v[..., 0]], -1),
        torch.stack([-v[..., 1], v[..., 0], zero], -1),
    ], -2)


def axis_angle_to_matrix(rotvec: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula, differentiable at zero. rotvec [..., 3] -> R [..., 3, 3]."""
    import torch

    theta2 = (rotvec * rotvec).sum(-1, keepdim=True)[..., None]  # [..., 1, 1]
    theta = torch.sqrt(theta2 + 1e-12)
    small = theta2 < 1e-8
    # Taylor expansions near zero keep gradients finite.
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / (theta2 + 1e-12))
    K = skew(rotvec)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand_as(K)
    return eye + a * K + b * (K @ K)


def se3_exp(xi: torch.Tensor) -> torch.Tensor:
    """Pose correction from axis-angle rotation and translation, as in NeRF--.

    Args:
        xi: [..., 6] (rotation vector, translation).
    Returns:
        T: [..., 4, 4] with T[:3, :3] = exp(rotvec), T[:3, 3] = translation.
    """
    import torch

    R = axis_angle_to_matrix(xi[..., :3])
    top = torch.cat([R, xi[..., 3:, None]], -1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], -2)


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Angle of rotation matrices in degrees. R [..., 3, 3] -> [...]."""
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) minimising ||dst - (s R src + t)||^2 (Umeyama 1991).

    Args:
        src, dst: [N, 3] corresponding points, N >= 3 (N == 2 still gives scale and a rotation).
    Returns:
        scale, R [3, 3], t [3].
    """
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var_s = (xs**2).sum() / len(src)
    scale = float(np.trace(np.diag(S) @ D) / var_s) if var_s > 0 else 1.0
    t = mu_d - scale * R @ mu_s
    return scale, R, t


def align_poses(c2w_pred: np.ndarray, c2w_gt: np.ndarray) -> np.ndarray:
    """Map predicted poses into the ground truth frame by the similarity of their centres.

    Args:
        c2w_pred, c2w_gt: [N, 4, 4].
    Returns:
        aligned c2w_pred: [N, 4, 4].
    """
    scale, R, t = umeyama(c2w_pred[:, :3, 3], c2w_gt[:, :3, 3])
    out = c2w_pred.copy()
    out[:, :3, :3] = R @ c2w_pred[:, :3, :3]
    out[:, :3, 3] = scale * c2w_pred[:, :3, 3] @ R.T + t
    return out


def pose_errors(c2w_pred: np.ndarray, c2w_gt: np.ndarray,
                align: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (degrees) and translation errors per camera, after similarity alignment.

    This is how BARF and SPARF report pose errors: align the camera centres with Umeyama, then
    compare each rotation (geodesic angle) and centre (Euclidean distance, in the ground truth's
    units).

    Args:
        c2w_pred, c2w_gt: [N, 4, 4].
    Returns:
        rotation_deg [N], translation [N].
    """
    pred = align_poses(c2w_pred, c2w_gt) if align else c2w_pred
    R_rel = np.swapaxes(pred[:, :3, :3], -1, -2) @ c2w_gt[:, :3, :3]
    rot = rotation_angle_deg(R_rel)
    trans = np.linalg.norm(pred[:, :3, 3] - c2w_gt[:, :3, 3], axis=-1)
    return rot, trans

"""The mesh's colour from the photos themselves, as photogrammetry tools texture a mesh.

For every texel (its surface point and normal, ``texture.rasterize_uv``), the photos that see
it: in front of the camera, inside the photo and its mask, facing the camera more than
``MIN_COS``, and not hidden by the mesh (the point's depth against a depth map of the mesh
ray cast from that camera at ``DEPTH_SIDE`` pixels). Each photo that sees it is weighted by
the cosine between the normal and the view ray (to the ``COS_POWER``), by how many of its
pixels the surface covers there (focal length over distance) and by its sharpness there (local
Laplacian energy), the last two relative to the best photo of that texel, and feathered near
the edges of what it sees, so that seams between photos fade. A texel blends its ``BEST_FEW``
best photos, each weighted by how close it comes to the best (``BLEND_RATIO``). The photos'
exposures are matched first: a gain per photo and channel, fitted in log space on texels seen
by several photos against their mean (the median photo keeps gain 1). Each photo is sampled at
its own resolution, bilinearly; texels no photo sees are left to the radiance field.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

if TYPE_CHECKING:
    from cadnerf_core.mesh.renderer import MeshRenderer
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.retrieval.result import RetrievalResult

log = logging.getLogger(__name__)

DEPTH_SIDE = 512
"""Long side in pixels of the depth maps the occlusion test reads."""
DEPTH_TOLERANCE = 0.01
"""A point is hidden when it lies behind the mesh's depth by more than this share of its depth
(plus the depth a slanted surface spans over a depth-map pixel and a half)."""
MIN_COS = 0.15
"""Photos seeing the surface more obliquely than this cosine do not colour it."""
COS_POWER = 2.0
"""Exponent of the view cosine in a photo's weight."""
FEATHER_PX = 8.0
"""Depth-map pixels over which a photo's weight fades to ``MIN_FEATHER`` toward the edges of
what it sees (the mesh's outline, depth jumps, its mask's border)."""
MIN_FEATHER = 0.05
"""A photo's weight at the very edge of what it sees (not 0: it may be the only one)."""
BEST_FEW = 3
"""Photos blended at most per texel."""
BLEND_RATIO = 0.5
"""Photos weighted under this share of a texel's best photo's weight take no part in it."""
SHARP_WINDOW = 7
"""Side in photo pixels of the window of the local Laplacian energy (sharpness)."""
GAIN_SAMPLES = 100_000
"""Texels drawn to fit the photos' exposure gains."""
MIN_SHARED = 20
"""Texels two photos must share for their exposures to be compared."""
GAIN_RANGE = (0.5, 2.0)
"""Bounds of a fitted gain: beyond them the photos disagree for reasons a gain cannot mend."""
CHUNK = 1 << 18
"""Texels per pass over the photos (memory bound)."""


@dataclass(frozen=True)
class PhotoView:
    """One photo with its camera, as the texturing reads it."""

    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1]
    K: np.ndarray  # [3, 3] in this photo's pixels (pixel (i, j) centred at (i + .5, j + .5))
    c2w: np.ndarray  # [4, 4] OpenCV camera-to-world
    mask: np.ndarray | None = None  # [H, W] bool: the object; None: everywhere


@dataclass(frozen=True)
class _Prepared:
    """A photo with the maps its observations read (at depth-map resolution)."""

    view: PhotoView
    w2c: np.ndarray  # [4, 4]
    scale: float  # depth-map pixels per photo pixel
    depth: np.ndarray  # [h, w] float32 camera z of the mesh, inf where no hit
    feather: np.ndarray  # [h, w] float32 in [MIN_FEATHER, 1]
    sharpness: np.ndarray  # [h, w] float32 local Laplacian energy


@dataclass(frozen=True)
class _Observations:
    """What every photo sees of some texels."""

    seen: np.ndarray  # [P, T] bool
    interior: np.ndarray  # [P, T] bool: seen, and away from the edges of what it sees
    weight: np.ndarray  # [P, T] float32 blend weights (rows of unseen texels: 0)
    rgb: np.ndarray  # [P, T, 3] float32 photo colours (0 where unseen)


def photo_views(model: TrainedModel, retrieval: RetrievalResult, photos: Sequence[Any],
                masks: Sequence[np.ndarray | None] | None = None) -> list[PhotoView]:
    """The kept photos with their refined cameras, in their working pixels.

    Args:
        photos: the job's photos (``intake.photos.Photo``: ``rgb`` at working size).
        masks: per photo index, its object mask [H, W] (``Intake.masks``); None: the photos'
            own (``Photo.mask``, possibly None).
    """
    from cadnerf_core.intake.crop import uncrop_intrinsics

    views = []
    for m, c2w in zip(retrieval.kept, model.c2w, strict=True):
        photo = photos[m.index]
        mask = photo.mask if masks is None else masks[m.index]
        views.append(PhotoView(rgb=np.asarray(photo.rgb, np.float32),
                               K=uncrop_intrinsics(m.K_canon, m.box),
                               c2w=np.asarray(c2w, np.float64), mask=mask))
    return views


def _depth_map(renderer: MeshRenderer, view: PhotoView) -> tuple[np.ndarray, float]:
    """The mesh's depth from the photo's camera at ``DEPTH_SIDE`` on the long side.

    Returns depth [h, w] float32 (inf where no hit) and the depth-map pixels per photo pixel.
    """
    height, width = view.rgb.shape[:2]
    scale = min(1.0, DEPTH_SIDE / max(height, width))
    w, h = max(1, round(width * scale)), max(1, round(height * scale))
    K = np.array(view.K, np.float64)
    K[0] *= w / width
    K[1] *= h / height
    result = renderer.render(K, view.c2w, w, h)
    return np.where(result.mask, result.depth, np.inf).astype(np.float32), w / width


def _feather(depth: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Weight factor growing from ``MIN_FEATHER`` at the edges of what a photo sees to 1 at
    ``FEATHER_PX`` from them. depth [h, w] (inf: no hit), mask [H, W] or None -> [h, w]."""
    import cv2
    from scipy.ndimage import distance_transform_edt

    finite = np.isfinite(depth)
    edge = ~finite
    d = np.where(finite, depth, 0.0)
    for axis in (0, 1):
        jump = np.abs(np.diff(d, axis=axis)) > 5.0 * DEPTH_TOLERANCE * np.maximum(
            np.take(d, range(d.shape[axis] - 1), axis=axis), 1e-6)
        pad = [(0, 0), (0, 0)]
        pad[axis] = (0, 1)
        edge |= np.pad(jump, pad)
        pad[axis] = (1, 0)
        edge |= np.pad(jump, pad)
    if mask is not None:
        small = cv2.resize(mask.astype(np.uint8), depth.shape[::-1],
                           interpolation=cv2.INTER_NEAREST)
        edge |= small == 0
    if not edge.any():
        return np.ones(depth.shape, np.float32)
    distance = distance_transform_edt(~edge)
    return np.clip(distance / FEATHER_PX, MIN_FEATHER, 1.0).astype(np.float32)


def _sharpness(rgb: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Local Laplacian energy of a photo, measured at its own resolution and averaged down.

    rgb [H, W, 3] -> [h, w] float32 (``shape`` = (h, w))."""
    import cv2

    gray = np.ascontiguousarray(rgb.mean(axis=2), dtype=np.float32)
    laplacian = cv2.Laplacian(gray, cv2.CV_32F, ksize=3)
    energy = cv2.blur(laplacian * laplacian, (SHARP_WINDOW, SHARP_WINDOW))
    return cv2.resize(energy, shape[::-1], interpolation=cv2.INTER_AREA)


def prepare(renderer: MeshRenderer, view: PhotoView) -> _Prepared:
    """A photo's depth, feather and sharpness maps against the mesh of ``renderer``."""
    depth, scale = _depth_map(renderer, view)
    return _Prepared(view=view, w2c=np.linalg.inv(view.c2w), scale=scale, depth=depth,
                     feather=_feather(depth, view.mask),
                     sharpness=_sharpness(view.rgb, depth.shape))


def _project(prep: _Prepared, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points [T, 3] in photo pixels [T, 2] and their camera depth [T]."""
    # einsum, not @: BLAS is slow on [T, 3] x [3, 3] products and fights other threads.
    cam = np.einsum("td,kd->tk", points, prep.w2c[:3, :3]) + prep.w2c[:3, 3]
    z = cam[:, 2]
    proj = np.einsum("td,kd->tk", cam, np.asarray(prep.view.K, np.float64)[:2])
    return proj / np.where(z > 1e-9, z, 1.0)[:, None], z


def _lookup(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """grid [h, w] at integer pixels (clamped to the grid). Returns [T]."""
    h, w = grid.shape
    return grid[np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)]


def observe(prep: _Prepared, points: np.ndarray,
            normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which texels a photo sees, where, and how well.

    Args:
        points, normals: [T, 3] surface points and unit outward normals (world frame).
    Returns:
        seen [T] bool, pixel [T, 2] (photo pixels, continuous), and the factors [T, 4] of its
        weight: view cosine (to ``COS_POWER``), feather, surface resolution (pixels per world
        unit), sharpness.
    """
    xy, z = _project(prep, points)
    height, width = prep.view.rgb.shape[:2]
    ray = points - prep.view.c2w[:3, 3]
    distance = np.maximum(np.linalg.norm(ray, axis=1), 1e-12)
    cos = -np.einsum("td,td->t", normals, ray) / distance
    seen = (z > 1e-6) & (cos > MIN_COS) & (xy[:, 0] >= 0) & (xy[:, 0] < width) \
        & (xy[:, 1] >= 0) & (xy[:, 1] < height)
    if prep.view.mask is not None:
        seen &= _lookup(prep.view.mask, xy[:, 1].astype(np.int64), xy[:, 0].astype(np.int64))
    small = xy * prep.scale - 0.5
    c0, r0 = np.floor(small[:, 0]).astype(np.int64), np.floor(small[:, 1]).astype(np.int64)
    nearest = np.minimum.reduce([_lookup(prep.depth, r0 + dr, c0 + dc)
                                 for dr in (0, 1) for dc in (0, 1)])
    focal = float(prep.view.K[0, 0]) * prep.scale
    cos_c = np.clip(cos, MIN_COS, 1.0)
    slope = 1.5 * z / focal * np.sqrt(1.0 - cos_c**2) / cos_c
    seen &= z <= nearest + DEPTH_TOLERANCE * z + slope
    rc = (np.round(small[:, 1]).astype(np.int64), np.round(small[:, 0]).astype(np.int64))
    factors = np.stack([cos_c**COS_POWER, _lookup(prep.feather, *rc),
                        float(prep.view.K[0, 0]) / np.maximum(z, 1e-6),
                        _lookup(prep.sharpness, *rc)], 1)
    return seen, xy, factors.astype(np.float32)


def sample(rgb: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear colours of a photo [H, W, 3] at continuous pixels [T, 2] -> [T, 3] float32."""
    import cv2

    n = len(xy)
    if n == 0:
        return np.zeros((0, 3), np.float32)
    cols = 4096
    rows = -(-n // cols)
    flat = np.zeros((rows * cols, 2), np.float32)
    flat[:n] = xy - 0.5  # OpenCV's pixel (i, j) is centred on integer coordinates
    maps = flat.reshape(rows, cols, 2)
    out = cv2.remap(np.ascontiguousarray(rgb, np.float32), maps[..., 0], maps[..., 1],
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:n]


def blend_weights(seen: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """Each photo's share of each texel from its weight factors.

    Args:
        seen: [P, T] bool; factors: [P, T, 4] (``observe``).
    Returns:
        [P, T] float32, rows summing to 1 over the photos of texels some photo sees, else 0.
    """
    f = np.where(seen[..., None], factors, 0.0)
    best = f.max(axis=0, keepdims=True)  # [1, T, 3]
    resolution = f[..., 2] / np.maximum(best[..., 2], 1e-12)
    sharp = (f[..., 3] + 1e-6) / (best[..., 3] + 1e-6)
    weight = np.where(seen, f[..., 0] * f[..., 1] * resolution * np.sqrt(sharp), 0.0)
    if len(weight) > BEST_FEW:
        kth = np.sort(weight, axis=0)[-BEST_FEW]
        weight = np.where(weight >= kth, weight, 0.0)
    top = weight.max(axis=0, keepdims=True)
    share = np.clip((weight / np.maximum(top, 1e-12) - BLEND_RATIO) / (1.0 - BLEND_RATIO),
                    0.0, 1.0) * (weight > 0)
    return (share / np.maximum(share.sum(axis=0, keepdims=True), 1e-12)).astype(np.float32)


def observe_all(preps: Sequence[_Prepared], points: np.ndarray,
                normals: np.ndarray) -> _Observations:
    """Every photo's view of the texels ``points``, ``normals`` [T, 3] (see ``_Observations``)."""
    seen, factors, rgb = [], [], []
    for prep in preps:
        s, xy, f = observe(prep, points, normals)
        colour = np.zeros((len(points), 3), np.float32)
        colour[s] = sample(prep.view.rgb, xy[s])
        seen.append(s)
        factors.append(f)
        rgb.append(colour)
    seen_a, factors_a = np.stack(seen), np.stack(factors)
    return _Observations(seen=seen_a, interior=seen_a & (factors_a[..., 1] >= 1.0),
                         weight=blend_weights(seen_a, factors_a), rgb=np.stack(rgb))


def fit_gains(rgb: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Per photo and channel, the gain that brings its colours to the other photos'.

    In log space: for each pair of photos sharing ``MIN_SHARED`` texels or more, none near
    black or saturated, the median of their log colour differences (robust to texels one of
    them sees at a seam); then the log gains that fit those differences best (least squares,
    each pair weighted by its texels), the median photo's gain set to 1 in each set of photos
    linked by shared texels (a photo sharing none keeps 1).

    Args:
        rgb: [P, T, 3] photo colours; seen: [P, T] bool.
    Returns:
        gains [P, 3] within ``GAIN_RANGE`` (1 for photos sharing no texels with another).
    """
    P = len(rgb)
    ok = seen & (rgb.min(axis=2) > 0.02) & (rgb.max(axis=2) < 0.98)
    logc = np.log(np.maximum(rgb, 1e-6))
    rows, targets, weights = [], [], []
    for i in range(P):
        for j in range(i + 1, P):
            both = ok[i] & ok[j]
            if both.sum() < MIN_SHARED:
                continue
            row = np.zeros(P)
            row[i], row[j] = 1.0, -1.0
            rows.append(row)
            targets.append(np.median(logc[j, both] - logc[i, both], axis=0))
            weights.append(np.sqrt(both.sum()))
    if not rows:
        return np.ones((P, 3), np.float32)
    A = np.array(rows) * np.array(weights)[:, None]
    b = np.array(targets) * np.array(weights)[:, None]
    A, b = np.vstack([A, np.full((1, P), 1e-3)]), np.vstack([b, np.zeros((1, 3))])
    log_gain = np.linalg.lstsq(A, b, rcond=None)[0]  # [P, 3]
    for members in _linked_sets(np.array(rows)):
        log_gain[members] -= np.median(log_gain[members], axis=0)
    lo, hi = GAIN_RANGE
    return np.clip(np.exp(log_gain), lo, hi).astype(np.float32)


def _linked_sets(pairs: np.ndarray) -> list[np.ndarray]:
    """The sets of photos linked by pairs (rows [E, P] with +1 and -1 at a pair's photos),
    each [n] photo indices; photos in no pair form sets of one."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    first, second = pairs.argmax(axis=1), pairs.argmin(axis=1)
    P = pairs.shape[1]
    graph = coo_matrix((np.ones(len(pairs)), (first, second)), shape=(P, P))
    count, labels = connected_components(graph, directed=False)
    return [np.flatnonzero(labels == k) for k in range(count)]


def _gains(preps: Sequence[_Prepared], points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The photos' exposure gains [P, 3] fitted on up to ``GAIN_SAMPLES`` texels [T, 3]."""
    rng = np.random.default_rng(0)
    pick = rng.choice(len(points), min(GAIN_SAMPLES, len(points)), replace=False)
    obs = observe_all(preps, points[pick], normals[pick])
    return fit_gains(obs.rgb, obs.interior)


def photo_colours(mesh: trimesh.Trimesh, views: Sequence[PhotoView], points: np.ndarray,
                  normals: np.ndarray, check: Callable[[], None] | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The colour the photos give surface points, where some photo sees them.

    Args:
        mesh: the surface the points lie on (its depth hides what a photo cannot see).
        views: the photos with their cameras, in the mesh's frame.
        points, normals: [T, 3] surface points and unit outward normals.
        check: called between passes (a cancel raises).
    Returns:
        rgb [T, 3] float32 in [0, 1] (0 where unseen) and seen [T] bool.
    """
    rgb = np.zeros((len(points), 3), np.float32)
    seen = np.zeros(len(points), bool)
    if not views or not len(points):
        return rgb, seen
    from cadnerf_core.mesh.renderer import MeshRenderer

    renderer = MeshRenderer(mesh)
    preps = [prepare(renderer, view) for view in views]
    gains = _gains(preps, points, normals)
    log.info("photo texture: exposure gains %s", np.round(gains, 3).tolist())
    for start in range(0, len(points), CHUNK):
        if check is not None:
            check()
        part = slice(start, start + CHUNK)
        obs = observe_all(preps, points[part], normals[part])
        blended = np.einsum("pt,ptc->tc", obs.weight, obs.rgb * gains[:, None])
        rgb[part] = np.clip(blended, 0.0, 1.0)
        seen[part] = obs.seen.any(axis=0)
    log.info("photo texture: %.1f%% of %d texels seen by a photo", 100 * seen.mean(), len(seen))
    return rgb, seen

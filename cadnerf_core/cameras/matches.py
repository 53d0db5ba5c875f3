"""Points the photos share: features matched between every pair, checked by epipolar geometry.

Silhouettes cannot tell which way round a walk went on an object that looks alike from
mirrored sides (a bottle, a mug, a lamp), but its texture can: a label, a print, wood grain.
Each photo's features are found inside its mask (dilated a little, so features on the outline
count), on a crop of the object's bounding box scaled to ``MatchesConfig.size`` pixels on its
long side, and, with their own share, round it (``MatchesConfig.context``: the table or floor
the object stands on shares points between photos where a polished or plain object has none).
By default they are ALIKED's learned features, matched by LightGlue between the photos the walk
makes close and by mutual nearest descriptors between the others (``cameras.learned``; XFeat
with LighterGlue where asked); SIFT
with Lowe's ratio test (OpenCV, no learned weights) where ``MatchesConfig.method`` asks. Every
pair's matches are checked by RANSAC on the essential matrix with a focal-length estimate; the
surviving inliers give the pair's relative rotation (``cv2.recoverPose``).

Between two photos taken walking round an upright object, that rotation is a turn about the
object's vertical axis: by the walking step, positive when the library azimuth increases
(the camera orbits counter-clockwise seen from above, ``conventions.spherical_position``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from cadnerf_core.cameras.orbit import object_centre, orbit_consistent
from cadnerf_core.config import MatchesConfig
from cadnerf_core.config_matches import MIN_SEARCH_SIDE
from cadnerf_core.intake.crop import mask_bbox

RATIO = 0.8
"""Lowe's ratio test: a match is kept when its nearest descriptor is this much nearer than
the second nearest."""
RANSAC_PROB = 0.999
MAX_FEATURES = 2000
"""Most SIFT features kept per photo (the strongest of each of its 1 + 2 * len(TILTS) images
get an equal share): bounds the cost of matching a pair."""
TILTS = (math.sqrt(2.0), 2.0)
"""Foreshortenings simulated, along each image axis (ASIFT's first two tilts)."""
AGREEMENT = 0.75
"""Share of the consecutive turns that must agree in sign for them to give evidence (one
mismatched pair in four or five is common; a split vote is none)."""
MASK_DILATION = 0.02
"""Share of the crop's long side by which a mask is grown before features are looked for."""


@dataclass(frozen=True)
class Features:
    """One photo's SIFT features: ``points [N, 2]`` in the photo's pixels (float64),
    ``descriptors [N, 128]`` float32, and ``scale``: crop pixels per photo pixel where they
    were found."""

    points: np.ndarray
    descriptors: np.ndarray
    scale: float = 1.0


NO_FEATURES = Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32))


@dataclass(frozen=True)
class PairMatch:
    """The verified matches between photos ``i < j``.

    ``matched``: mutual ratio-test matches; ``inliers``: those the essential matrix keeps;
    ``sampson_px``: their median Sampson error in photo pixels; ``turn_deg``: the turn about
    the vertical axis from photo i to photo j (> 0: azimuth increasing), None when the pair
    has fewer than ``MatchesConfig.min_inliers``; ``rotation [3, 3]``: camera i to camera j
    (OpenCV axes, ``x_j = R @ x_i + t``), None likewise; ``points [K, 2, 2]``: the inliers'
    photo pixels in i and j.
    """

    i: int
    j: int
    matched: int
    inliers: int
    sampson_px: float | None
    turn_deg: float | None
    rotation: np.ndarray | None
    points: np.ndarray

    @property
    def inlier_ratio(self) -> float:
        """Share of the mutual matches the geometry keeps (0 when none were matched)."""
        return self.inliers / self.matched if self.matched else 0.0

    def to_json(self) -> dict[str, Any]:
        """JSON-ready summary (no points)."""
        return {"i": self.i, "j": self.j, "matched": self.matched, "inliers": self.inliers,
                "inlier_ratio": round(self.inlier_ratio, 4),
                "sampson_px": None if self.sampson_px is None else round(self.sampson_px, 3),
                "turn_deg": None if self.turn_deg is None else round(self.turn_deg, 2)}


def _sift(gray: np.ndarray, inside: np.ndarray,
          clear_of: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """SIFT points [N, 2] (pixel centres at integers) and descriptors [N, 128] of one image,
    found where ``inside`` (uint8, 255) is set. ``clear_of`` (uint8, 255 = the object): only
    features whose patch stays off the object are kept (distance to it at least the
    keypoint's size), so an outline seen against a plain background, which moves with the
    view, gives none."""
    share = MAX_FEATURES // (1 + 2 * len(TILTS))
    sift = cv2.SIFT_create(nfeatures=share)  # type: ignore[attr-defined]
    keypoints, descriptors = sift.detectAndCompute(gray, inside)
    if descriptors is None or not keypoints:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    points = np.array([k.pt for k in keypoints], dtype=np.float64)
    if clear_of is not None:
        distance = cv2.distanceTransform(cv2.bitwise_not(clear_of), cv2.DIST_L2, 3)
        rows = np.clip(np.round(points[:, 1]).astype(int), 0, gray.shape[0] - 1)
        cols = np.clip(np.round(points[:, 0]).astype(int), 0, gray.shape[1] - 1)
        keep = distance[rows, cols] >= np.array([k.size for k in keypoints])
        points, descriptors = points[keep], descriptors[keep]
    return points, descriptors


def _tilted(gray: np.ndarray, inside: np.ndarray, tilt: float, axis: int,
            clear_of: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """SIFT features of the image shrunk by ``tilt`` along ``axis`` (0: x, 1: y), as an
    oblique view would show it (ASIFT's simulated tilt, anti-aliased first); points in the
    unshrunk image's pixels. ``clear_of``: as for ``_sift``."""
    sigma = [0.01, 0.01]
    sigma[axis] = 0.8 * math.sqrt(tilt * tilt - 1.0)
    blurred = cv2.GaussianBlur(gray, (0, 0), sigmaX=sigma[0], sigmaY=sigma[1])
    factor = np.ones(2)
    factor[axis] = 1.0 / tilt
    shape = (max(1, round(gray.shape[1] * factor[0])), max(1, round(gray.shape[0] * factor[1])))
    shrunk = None if clear_of is None else cv2.resize(clear_of, shape,
                                                      interpolation=cv2.INTER_NEAREST)
    points, descriptors = _sift(cv2.resize(blurred, shape, interpolation=cv2.INTER_LINEAR),
                                cv2.resize(inside, shape, interpolation=cv2.INTER_NEAREST),
                                shrunk)
    return (points + 0.5) / factor - 0.5, descriptors


def detect(image: np.ndarray, mask: np.ndarray, size: int, context: float = 0.0) -> Features:
    """SIFT features of one photo inside its (slightly grown) mask, from the photo and from
    its copies shrunk horizontally and vertically by each of ``TILTS``; with ``context``, also
    those round the object.

    Walking round an object foreshortens its surfaces across the photo (and a change of
    height, along it): a surface facing one photo is seen obliquely from the next, and
    SIFT alone matches little beyond about 30 degrees of turn. The shrunk copies simulate
    those oblique views (ASIFT's idea, along the two axes that matter rather than every
    direction: a third of its cost).

    Args:
        image: [H, W, 3] float in [0, 1] (or uint8).
        mask: [H, W] bool, non-empty.
        size: long side in pixels of the object's bounding-box crop searched (never enlarged).
        context: share of the box's width and height added on each side, in which features
            outside the mask are found too (``MatchesConfig.context``): on a crop of that
            larger box, also ``size`` pixels on its long side, with their own share of
            ``MAX_FEATURES``, so the object keeps all of its own. 0: the object alone.
    Returns:
        The features, their points in the photo's own pixels; ``scale`` is the object's.
    """
    box = mask_bbox(mask)
    x0, y0, x1, y1 = box
    side = max(x1 - x0, y1 - y0)
    points, descriptors, scale = _features_in(image, mask, box, size, side, outside=False)
    if context > 0:
        height, width = mask.shape
        grow_x, grow_y = round(context * (x1 - x0)), round(context * (y1 - y0))
        grown = (max(0, x0 - grow_x), max(0, y0 - grow_y), min(width, x1 + grow_x),
                 min(height, y1 + grow_y))
        around, described, _ = _features_in(image, mask, grown, size, side, outside=True)
        points = np.concatenate([points, around])
        descriptors = np.concatenate([descriptors, described])
    return Features(points, descriptors, scale)


def _features_in(image: np.ndarray, mask: np.ndarray, box: tuple[int, int, int, int],
                 size: int, object_side: int,
                 outside: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """SIFT features (``_sift`` and ``_tilted``) on the crop ``box`` (x0, y0, x1, y1) of the
    photo shrunk to ``size`` pixels on its long side: inside the mask grown by
    ``MASK_DILATION`` of the object's long side (``object_side``, photo pixels), or
    (``outside``) everywhere else in the crop. Returns points [N, 2]
    in photo pixels, descriptors [N, 128] float32, and the crop's scale."""
    x0, y0, x1, y1 = box
    scale = min(1.0, size / max(x1 - x0, y1 - y0))
    crop = np.ascontiguousarray(image[y0:y1, x0:x1, :3])
    if crop.dtype != np.uint8:  # grey and shrunk before the conversion: a 12 MP crop is slow
        crop = crop.astype(np.float32)
    gray: np.ndarray = cv2.cvtColor(crop, cv2.COLOR_RGB2GRAY)
    inside: np.ndarray = mask[y0:y1, x0:x1].astype(np.uint8) * 255
    shape = (max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale)))
    if scale < 1.0:
        gray = cv2.resize(gray, shape, interpolation=cv2.INTER_AREA)
        inside = cv2.resize(inside, shape, interpolation=cv2.INTER_NEAREST)
    if gray.dtype != np.uint8:
        gray = (np.clip(gray, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    grow = max(1, round(MASK_DILATION * scale * object_side))
    clear_of = inside if outside else None
    inside = cv2.dilate(inside, np.ones((2 * grow + 1, 2 * grow + 1), np.uint8))
    if outside:
        inside = cv2.bitwise_not(inside)
    found = [_sift(gray, inside, clear_of)] + [_tilted(gray, inside, tilt, axis, clear_of)
                                               for tilt in TILTS for axis in (0, 1)]
    points = np.concatenate([p for p, _ in found])
    # Pixel centres: crop pixel c covers photo pixels [c / s, (c + 1) / s).
    points = (points + 0.5) / scale - 0.5 + np.array([x0, y0], dtype=np.float64)
    return points, np.concatenate([d for _, d in found]).astype(np.float32), scale


def _two_nearest(d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of squared distances [N, M] (M >= 2, changed in place): the nearest column and
    whether it passes the ratio test against the second nearest. Returns [N] int64, [N] bool."""
    rows = np.arange(len(d2))
    nearest = d2.argmin(axis=1)
    first = d2[rows, nearest].copy()
    d2[rows, nearest] = np.inf
    return nearest, first < RATIO**2 * d2.min(axis=1)


def mutual_matches(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Descriptor matches passing Lowe's ratio test both ways and agreeing.

    One matrix product gives every squared distance (``|a|^2 + |b|^2 - 2 a.b``), so both
    directions cost one BLAS call: far quicker than a brute-force matcher per direction.

    Args:
        a: [Na, D], b: [Nb, D] descriptors.
    Returns:
        [M, 2] int64 index pairs (into a, into b), by increasing index into a.
    """
    if len(a) < 2 or len(b) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    a = np.asarray(a, dtype=np.float32)
    b = np.asarray(b, dtype=np.float32)
    d2 = (a * a).sum(axis=1)[:, None] + (b * b).sum(axis=1)[None, :] - 2.0 * (a @ b.T)
    backward, backward_ok = _two_nearest(d2.T.copy())
    forward, forward_ok = _two_nearest(d2)
    rows = np.flatnonzero(forward_ok & backward_ok[forward]
                          & (backward[forward] == np.arange(len(a))))
    return np.stack([rows, forward[rows]], axis=1).astype(np.int64)


def sampson_errors(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """Sampson distances of point pairs [N, 2] to the fundamental matrix ``F`` (x_b^T F x_a
    = 0), in the points' units. Returns [N]."""
    ha = np.concatenate([x_a, np.ones((len(x_a), 1))], axis=1)
    hb = np.concatenate([x_b, np.ones((len(x_b), 1))], axis=1)
    fa, fb = ha @ F.T, hb @ F
    num = np.einsum("ni,ni->n", hb, fa) ** 2
    den = fa[:, 0] ** 2 + fa[:, 1] ** 2 + fb[:, 0] ** 2 + fb[:, 1] ** 2
    return np.asarray(np.sqrt(num / np.maximum(den, 1e-18)))


def vertical_turn_deg(R: np.ndarray) -> float:
    """The turn about the object's vertical axis, in degrees, of a relative rotation ``R``
    (camera i to camera j) between photos of an upright object.

    The world's up is about camera i's -y axis, tilted toward -z by the elevation, so the turn
    is the rotation vector's part in camera i's y-z plane: positive about +y (the azimuth of
    ``cameras.spherical_position`` increasing). Its x part (a change of elevation) is left out.
    """
    rotvec = cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel()
    return math.degrees(math.copysign(math.hypot(rotvec[1], rotvec[2]), rotvec[1]))


def verify_pair(i: int, j: int, a: Features, b: Features, K_a: np.ndarray, K_b: np.ndarray,
                config: MatchesConfig,
                centres: tuple[np.ndarray, np.ndarray] | None = None) -> PairMatch:
    """Match two photos' SIFT features (``mutual_matches``) and keep those the essential
    matrix explains (``verify_matches``)."""
    pairs = mutual_matches(a.descriptors, b.descriptors)
    return verify_matches(i, j, a, b, pairs, K_a, K_b, config, centres)


def verify_matches(i: int, j: int, a: Features, b: Features, pairs: np.ndarray,
                   K_a: np.ndarray, K_b: np.ndarray, config: MatchesConfig,
                   centres: tuple[np.ndarray, np.ndarray] | None = None) -> PairMatch:
    """Keep the matches between two photos that the essential matrix explains.

    Args:
        i, j: the photos' indices; a, b: their features.
        pairs: [M, 2] int64 matched feature indices (into a, into b).
        K_a, K_b: [3, 3] their intrinsics in photo pixels (the focal length an estimate).
        config: ``threshold_px`` (RANSAC, in pixels of the searched crops) and ``min_inliers``.
        centres: the photos' object centres (``orbit.object_centre``, photo pixels): a pose
            that does not look at one object from both photos (``orbit.orbit_consistent``)
            gives the pair no rotation, its inliers kept.
    Returns:
        The pair's matches.
    """
    empty = np.zeros((0, 2, 2))
    if len(pairs) < max(8, config.min_inliers):
        return PairMatch(i, j, len(pairs), 0, None, None, None, empty)
    x_a, x_b = a.points[pairs[:, 0]], b.points[pairs[:, 1]]
    n_a = cv2.undistortPoints(x_a.reshape(-1, 1, 2), K_a, None).reshape(-1, 2)
    n_b = cv2.undistortPoints(x_b.reshape(-1, 1, 2), K_b, None).reshape(-1, 2)
    # The threshold is set in the searched crops' pixels: in normalised image units here.
    focal = float(np.mean([K_a[0, 0] * a.scale, K_b[0, 0] * b.scale]))
    threshold = config.threshold_px / focal
    cv2.setRNGSeed(0)  # RANSAC's samples: the same photos give the same answer
    E, inlier = cv2.findEssentialMat(n_a, n_b, np.eye(3), cv2.USAC_MAGSAC, RANSAC_PROB,
                                     threshold)
    if E is None or E.shape != (3, 3):
        return PairMatch(i, j, len(pairs), 0, None, None, None, empty)
    count, R, t, pose_mask = cv2.recoverPose(E, n_a, n_b, np.eye(3), mask=inlier.copy())
    keep = pose_mask.ravel() > 0
    inliers = int(keep.sum())
    F = np.linalg.inv(K_b).T @ E @ np.linalg.inv(K_a)
    sampson = float(np.median(sampson_errors(F, x_a[keep], x_b[keep]))) if inliers else None
    points = np.stack([x_a[keep], x_b[keep]], axis=1)
    if inliers < config.min_inliers or (
            centres is not None and not orbit_consistent(R, t, *centres, K_a, K_b)):
        return PairMatch(i, j, len(pairs), inliers, sampson, None, None, points)
    return PairMatch(i, j, len(pairs), inliers, sampson, vertical_turn_deg(R), R, points)


def too_small(masks: Sequence[np.ndarray], context: float = 0.0) -> list[int]:
    """Indices of the photos ``match_photos`` gives no features for lack of size or object
    (``large_enough``)."""
    return [i for i, mask in enumerate(masks) if not large_enough(mask, context)]


def large_enough(mask: np.ndarray, context: float = 0.0) -> bool:
    """Whether the region of a photo searched for features (its object's bounding box grown by
    ``context`` of its size on each side, within the photo) spans at least ``MIN_SEARCH_SIDE``
    pixels: enough detail to be matched."""
    if not mask.any():
        return False
    x0, y0, x1, y1 = mask_bbox(mask)
    height, width = mask.shape[:2]
    grow_x, grow_y = context * (x1 - x0), context * (y1 - y0)
    side_x = min(width, x1 + grow_x) - max(0, x0 - grow_x)
    side_y = min(height, y1 + grow_y) - max(0, y0 - grow_y)
    return max(side_x, side_y) >= MIN_SEARCH_SIDE


def match_photos(images: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                 intrinsics: Sequence[np.ndarray], config: MatchesConfig,
                 check: Callable[[], None] | None = None) -> list[PairMatch]:
    """Matches between every pair of photos, verified (``verify_matches``): ALIKED (or XFeat)
    features matched by LightGlue (LighterGlue) between the photos the walk makes close and by
    mutual nearest descriptors between the others (``cameras.learned``), or SIFT
    (``config.method``).

    Args:
        images: P photos [H_i, W_i, 3] float in [0, 1]; masks: P [H_i, W_i] bool.
        intrinsics: P [3, 3] intrinsics in photo pixels (focal lengths may be estimates).
        config: the matching settings.
        check: called between photos and between pairs (raises to cancel the job).
    Returns:
        P * (P - 1) / 2 pairs, (0, 1), (0, 2), ... (a photo with no object, or whose searched
        region spans fewer than ``MIN_SEARCH_SIDE`` pixels, gets no features).
    """
    check = check or (lambda: None)
    centres = [object_centre(mask) if mask.any() else np.zeros(2) for mask in masks]
    usable = [large_enough(mask, config.context) for mask in masks]
    if config.method == "sift":
        found = [detect(image, mask, config.size, config.context) if use else NO_FEATURES
                 for image, mask, use in zip(images, masks, usable, strict=True)]
        return [verify_pair(i, j, found[i], found[j], intrinsics[i], intrinsics[j], config,
                            (centres[i], centres[j]))
                for i in range(len(found)) for j in range(i + 1, len(found))]
    from cadnerf_core.cameras import learned

    method = learned.learned_method(config)
    features = []
    for image, mask, use in zip(images, masks, usable, strict=True):
        check()
        features.append(learned.detect(image, mask, config.size, config.context, method,
                                       config.keypoints) if use
                        else learned.CropFeatures(NO_FEATURES.points,
                                                  np.zeros((0, 64), np.float32),
                                                  method=method))
    indices = learned.match_indices(features, learned.close_pairs(len(features)), check)
    return [verify_matches(i, j, features[i], features[j], pairs, intrinsics[i],
                           intrinsics[j], config, (centres[i], centres[j]))
            for (i, j), pairs in indices.items()]


def reindexed(pairs: Sequence[PairMatch], position: Sequence[int]) -> list[PairMatch]:
    """The pairs of photos renumbered: photo k becomes ``position[k]``; a pair whose photos
    swap order is turned round (the turn negated, the rotation inverted, the points swapped)."""
    out = []
    for p in pairs:
        i, j = position[p.i], position[p.j]
        if i < j:
            out.append(dataclasses.replace(p, i=i, j=j))
            continue
        out.append(dataclasses.replace(
            p, i=j, j=i, turn_deg=None if p.turn_deg is None else -p.turn_deg,
            rotation=None if p.rotation is None else p.rotation.T,
            points=p.points[:, ::-1]))
    return out


def inlier_table(pairs: Sequence[PairMatch], n_photos: int) -> np.ndarray:
    """Inliers of every pair as a symmetric [n_photos, n_photos] table (0 on the diagonal).
    A pair whose geometry was not trusted (too few inliers, or no pose looking at one object:
    no ``rotation``) counts none: a few chance matches between the mirrored sides of a plain
    object would pull the order search to a wrong walk."""
    table = np.zeros((n_photos, n_photos))
    for p in pairs:
        shared = p.inliers if p.rotation is not None else 0
        table[p.i, p.j] = table[p.j, p.i] = shared
    return table


def usable_turns(pairs: Sequence[PairMatch], n_photos: int,
                 config: MatchesConfig) -> list[PairMatch]:
    """The consecutive pairs (i, i + 1) whose turn is known and, in size, within
    ``config.turn_range`` times an even step (360 / ``n_photos`` degrees): smaller turns are
    mostly features that travel with the camera, larger ones mismatched repeats."""
    step = 360.0 / max(n_photos, 1)
    low, high = config.turn_range
    return [p for p in pairs if p.j == p.i + 1 and p.turn_deg is not None
            and low * step <= abs(p.turn_deg) <= high * step]


def walk_evidence(pairs: Sequence[PairMatch], n_photos: int, config: MatchesConfig) -> float:
    """Evidence for the walking direction from the turns between consecutive photos.

    The consecutive pairs of ``usable_turns`` vote with their sign. When at least
    ``AGREEMENT`` of the votes agree, the evidence is ``config.evidence_per_pair`` times
    their sum, in the unit of the texture cue (``direction.walk_direction_evidence``):
    > 0 favours increasing azimuth. Returns 0 when no pair votes (a texture-less object) or
    the votes are split.
    """
    signs = [math.copysign(1.0, p.turn_deg) for p in usable_turns(pairs, n_photos, config)
             if p.turn_deg is not None]
    total = float(sum(signs))
    if not signs or (len(signs) + abs(total)) / 2.0 < AGREEMENT * len(signs):
        return 0.0
    return config.evidence_per_pair * total

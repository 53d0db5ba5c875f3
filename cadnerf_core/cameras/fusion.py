"""The retrieved cameras fused with the rotations the photos' matches measured.

Retrieval gives each photo the library view whose silhouette fits best: a camera in the CAD
model's frame, but only as near as the library's views are to each other and as the
silhouettes can tell (a body of revolution's azimuth, a symmetric object's side). The
essential matrix of two photos' verified matches gives their relative rotation to a degree or
two wherever the object has texture. Together: rotation averaging over the matched pairs fixes
every photo's rotation relative to the others, and one rotation, fitted robustly to all the
retrieved cameras at once, anchors that rigid set in the CAD model's frame (each connected set
of at least ``MIN_PHOTOS`` photos on its own). Each photo's error
in retrieval then counts once among all of them instead of being its camera.

Steps: pairs whose rotation lies far from the retrieved cameras' (``prior.PRIOR_DEG``: matched
on repeated print or on highlights that travel with the camera) or disagrees with a triangle of
other pairs (``viewgraph.CYCLE_DEG``) are dropped; each set of photos the remaining pairs
connect, the largest first, is solved by iteratively reweighted chordal averaging
(``average_rotations``) from the rotations its surest pairs chain (``spanning_tree_start``); its
anchor is the robust chordal mean of ``W_i^retrieved A_i^T``
(``anchor``). Each fused camera keeps its retrieved distance to the object's centre and looks at
it, as library cameras do. Photos outside every set keep their retrieved cameras.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from cadnerf_core.cameras.conventions import rotation_angle_deg, scale_focal
from cadnerf_core.cameras.mapper import Mapped
from cadnerf_core.cameras.matches import PairMatch
from cadnerf_core.cameras.prior import plausible
from cadnerf_core.cameras.viewgraph import component, consistent_edges, spanning_tree_start
from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult

log = logging.getLogger(__name__)

ROBUST_DEG = 5.0
"""Scale of the averaging's Cauchy weights: a pair this far off its solution counts half."""
ANCHOR_OUTLIER_DEG = 45.0
"""A retrieved camera this far from the fused set's fit is left out of the anchor (one
retrieved on the wrong side is 90 to 180 degrees off; retrieval's common errors, 10 to 30
degrees, average out best in a plain mean)."""
ITERATIONS = 50
OUTLIER_DEG = 10.0
"""A pair whose rotation the averaged cameras miss by more than this is left out."""
MIN_PHOTOS = 3
"""Fewest photos a connected set of pairs must hold to be fused. Photos 40 degrees and more
apart often fall into several such sets, which the pairs hold together though nothing joins
them: each is fused and anchored by its own retrieved cameras (two photos alone are not: one
pair, which no triangle checks, would move both)."""
FOCAL_FACTORS = tuple(float(f) for f in np.geomspace(0.5, 2.0, 13))
"""Factors on the retrieved focal length tried where no photo's own is known."""
FOCAL_MARGIN_DEG = 1.0
"""How much nearer the retrieved cameras another focal length must fuse them to be taken."""
MAPPED_WEIGHT = 4.0
"""Weight of a relative rotation between two photos the mapper registered (a pair's own is at
most 1): bundle adjusted over every match those photos share, it is the surest edge."""


@dataclass(frozen=True)
class Fusion:
    """What fusing did: ``photos`` moved (kept photos' indices as given), ``pairs`` used,
    ``dropped`` pairs not used (contradicted by triangles or the solve, or in a set too small),
    the median angle in degrees each fused camera moved from its retrieved one (``moved_deg``)
    and the median angle the matches' rotations
    disagree with the fused ones (``residual_deg``); ``focal_factor``: what the retrieved focal
    length was multiplied by (``focal_factor``; 1 where the photos' own is known)."""

    photos: list[int]
    pairs: int
    dropped: int
    moved_deg: float
    residual_deg: float
    focal_factor: float = 1.0
    mapped: tuple[int, ...] = ()
    """Photos whose cameras the mapper registered, joined as one rigid set."""
    implausible: int = 0
    """Pairs left out before the solve, their rotation far from the retrieved cameras'
    (``prior.PRIOR_DEG``)."""
    sets: int = 1
    """Connected sets of photos fused, each anchored by its own retrieved cameras."""

    def to_json(self) -> dict[str, object]:
        """JSON-ready summary."""
        return {"photos": self.photos, "pairs": self.pairs, "dropped": self.dropped,
                "implausible": self.implausible, "sets": self.sets,
                "moved_deg": round(self.moved_deg, 2),
                "residual_deg": round(self.residual_deg, 2),
                "focal_factor": round(self.focal_factor, 4), "mapped": list(self.mapped)}


def project_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation nearest ``M`` [3, 3] in the Frobenius norm."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt))) or 1.0])
    return np.asarray(U @ D @ Vt)


def _angle(R: np.ndarray) -> float:
    return float(rotation_angle_deg(np.asarray(R)[None])[0])


def average_rotations(n: int, edges: dict[tuple[int, int], np.ndarray],
                      weights: dict[tuple[int, int], float],
                      start: np.ndarray) -> np.ndarray:
    """World-to-camera rotations ``W [n, 3, 3]`` with ``W_j ~ R_ij W_i`` on every edge, by
    iteratively reweighted chordal averaging (each photo in turn set to the weighted mean its
    edges give it, Cauchy weights of scale ``ROBUST_DEG``), from ``start`` [n, 3, 3] (its gauge
    is free: only relative rotations are fitted)."""
    W = start.copy()
    for _ in range(ITERATIONS):
        for p in range(n):
            total = np.zeros((3, 3))
            for (i, j), R in edges.items():
                if p not in (i, j):
                    continue
                guess = R.T @ W[j] if p == i else R @ W[i]
                residual = _angle(guess @ W[p].T)
                total += weights[(i, j)] * guess / (1.0 + (residual / ROBUST_DEG) ** 2)
            if np.abs(total).sum() > 0:
                W[p] = project_rotation(total)
    return W


def anchor(relative: np.ndarray, retrieved: np.ndarray) -> np.ndarray:
    """The rotation ``G`` that best carries the rigid set ``relative`` [n, 3, 3] (world-to-camera,
    any gauge) onto the ``retrieved`` [n, 3, 3] (``retrieved_i ~ relative_i G``): their chordal
    mean, leaving out cameras retrieval got wrong (``ANCHOR_OUTLIER_DEG``)."""
    used = np.ones(len(relative), dtype=bool)
    G = np.eye(3)
    for _ in range(ITERATIONS):
        G = project_rotation(np.einsum("nji,njk->ik", relative[used], retrieved[used]))
        residual = rotation_angle_deg(np.swapaxes(relative @ G, 1, 2) @ retrieved)
        inside = residual < ANCHOR_OUTLIER_DEG
        if not inside.any() or np.array_equal(inside, used):
            break
        used = inside
    return G


def scaled_focal(matches: Sequence[PhotoMatch], factor: float) -> list[PhotoMatch]:
    """The matches with their focal lengths times ``factor``."""
    if factor == 1.0:
        return list(matches)
    return [dataclasses.replace(m, K_photo=scale_focal(m.K_photo, factor),
                                K_canon=scale_focal(m.K_canon, factor)) for m in matches]


def moved_to(matches: Sequence[PhotoMatch], cameras: dict[int, np.ndarray]) -> list[PhotoMatch]:
    """The matches with the given photos' cameras (c2w by photo index), their retrieved ones
    kept in ``c2w_retrieved``."""
    return [m if m.index not in cameras
            else dataclasses.replace(m, c2w=cameras[m.index], c2w_retrieved=m.c2w)
            for m in matches]


@dataclass(frozen=True)
class _Solved:
    """One solution: the photos fused (as given), their world-to-camera rotations, the pairs
    used (slots into ``photos``) and how far each camera moved from its retrieved one."""

    photos: list[int]
    rotations: np.ndarray
    used: dict[tuple[int, int], np.ndarray]
    moved: np.ndarray
    dropped: int


def _solve(kept: dict[int, PhotoMatch], edges: dict[tuple[int, int], np.ndarray],
           weights: dict[tuple[int, int], float]) -> _Solved | None:
    """Averaging and anchor of the largest set of photos the pairs triangles do not contradict
    connect; None when it holds fewer than ``MIN_PHOTOS`` photos."""
    good = consistent_edges(edges)
    for _ in range(ITERATIONS):
        photos = component(sorted(kept), sorted(good))
        if len(photos) < MIN_PHOTOS:
            return None
        slot = {photo: k for k, photo in enumerate(photos)}
        pairs = [(i, j) for i, j in sorted(good) if i in slot and j in slot]
        used = {(slot[i], slot[j]): edges[(i, j)] for i, j in pairs}
        used_w = {(slot[i], slot[j]): weights[(i, j)] for i, j in pairs}
        retrieved = np.stack([kept[p].c2w[:3, :3].T for p in photos])  # world-to-camera
        tree = spanning_tree_start(len(photos), used, used_w, retrieved)
        relative = average_rotations(len(photos), used, used_w, tree)
        # Pairs the solution cannot explain are wrong (a symmetric object's other side, a
        # repeated print): left out, and the rest solved again.
        wrong = {(i, j) for i, j in pairs
                 if _angle(edges[(i, j)] @ relative[slot[i]] @ relative[slot[j]].T)
                 > OUTLIER_DEG}
        if not wrong:
            break
        good -= wrong
    else:
        return None
    fused = relative @ anchor(relative, retrieved)
    moved = rotation_angle_deg(np.swapaxes(fused, 1, 2) @ retrieved)
    return _Solved(photos, fused, used, moved, len(edges) - len(pairs))


def _every_set(kept: dict[int, PhotoMatch], edges: dict[tuple[int, int], np.ndarray],
               weights: dict[tuple[int, int], float]) -> list[_Solved]:
    """``_solve`` on the largest connected set, then on each further set of the photos left,
    largest first, while one holds ``MIN_PHOTOS``."""
    solutions: list[_Solved] = []
    taken: set[int] = set()
    while True:
        rest = {p: m for p, m in kept.items() if p not in taken}
        among = {e: R for e, R in edges.items() if e[0] in rest and e[1] in rest}
        if not among:
            return solutions
        solved = _solve(rest, among, weights)
        if solved is None:
            return solutions
        solutions.append(solved)
        taken |= set(solved.photos)


def _fundamentals(pairs: Sequence[PairMatch]) -> dict[tuple[int, int], np.ndarray]:
    """The fundamental matrix of each pair with a rotation, fitted to its inliers (least
    median of squares; they are verified already)."""
    out = {}
    for p in pairs:
        if p.rotation is None or len(p.points) < 8:
            continue
        F, _ = cv2.findFundamentalMat(p.points[:, 0], p.points[:, 1], cv2.FM_LMEDS)
        if F is not None and F.shape == (3, 3):
            out[(p.i, p.j)] = F
    return out


def _rotations_at(pairs: Sequence[PairMatch], fundamentals: dict[tuple[int, int], np.ndarray],
                  intrinsics: dict[int, np.ndarray]) -> dict[tuple[int, int], np.ndarray]:
    """Each pair's rotation under the given intrinsics (``E = K_j^T F K_i``)."""
    out = {}
    for p in pairs:
        F = fundamentals.get((p.i, p.j))
        if F is None or p.i not in intrinsics or p.j not in intrinsics:
            continue
        K_a, K_b = intrinsics[p.i], intrinsics[p.j]
        n_a = cv2.undistortPoints(p.points[:, 0].reshape(-1, 1, 2), K_a, None).reshape(-1, 2)
        n_b = cv2.undistortPoints(p.points[:, 1].reshape(-1, 1, 2), K_b, None).reshape(-1, 2)
        _, R, _, _ = cv2.recoverPose(K_b.T @ F @ K_a, n_a, n_b, np.eye(3))
        out[(p.i, p.j)] = R
    return out


def focal_factor(retrieval: RetrievalResult, pairs: Sequence[PairMatch],
                 min_inliers: int) -> tuple[float, float, float]:
    """The factor on the retrieved focal length (``FOCAL_FACTORS``) whose pair rotations, fused,
    sit nearest the retrieved cameras; 1 unless it beats the retrieved focal length by
    ``FOCAL_MARGIN_DEG``.

    Two photos' matches tell their relative rotation only with the focal length: on photos
    taken round an object (optical axes meeting at it) the epipolar geometry of each pair
    hardly constrains it, and too long a focal length shrinks every turn. The retrieved cameras
    know the turns roughly, from the silhouettes, so the focal length whose rigid set of
    cameras needs the least moving to sit on them is the one the photos and the silhouettes
    agree on.

    Returns:
        The factor, and the median angle the cameras moved at it and at factor 1 (degrees).
    """
    kept = {m.index: m for m in retrieval.kept}
    usable = [p for p in pairs if p.inliers >= min_inliers and p.i in kept and p.j in kept]
    fundamentals = _fundamentals(usable)
    weights = {(p.i, p.j): min(1.0, p.inliers / (4.0 * min_inliers)) for p in usable}
    moved = {}
    for factor in sorted({1.0, *FOCAL_FACTORS}):
        intrinsics = {i: scale_focal(m.K_photo, factor) for i, m in kept.items()}
        solved = _solve(kept, _rotations_at(usable, fundamentals, intrinsics), weights)
        if solved is not None:
            moved[factor] = float(np.median(solved.moved))
    if 1.0 not in moved:
        return 1.0, float("nan"), float("nan")
    best = min(moved, key=lambda f: moved[f])
    if moved[best] > moved[1.0] - FOCAL_MARGIN_DEG:
        best = 1.0
    return best, moved[best], moved[1.0]


def mapped_edges(mapped: Mapped, photos: Sequence[int]) -> dict[tuple[int, int], np.ndarray]:
    """The relative rotation ``R_ij`` (``W_j ~ R_ij W_i``, world-to-camera) between every two of
    ``photos`` the mapper registered, from its cameras."""
    row = {photo: k for k, photo in enumerate(mapped.photos)}
    inside = sorted(p for p in photos if p in row)
    W = {p: mapped.c2w[row[p], :3, :3].T for p in inside}
    return {(i, j): W[j] @ W[i].T for a, i in enumerate(inside) for j in inside[a + 1:]}


def fuse(retrieval: RetrievalResult, pairs: Sequence[PairMatch],
         min_inliers: int, search_focal: bool = False,
         mapped: Mapped | None = None) -> tuple[RetrievalResult, Fusion | None]:
    """The retrieval with its kept photos' cameras fused with the pairs' rotations.

    Args:
        retrieval: the retrieved cameras (photos indexed as given).
        pairs: verified matches between the photos (as given), with rotations where known.
        min_inliers: fewest inliers of a pair used (``MatchesConfig.min_inliers``).
        search_focal: no photo's focal length is known: the pairs' rotations are taken at the
            focal length ``focal_factor`` finds (the mapper's, given ``mapped``), which every
            camera then gets; else at the retrieved one (the photos' own).
        mapped: the mapper's cameras of some of the photos (``mapper.complete`` false): their
            relative rotations join the pairs' as edges of weight ``MAPPED_WEIGHT``.
    Returns:
        The retrieval with fused ``c2w`` (the other fields as retrieved, but the focal length),
        and what fusing did; when fewer than ``MIN_PHOTOS`` kept photos are connected by usable
        pairs, the cameras as retrieved (``fusion`` records no photos) and None.
    """
    kept = {m.index: m for m in retrieval.kept}
    candidates = [p for p in pairs if p.rotation is not None and p.inliers >= min_inliers
                  and p.i in kept and p.j in kept]
    usable = plausible(retrieval, candidates)
    weights = {(p.i, p.j): min(1.0, p.inliers / (4.0 * min_inliers)) for p in usable}
    factor = 1.0
    if search_focal:
        factor = (focal_factor(retrieval, usable, min_inliers)[0] if mapped is None
                  else mapped.focal / float(retrieval.matches[0].K_photo[0, 0]))
        edges = _rotations_at(usable, _fundamentals(usable),
                              {i: scale_focal(m.K_photo, factor) for i, m in kept.items()})
    else:
        edges = {(p.i, p.j): np.asarray(p.rotation) for p in usable}
    rigid = {} if mapped is None else mapped_edges(mapped, list(kept))
    edges.update(rigid)
    weights.update({edge: MAPPED_WEIGHT for edge in rigid})
    solutions = _every_set(kept, edges, weights)
    if not solutions:
        return dataclasses.replace(retrieval, fusion={
            "photos": [], "pairs": len(edges),
            "implausible": len(candidates) - len(usable)}), None
    cameras, moved, residual, used = {}, [], [], 0
    for solved in solutions:
        fused = solved.rotations
        residual += [_angle(R @ fused[i] @ fused[j].T) for (i, j), R in solved.used.items()]
        moved += solved.moved.tolist()
        used += len(solved.used)
        for photo, rotation in zip(solved.photos, fused, strict=True):
            c2w = np.eye(4)
            c2w[:3, :3] = rotation.T
            # At its retrieved distance, looking at the centre.
            c2w[:3, 3] = -np.linalg.norm(kept[photo].c2w[:3, 3]) * c2w[:3, 2]
            cameras[photo] = c2w
    matches = moved_to(scaled_focal(retrieval.matches, factor), cameras)
    summary = Fusion(sorted(cameras), used, len(edges) - used, float(np.median(moved)),
                     float(np.median(residual)) if residual else 0.0, factor,
                     tuple(sorted({p for edge in rigid for p in edge} & set(cameras))),
                     len(candidates) - len(usable), len(solutions))
    log.info("fused %d cameras in %d set(s) with %d pairs' rotations (%d far from the retrieved "
             "cameras' and %d else unused): moved %.1f deg (median), pairs within "
             "%.1f deg; focal length x%.2f", len(summary.photos), summary.sets, summary.pairs,
             summary.implausible,
             summary.dropped, summary.moved_deg, summary.residual_deg, factor)
    return dataclasses.replace(retrieval, matches=matches, fusion=summary.to_json()), summary


SET_ASIDE = {"photos": [], "set_aside": True}
"""The ``fusion`` record of the retrieval kept unfused among the hypotheses: chosen, its cameras
come from silhouettes alone though the photos share points (``job_warnings``)."""


def fuse_hypotheses(retrieval: RetrievalResult, min_inliers: int,
                    search_focal: bool = False, mapped: Mapped | None = None) -> RetrievalResult:
    """``fuse`` applied to the retrieval and to each of its alternatives, with its own pairs
    (``search_focal``: the focal length found on the retrieval serves them all). Where the
    pairs moved the retrieved cameras, the retrieval as it was stays among the alternatives:
    pairs matched wrongly that still agree with each other pull every fused hypothesis off,
    and the start's silhouette fit (``start``) then tells. ``mapped``: the mapper's cameras of
    some of the photos, a rigid set in every hypothesis."""
    fused, summary = fuse(retrieval, retrieval.pairs, min_inliers, search_focal, mapped)
    factor = 1.0 if summary is None else summary.focal_factor
    others = []
    for other in retrieval.alternatives:
        other = dataclasses.replace(other, matches=scaled_focal(other.matches, factor))
        others.append(_fuse_at(other, retrieval.pairs, min_inliers, mapped) if search_focal
                      else fuse(other, retrieval.pairs, min_inliers, mapped=mapped)[0])
    if summary is not None and others:  # where the job weighs hypotheses at all
        others.append(dataclasses.replace(retrieval, alternatives=[], fusion=dict(SET_ASIDE)))
    return dataclasses.replace(fused, alternatives=others)


def _fuse_at(retrieval: RetrievalResult, pairs: Sequence[PairMatch],
             min_inliers: int, mapped: Mapped | None = None) -> RetrievalResult:
    """``fuse`` with the pairs' rotations taken at the retrieval's own focal length."""
    kept = {m.index: m for m in retrieval.kept}
    usable = [p for p in pairs if p.rotation is not None and p.inliers >= min_inliers
              and p.i in kept and p.j in kept]
    rotations = _rotations_at(usable, _fundamentals(usable),
                              {i: m.K_photo for i, m in kept.items()})
    at_focal = [dataclasses.replace(p, rotation=rotations[(p.i, p.j)]) for p in usable
                if (p.i, p.j) in rotations]
    return fuse(retrieval, at_focal, min_inliers, mapped=mapped)[0]


def pairs_at_focal(retrieval: RetrievalResult) -> RetrievalResult:
    """The retrieval (and its alternatives) with each pair's rotation taken again at the
    cameras' focal length (``K_photo``): matched where no photo told it, the pairs' rotations
    were measured at a guess, and training compares them with its starting cameras."""
    intrinsics = {m.index: m.K_photo for m in retrieval.matches}
    usable = [p for p in retrieval.pairs if p.rotation is not None]
    rotations = _rotations_at(usable, _fundamentals(usable), intrinsics)
    pairs = [dataclasses.replace(p, rotation=rotations[(p.i, p.j)])
             if (p.i, p.j) in rotations else p for p in retrieval.pairs]
    others = [dataclasses.replace(a, pairs=pairs) for a in retrieval.alternatives]
    return dataclasses.replace(retrieval, pairs=pairs, alternatives=others)

"""CAD model and pose retrieval from photo masks.

Each photo's mask is cropped canonically (as the library's silhouettes were), compared by IoU
with every silhouette of every model at once, the model is chosen by votes, and one library
view per photo is found by a pose solver (``posesearch``). A photo matched to view v of model m
gets the camera ``c2w = library.poses[v]``, intrinsics ``K_canon`` in the canonical crop, and
``K_photo`` in its own pixels: exact, since both crops are affine maps of pixel coordinates.
With ``shared_focal`` the photos then share one focal length (one camera walked round the
object), each camera moved in or out so the object keeps its size in its photo.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from cadnerf_core.config import AMBIGUOUS_HINT
from cadnerf_core.intake.crop import CropBox, apply_crop, crop_intrinsics, uncrop_intrinsics
from cadnerf_core.intake.photos import canonical_masks
from cadnerf_core.progress import Progress
from cadnerf_core.retrieval.posesearch import PoseSearchResult, cyclic_dp, paper_algorithm1

if TYPE_CHECKING:
    from cadnerf_core.library.format import Library

log = logging.getLogger(__name__)


TOP_MODELS = 5  # models listed in a result, best first
APPEARANCE_SIZE = 128  # side of the crops the texture direction cue looks at


class RetrievalConfig(BaseModel):
    """How models and poses are retrieved."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    solver: Literal["dp", "paper"] = "dp"
    """Pose solver: "dp" (exact cyclic dynamic programme, ours) or "paper" (Algorithm 1)."""
    top_k: int = Field(default=10, ge=1)
    """Candidate views per photo in the paper's solver (the DP considers every view)."""
    max_discard: int = Field(default=2, ge=0)
    """Most photos either solver may discard."""
    discard_penalty: float = Field(default=0.3, ge=0.0)
    """DP only: IoU a discard costs; a photo is dropped only if keeping it costs more."""
    cyclic: bool = True
    """DP only: the walk may start at any azimuth and wrap once (the paper's may not)."""
    both_directions: bool = True
    """DP only: also try the walk with decreasing azimuth."""
    direction_margin: float = Field(default=0.0, ge=0.0)
    """DP only: IoU per photo by which a decreasing walk must beat an increasing one (at
    equal objectives the increasing walk, the paper's order, wins anyway). Measured on the
    synthetic walks of ``benchmarks/bench_retrieval.py``, which run both ways equally often,
    any margin > 0 only turns true decreasing walks into their front/back flips."""
    spread_weight: float = Field(default=10.0, ge=0.0)
    """DP only: weight of the prior that photos taken walking around an object are spread
    round it: ``spread_weight * sum over the walk's gaps g of (g / 360 deg) ** 2`` is
    subtracted (2 for 5 even gaps, 10 when every photo sits at one azimuth). Measured on the
    52 synthetic walks of ``benchmarks/bench_retrieval.py`` (36 azimuths, 48 models): median
    rotation error 17.0 degrees at 3, 13.8 at 10, 13.0 at 20 (14.3 at 10 with the shipped
    49 models, ``docs/bench_retrieval_full.md``); 10 is the milder prior for real walks,
    which are less even than the benchmark's (steps within 20% of 360/n). The prior assumes a
    walk around the object: the photos of half a walk may be spread round it, so lower it
    (or set 0) for partial walks."""
    model_choice: Literal["votes", "walk"] = "walk"
    """"votes": the model most photos' best views belong to (the paper). "walk": of the five
    models with most votes, the one whose best ordered walk (the pose solver's objective) is
    best. The paper's solver always uses "votes"."""
    appearance_weight: float = Field(default=0.2, ge=0.0)
    """DP only, with photos given: IoU per unit of texture evidence (``direction.py``) by
    which the walking direction the photos' texture favours is preferred (0: silhouettes
    alone decide). Chosen with ``appearance_threshold`` by a sweep on the 52 synthetic walks of
    ``benchmarks/bench_retrieval.py`` (128 px; weights 0.1 and 0.2, thresholds 0.5, 0.3, 0.25
    and 0.2): weight 0.2 with threshold 0.25 turns two walks flipped front to back right (an
    armchair and a bottle, evidence +0.32 and -0.26) and no right walk wrong, median rotation
    error 13.6 degrees against 14.3 at the former 0.1 and 0.5. Most of those walks' meshes
    have no texture at all (evidence 0); larger weights start to override the silhouettes."""
    appearance_threshold: float = Field(default=0.25, ge=0.0)
    """DP only: texture evidence weaker than this (in absolute value) is ignored. On the 52
    synthetic walks, evidence between 0.25 and 0.5 pointed the right way on 4 of 5 walks (the
    fifth, a textured cow walked backwards, the silhouettes had flipped already), evidence
    between 0.1 and 0.25 on 2 of 5."""
    walk: Literal["auto", "ccw", "cw"] = "auto"
    """Which way round the photos were taken, when the photographer knows: "ccw"
    (counter-clockwise seen from above: the object on your left as you walk; the library's
    increasing azimuth), "cw" (clockwise), or "auto" (the DP tries both; the paper's solver
    assumes "ccw", its photo order following the library's). A given direction removes the
    one ambiguity silhouettes cannot resolve on objects that look alike from mirrored sides
    (mugs, lamps, bottles); both solvers honour it."""
    ambiguity_margin: float = Field(default=0.05, ge=0.0)
    """DP, "auto" only: when the best walk beats the best walk the other way by less than this
    (summed IoU) and the texture cue is below ``appearance_threshold``, the result is flagged
    ``direction_ambiguous`` and the job warns that the direction is a guess. Measured on the
    52 synthetic walks of ``benchmarks/bench_retrieval.py``; see ``docs/bench_retrieval_full.md``
    (the "lead" column)."""
    ambiguous_walk: Literal["ccw", "best"] = "ccw"
    """DP, "auto" only: the walk taken when the direction is ambiguous (above). "ccw": the
    counter-clockwise one, the library's increasing azimuth and the paper's assumed order, so
    that a photographer who walks with the object on the left gets the right poses from
    photos that cannot tell the direction, and the result never depends on a lead of a few
    hundredths of IoU; "best": the walk with the higher objective, however slight (a coin
    toss on such photos). Measured on the 52 synthetic walks of
    ``benchmarks/bench_retrieval.py`` (walked each way equally often); see
    ``docs/bench_retrieval_full.md``."""
    shared_focal: bool = True
    """One camera for the whole walk: every photo gets the median of the photos' focal lengths
    (in units of the photo's longer side), and the distance to the object that keeps the
    object's size in the photo. Each library match gives a focal length of its own (the
    library camera zoomed to the photo's crop), and these disagree by the ratio of the CAD
    model's silhouette to the object's, view by view (on the benchmark's 6-view walks, 6% on
    a close match to 73% on a drill matched to a loose one, against one true focal length);
    the NeRF's poses cannot absorb a focal length error, its scene bends instead. Where the
    photos bring their focal length (a phone's EXIF), the median of those is used instead:
    the silhouettes cannot tell a wide lens near the object from a long one far away. Off: each
    photo keeps its match's focal length at the library's distance (the paper's retrieval,
    whose photos are taken at equal distances)."""
    perspective: Literal["auto", "far", "near"] = "auto"
    """Which of the library's silhouette sets to match (``LibrarySpec.near_distance``): "far"
    (the 40-degree camera at distance 4), "near" (65 degrees, from about half as far, a
    phone's framing), or "auto": where the photos' focal length is known (EXIF), both, keeping
    the set whose matched views show the object at the angle the photos do (the median over
    the kept photos of |log(crop side / focal length)| against the library view's own), since
    that angle fixes how near the camera stood and so the silhouette's perspective; the
    silhouettes' IoU cannot tell. On the 52 synthetic walks of ``benchmarks/bench_retrieval.py``
    (median rotation error): at 65 degrees 14.7 from the far set, 13.9 from the near one, 13.9
    choosing by the angle, 14.6 choosing by the higher mean IoU; at 40 degrees 13.6, 15.2, 13.6
    and 15.9. Without a known focal length, "far"."""
    size: int | None = Field(default=None, ge=8)
    """Side in pixels of the canonical crop that ``K_canon`` and ``box`` refer to; None =
    the library's silhouette size. (IoU is always computed at the library's size.)"""


@dataclass
class PhotoMatch:
    """One photo's retrieved camera.

    ``view``: library view index (a discarded photo keeps its own best view, flagged);
    ``c2w [4, 4]``: library pose; ``K_canon [3, 3]``: intrinsics in the canonical crop of
    ``box.size`` px; ``box``: photo -> canonical crop; ``K_photo [3, 3]``: in photo pixels.
    """

    index: int
    name: str
    view: int
    azimuth: float
    elevation: float
    iou: float
    discarded: bool
    c2w: np.ndarray
    K_canon: np.ndarray
    box: CropBox
    K_photo: np.ndarray

    def to_json(self) -> dict[str, Any]:
        """JSON-ready form (matrices as nested lists)."""
        return {"index": self.index, "name": self.name, "view": self.view,
                "azimuth": self.azimuth, "elevation": self.elevation, "iou": self.iou,
                "discarded": self.discarded, "c2w": self.c2w.tolist(),
                "K_canon": self.K_canon.tolist(), "box": self.box.to_dict(),
                "K_photo": self.K_photo.tolist()}


@dataclass
class RetrievalResult:
    """The chosen model, the best models by votes, and every photo's match."""

    model_id: str
    category: str
    top_models: list[dict[str, Any]]
    matches: list[PhotoMatch]
    solver: str
    direction: int
    score: float
    direction_evidence: float = 0.0
    """Texture evidence for the walking direction (> 0: increasing azimuth; 0: none used)."""
    direction_lead: float | None = None
    """The DP's objective of its best walk less that of the best walk the other way (None
    when the direction was given or the paper's solver ran)."""
    direction_ambiguous: bool = False
    """Neither the silhouettes (lead under ``RetrievalConfig.ambiguity_margin``) nor the texture
    told the walking direction: the walk is the one ``RetrievalConfig.ambiguous_walk`` assumes
    (counter-clockwise by default), and the poses are the mirrored walk's if the photographer
    went the other way."""
    perspective: str = "far"
    """The library silhouette set matched ("far" or "near", ``RetrievalConfig.perspective``)."""

    @property
    def kept(self) -> list[PhotoMatch]:
        """Matches of the photos that were not discarded."""
        return [m for m in self.matches if not m.discarded]

    def to_json(self) -> dict[str, Any]:
        """JSON-ready form (the ``retrieval.json`` of a job)."""
        return {"model_id": self.model_id, "category": self.category,
                "top_models": self.top_models, "solver": self.solver,
                "direction": self.direction, "score": self.score,
                "direction_evidence": self.direction_evidence,
                "direction_lead": self.direction_lead,
                "direction_ambiguous": self.direction_ambiguous,
                "perspective": self.perspective,
                "discarded": [m.index for m in self.matches if m.discarded],
                "matches": [m.to_json() for m in self.matches]}


def _pack_bits(flat: np.ndarray) -> np.ndarray:
    """Bit-pack rows of a bool matrix [K, N] into uint64 words [K, ceil(N / 64)]."""
    packed = np.packbits(flat, axis=1)
    pad = (-packed.shape[1]) % 8
    if pad:
        packed = np.pad(packed, ((0, 0), (0, pad)))
    return np.ascontiguousarray(packed).view(np.uint64)


def _popcount(words: np.ndarray) -> np.ndarray:
    """Set bits per row of uint64 words [..., W]. Returns [...] int64."""
    if hasattr(np, "bitwise_count"):  # numpy >= 2
        return np.bitwise_count(words).sum(-1, dtype=np.int64)
    as_bytes = words.view(np.uint8)
    return _BYTE_BITS[as_bytes].sum(-1, dtype=np.int64)


_BYTE_BITS = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


def iou_table(masks: np.ndarray, silhouettes: np.ndarray) -> np.ndarray:
    """IoU of every mask with every silhouette, by popcount over bit-packed masks.

    Args:
        masks: [P, S, S] bool canonical photo masks.
        silhouettes: [M, V, S, S] bool canonical library silhouettes.
    Returns:
        iou: [P, M, V] float32 (0 where both are empty).
    """
    n_models, n_views = silhouettes.shape[:2]
    lib = _pack_bits(silhouettes.reshape(n_models * n_views, -1))  # [M*V, W]
    photos = _pack_bits(masks.reshape(len(masks), -1))  # [P, W]
    area_lib = _popcount(lib)
    area_photo = _popcount(photos)
    # One pass over the whole library per photo (P <= 10): [M*V, W] words at a time.
    inter = np.stack([_popcount(lib & words) for words in photos])  # [P, M*V]
    union = area_photo[:, None] + area_lib[None, :] - inter
    iou = np.divide(inter, union, out=np.zeros(inter.shape), where=union > 0)
    return iou.astype(np.float32).reshape(len(masks), n_models, n_views)


def vote_models(iou: np.ndarray) -> tuple[int, list[tuple[int, int, float]]]:
    """Choose a model: each photo votes for the model of its best view.

    Most votes wins; ties go to the larger summed best IoU over all photos.

    Args:
        iou: [P, M, V].
    Returns:
        the chosen model index, and (model, votes, summed best IoU) of every model, best first.
    """
    best = iou.max(axis=2)  # [P, M]
    votes = np.bincount(best.argmax(axis=1), minlength=iou.shape[1])
    scores = best.sum(axis=0)
    order = sorted(range(iou.shape[1]), key=lambda m: (-int(votes[m]), -float(scores[m]), m))
    ranking = [(m, int(votes[m]), float(scores[m])) for m in order]
    return order[0], ranking


def azimuth_bins(az_el: np.ndarray, n_azimuths: int) -> np.ndarray:
    """Azimuth bin of every library view. az_el [V, 2] degrees -> [V] int."""
    step = 360.0 / n_azimuths
    return np.round(az_el[:, 0] / step).astype(np.int64) % n_azimuths


def solve_poses(iou: np.ndarray, az_index: np.ndarray, n_azimuths: int,
                config: RetrievalConfig, evidence: float = 0.0) -> PoseSearchResult:
    """Run the configured pose solver on one model's IoU table.

    Args:
        iou: [P, V] IoU of each photo with each view.
        az_index: [V] azimuth bin of each view.
        n_azimuths: number of azimuth bins.
        evidence: texture evidence for the walking direction (> 0: increasing azimuth),
            used by the DP when it reaches ``config.appearance_threshold``.
    Returns:
        chosen views (-1 = discarded), score and direction.
    """
    given = {"ccw": 1, "cw": -1}.get(config.walk, 0)
    if given:
        # A clockwise walk is a counter-clockwise one over mirrored azimuth bins; the chosen
        # view indices do not depend on the bins' numbering.
        bins = az_index if given > 0 else (-np.asarray(az_index)) % n_azimuths
        forward = config.model_copy(update={"walk": "auto", "both_directions": False})
        found = solve_poses(iou, bins, n_azimuths, forward)
        return dataclasses.replace(found, direction=given, direction_lead=None)
    if config.solver == "paper":
        found = paper_algorithm1(iou, az_index, config.top_k, config.max_discard)
        if np.isfinite(found.score):
            return found
        # No ordered choice among the top-k: fall back on each photo's own best view.
        log.warning("the paper's solver found no ordered poses; using each photo's best view")
        return PoseSearchResult(np.argmax(iou, axis=1), float(iou.max(axis=1).sum()), 1)
    backward_cost = config.direction_margin * len(iou)
    if abs(evidence) >= config.appearance_threshold:
        # Each direction gains (or loses) weight * evidence: the decreasing walk pays twice.
        backward_cost += 2.0 * config.appearance_weight * evidence
    return cyclic_dp(iou, az_index, n_azimuths, config.discard_penalty, config.max_discard,
                     config.both_directions, config.cyclic, backward_cost=backward_cost,
                     spread_weight=config.spread_weight)


def _match(library: Library, m: int, p: int, name: str, view: int, discarded: bool,
           iou: float, box: CropBox) -> PhotoMatch:
    """Build one photo's match from its library view and crop box."""
    K_canon = library.canonical_K(m, view, box.size)
    azimuth, elevation = (float(x) for x in library.az_el[view])
    return PhotoMatch(p, name, view, azimuth, elevation, iou, discarded,
                      library.poses[view].copy(), K_canon, box, uncrop_intrinsics(K_canon, box))


FOCAL_SCALE_LIMITS = (0.5, 2.0)  # most a shared focal length moves a camera in or out


def share_focal(matches: Sequence[PhotoMatch], sizes: Sequence[tuple[int, int]],
                known: Sequence[float | None] | None = None) -> list[PhotoMatch]:
    """One focal length for every photo (``RetrievalConfig.shared_focal``).

    Args:
        matches: every photo's match, its focal length its own.
        sizes: (height, width) of every photo, in the matches' order.
        known: focal lengths in pixels the photos bring (their EXIF), None where unknown.
    Returns:
        The matches with one focal length per pixel of the photo's longer side: the median of
        the kept photos' known focal lengths where any is known, else of their matches'. Each
        camera is moved along its ray to the object's centre by the factor its focal length
        changed, so the object keeps its size in the photo (principal point and rotation
        unchanged; the factor limited to ``FOCAL_SCALE_LIMITS``).
    """
    kept = [m for m in matches if not m.discarded]
    given = [f / max(sizes[m.index]) for m in kept
             if known is not None and (f := known[m.index]) is not None]
    if len(kept) < 2 and not given:
        return list(matches)
    focal = float(np.median(given or [m.K_photo[0, 0] / max(sizes[m.index]) for m in kept]))
    out = []
    for m in matches:
        scale = float(np.clip(focal * max(sizes[m.index]) / m.K_photo[0, 0],
                              *FOCAL_SCALE_LIMITS))
        K_photo = m.K_photo.copy()
        K_photo[0, 0] *= scale
        K_photo[1, 1] *= scale
        c2w = m.c2w.copy()
        c2w[:3, 3] *= scale
        out.append(dataclasses.replace(m, c2w=c2w, K_photo=K_photo,
                                       K_canon=crop_intrinsics(K_photo, m.box)))
    return out


def direction_evidence(images: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                       boxes: Sequence[CropBox]) -> float:
    """Texture evidence for the walking direction (``direction.walk_direction_evidence``) of
    photos [H_i, W_i, 3] float in [0, 1], composited on white inside their masks and cropped
    by their canonical boxes at ``APPEARANCE_SIZE``."""
    from cadnerf_core.retrieval.direction import walk_direction_evidence

    rgbs, crops = [], []
    for image, mask, b in zip(images, masks, boxes, strict=True):
        box = CropBox(b.x0, b.y0, b.side, APPEARANCE_SIZE)
        alpha = apply_crop(mask.astype(np.float32), box)[..., None]
        rgb = apply_crop(np.asarray(image, dtype=np.float32), box, fill=1.0)
        rgbs.append(np.clip(rgb * alpha + (1.0 - alpha), 0.0, 1.0))
        crops.append(alpha[..., 0] > 0.5)
    return walk_direction_evidence(np.stack(rgbs), np.stack(crops))


def _choose_walk(iou: np.ndarray, m: int, ranking: Sequence[tuple[int, int, float]],
                 az_index: np.ndarray, n_azimuths: int, config: RetrievalConfig,
                 evidence: float) -> tuple[int, PoseSearchResult]:
    """The model and its walk: the voted model ``m``'s, or (``model_choice`` "walk", DP) the
    best walk of the ``TOP_MODELS`` most voted. Returns (model index, its walk)."""
    found = solve_poses(iou[:, m, :], az_index, n_azimuths, config, evidence)
    if config.model_choice == "walk" and config.solver == "dp":
        for other, _, _ in ranking[1:TOP_MODELS]:
            walk = solve_poses(iou[:, other, :], az_index, n_azimuths, config, evidence)
            if walk.score > found.score:
                m, found = other, walk
    return m, found


def retrieve(masks: Sequence[np.ndarray], names: Sequence[str], library: Library,
             config: RetrievalConfig | None = None, progress: Progress | None = None,
             images: Sequence[np.ndarray] | None = None,
             focals: Sequence[float | None] | None = None) -> RetrievalResult:
    """Retrieve the CAD model and a library pose for every photo.

    Args:
        masks: P full-photo masks [H_i, W_i] bool, in walking order.
        names: P photo names.
        library: the loaded library.
        config: solver settings (defaults when None).
        progress: reports stage "retrieval" (2 steps a silhouette set searched) and checks
            for cancellation.
        images: the P photos [H_i, W_i, 3] float in [0, 1], optional: their texture helps
            the DP choose the walking direction (``RetrievalConfig.appearance_weight``).
        focals: the P photos' focal lengths in pixels where known (EXIF), else None; with
            ``shared_focal`` the known ones set the shared focal length.
    Returns:
        The RetrievalResult.
    """
    config = config or RetrievalConfig()
    spec = library.spec  # both silhouette sets share the crop size and margin
    crops, boxes = canonical_masks(masks, spec.silhouette_size, spec.margin)
    evidence = 0.0
    if images is not None and config.solver == "dp" and config.appearance_weight > 0:
        evidence = direction_evidence(images, masks, boxes)
    photos = _Photos(names, [mask.shape[:2] for mask in masks], crops, boxes, evidence, focals)
    near = library.near
    known = [f for f in focals or [] if f is not None]
    wanted = config.perspective
    if wanted != "auto" or near is None or not known:
        single = "far" if wanted == "auto" else wanted
        chosen = _retrieve_from(photos, library.view_set(single), config, progress, single,
                                (0, 2))
    else:
        results = [_retrieve_from(photos, lib, config, progress, label, steps)
                   for lib, label, steps in ((library, "far", (0, 4)), (near, "near", (2, 4)))]
        mismatch = [_angle_mismatch(r, lib, focals)
                    for r, lib in zip(results, (library, near), strict=True)]
        chosen = results[int(np.argmin(mismatch))]
        log.info("perspective: %s (photos' angle against the matched views': far %.3f, "
                 "near %.3f)", chosen.perspective, *mismatch)
    if chosen.direction_ambiguous:
        log.warning("%s (lead %.3f IoU, texture evidence %+.2f)", AMBIGUOUS_HINT,
                    chosen.direction_lead, chosen.direction_evidence)
    return chosen


@dataclass
class _Photos:
    """What retrieval needs of the photos, computed once for every silhouette set."""

    names: Sequence[str]
    sizes: list[tuple[int, int]]  # (height, width) of each photo
    crops: np.ndarray  # canonical masks [P, S, S]
    boxes: list[CropBox]  # photo -> canonical crop
    evidence: float  # texture evidence for the walking direction
    focals: Sequence[float | None] | None


def _angle_mismatch(result: RetrievalResult, library: Library,
                    focals: Sequence[float | None] | None) -> float:
    """Median over the kept photos with a known focal length of |log(a_photo / a_view)|, a
    being the angle the object's canonical crop spans: crop side over focal length, in the
    photo and in the matched view's render. inf when no kept photo has a known focal length."""
    m = library.index(result.model_id)
    size = library.spec.silhouette_size
    logs = [abs(math.log((match.box.side / focal)
                         / (library.crop_box(m, match.view, size).side / library.K_render[0, 0])))
            for match in result.kept
            if focals is not None and (focal := focals[match.index]) is not None]
    return float(np.median(logs)) if logs else math.inf


def _retrieve_from(photos: _Photos, library: Library, config: RetrievalConfig,
                   progress: Progress | None, perspective: str,
                   steps: tuple[int, int]) -> RetrievalResult:
    """``retrieve`` against one silhouette set (``library`` is the set's own Library).
    ``steps``: (steps done before, total) of the "retrieval" stage; this search adds two."""
    spec = library.spec
    names, boxes, evidence = photos.names, photos.boxes, photos.evidence
    iou = iou_table(photos.crops, library.silhouettes)
    voted, ranking = vote_models(iou)
    if progress is not None:
        progress.step("retrieval", steps[0] + 1, steps[1])
    az_index = azimuth_bins(library.az_el, spec.n_azimuths)
    m, found = _choose_walk(iou, voted, ranking, az_index, spec.n_azimuths, config, evidence)
    ambiguous = (found.direction_lead is not None
                 and found.direction_lead < config.ambiguity_margin
                 and abs(evidence) < config.appearance_threshold)
    if ambiguous and found.direction < 0 and config.ambiguous_walk == "ccw":
        ccw = config.model_copy(update={"walk": "ccw"})
        lead = found.direction_lead
        m, found = _choose_walk(iou, voted, ranking, az_index, spec.n_azimuths, ccw, evidence)
        found = dataclasses.replace(found, direction_lead=lead)
    size = config.size or spec.silhouette_size
    matches = []
    for p, view in enumerate(found.views):
        discarded = bool(view < 0)
        v = int(np.argmax(iou[p, m])) if discarded else int(view)
        box = CropBox(boxes[p].x0, boxes[p].y0, boxes[p].side, size)
        matches.append(_match(library, m, p, names[p], v, discarded, float(iou[p, m, v]), box))
    if config.shared_focal:
        matches = share_focal(matches, photos.sizes, photos.focals)
    top = [{"model_id": library.models[i].id, "category": library.models[i].category,
            "votes": votes, "score": score} for i, votes, score in ranking[:TOP_MODELS]]
    entry = library.models[m]
    log.info("retrieved %s (%s) with %s: %d of %d photos kept", entry.id, entry.category,
             config.solver, sum(not x.discarded for x in matches), len(matches))
    if progress is not None:
        progress.step("retrieval", steps[0] + 2, steps[1])
    return RetrievalResult(entry.id, entry.category, top, matches, config.solver,
                           found.direction, found.score, evidence, found.direction_lead,
                           perspective=perspective, direction_ambiguous=ambiguous)

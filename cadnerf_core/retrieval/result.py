"""What retrieval returns: the chosen model and every photo's camera (``retrieval.json``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from cadnerf_core.intake.crop import CropBox

if TYPE_CHECKING:
    from cadnerf_core.cameras.matches import PairMatch


@dataclass
class PhotoMatch:
    """One photo's retrieved camera.

    ``view``: library view index (a discarded photo keeps its own best view, flagged);
    ``c2w [4, 4]``: library pose; ``K_canon [3, 3]``: intrinsics in the canonical crop of
    ``box.size`` px; ``box``: photo -> canonical crop; ``K_photo [3, 3]``: in photo pixels;
    ``c2w_retrieved [4, 4]``: the library pose where ``c2w`` is fused with the photos' matches
    (``retrieval.fusion``), else None.
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
    c2w_retrieved: np.ndarray | None = None

    def to_json(self) -> dict[str, Any]:
        """JSON-ready form (matrices as nested lists)."""
        return {"index": self.index, "name": self.name, "view": self.view,
                "azimuth": self.azimuth, "elevation": self.elevation, "iou": self.iou,
                "discarded": self.discarded, "c2w": self.c2w.tolist(),
                "K_canon": self.K_canon.tolist(), "box": self.box.to_dict(),
                "K_photo": self.K_photo.tolist(),
                **({} if self.c2w_retrieved is None
                   else {"c2w_retrieved": self.c2w_retrieved.tolist()})}


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
    """Evidence for the walking direction from the texture cue plus the turns between matched
    consecutive photos (> 0: increasing azimuth; 0: none used)."""
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
    focal_known: bool | None = None
    """Whether any photo's focal length was known (its EXIF, or ``RetrievalConfig.focal_35mm``);
    False: the field of view was estimated from silhouettes. None: not recorded."""
    alternatives: list[RetrievalResult] = field(default_factory=list)
    """The next best hypotheses (model, walking direction, poses), best first, when
    ``RetrievalConfig.hypotheses`` asks for more than one; not written to ``retrieval.json``."""
    order: list[int] = field(default_factory=list)
    """The photos' indices in the walking order retrieval used (empty: as given)."""
    order_mode: str = "walk"
    """``RetrievalConfig.order`` of the search that found this result."""
    reordered: bool = False
    """The photos did not look like a walk in the order given (``RetrievalConfig.order``
    "auto") or came in no order ("any"), and ``order`` differs from it as a cycle."""
    order_lead: float | None = None
    """The order search's objective of the order used less that of the best walk in any other
    order (summed IoU; None when no order was searched or the given one was kept)."""
    order_ambiguous: bool = False
    """The order was searched and no order led the others by ``order_ambiguity_margin`` a
    photo: the walking order, and with it the poses, may be wrong."""
    hypotheses: list[dict[str, Any]] = field(default_factory=list)
    """The hypotheses a short silhouette fit compared (model, direction, retrieval score, fit
    score), in retrieval's order, when there were several; this result is the best fit's."""
    pairs: list[PairMatch] = field(default_factory=list)
    """The verified matches between every pair of photos, the photos numbered as given, with their
    inliers' pixels (training's epipolar loss reads them); written to ``retrieval.json`` as
    ``photo_pairs`` (``matches.PairMatch.to_json``: photos i and j, mutual matches, inliers,
    inlier ratio, median Sampson error in pixels, turn about the vertical axis); empty when
    matching was off or had no photos."""
    fusion: dict[str, Any] | None = None
    """What fusing the cameras with the pairs' rotations did (``fusion.Fusion.to_json``), None
    when they were not fused."""
    too_small: list[int] = field(default_factory=list)
    """The photos matching skipped: their object spans fewer than
    ``config_matches.MIN_SEARCH_SIDE`` pixels (``matches.too_small``)."""

    def in_given_order(self, order: Sequence[int], mode: str, reordered: bool,
                       pairs: list[PairMatch], lead: float | None = None,
                       guess: bool = False) -> RetrievalResult:
        """This result, found on photos taken in ``order``, with every match indexed as given
        and in the given order again (its alternatives likewise) and the photos' ``pairs`` as
        matched in the given order; it records the walking order, its lead over any other
        order and whether it is a guess."""
        matches = sorted((dataclasses.replace(m, index=order[m.index]) for m in self.matches),
                         key=lambda m: m.index)
        others = [a.in_given_order(order, mode, reordered, pairs, lead, guess)
                  for a in self.alternatives]
        return dataclasses.replace(self, matches=matches, alternatives=others,
                                   order=list(order), order_mode=mode, reordered=reordered,
                                   pairs=pairs, order_lead=lead, order_ambiguous=guess)

    @property
    def photo_pairs(self) -> list[dict[str, Any]]:
        """``pairs`` as JSON summaries (no points)."""
        return [p.to_json() for p in self.pairs]

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
                **({} if self.focal_known is None else {"focal_known": self.focal_known}),
                "order": self.order or [m.index for m in self.matches],
                "order_mode": self.order_mode, "reordered": self.reordered,
                "order_lead": self.order_lead, "order_ambiguous": self.order_ambiguous,
                "discarded": [m.index for m in self.matches if m.discarded],
                "matches": [m.to_json() for m in self.matches],
                **({"hypotheses": self.hypotheses} if self.hypotheses else {}),
                **({"photo_pairs": self.photo_pairs} if self.photo_pairs else {}),
                **({"fusion": self.fusion} if self.fusion else {}),
                **({"too_small": self.too_small} if self.too_small else {})}

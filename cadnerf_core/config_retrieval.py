"""How the CAD model, the photos' poses and their walking order are retrieved: the
``retrieval`` section of the pipeline config (``cadnerf_core.config``, which re-exports it).
Torch-free, like the rest of the config."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from cadnerf_core.config_bounds import MAX_LR
from cadnerf_core.config_bounds import Frozen as _Frozen
from cadnerf_core.config_matches import MatchesConfig


class RetrievalConfig(_Frozen):
    """How the CAD model and the photos' poses are retrieved (``retrieval.retrieve.retrieve``)."""

    solver: Literal["dp", "paper"] = "dp"
    """Pose solver: "dp" (exact cyclic dynamic programme, ours) or "paper" (Algorithm 1)."""
    top_k: int = Field(default=10, ge=1, le=100)
    """Candidate views per photo in the paper's solver (the paper: 10; the DP uses every view)."""
    max_discard: int = Field(default=2, ge=0, le=5)
    """Most photos either solver may discard as inconsistent (the paper: 1-2)."""
    walk: Literal["auto", "ccw", "cw"] = "auto"
    """Which way round the photos were taken: "ccw" (the object on your left), "cw", or "auto".
    Give it for objects alike from mirrored sides (mugs, bottles): silhouettes cannot tell."""
    shared_focal: bool = True
    """One camera for the walk: the photos share one focal length (their EXIF one, else their
    matches' median), each camera moved to keep the object's size in its photo. Off: each
    photo keeps its match's focal length (photos taken at different zooms)."""
    focal_35mm: float | None = Field(default=None, ge=8.0, le=1200.0)
    """35 mm equivalent focal length of photos without EXIF (a phone: 24-28 mm); EXIF wins."""
    perspective: Literal["auto", "far", "near"] = "auto"
    """Library silhouettes to match: "far" (the library's narrow camera), "near" (a phone's wide
    lens), or "auto": the set fitting the photos' known focal length, else "far"."""
    discard_penalty: float = Field(default=0.3, ge=0.0, le=10.0)
    """DP only: IoU a discard costs; a photo is dropped only if keeping it costs more."""
    cyclic: bool = True
    """DP only: the walk may start at any azimuth and wrap once (the paper's may not)."""
    both_directions: bool = True
    """DP only: also try the walk with decreasing azimuth."""
    direction_margin: float = Field(default=0.0, ge=0.0, le=1.0)
    """DP only: IoU per photo by which a decreasing walk must beat an increasing one (0: a
    margin turns true decreasing walks into front/back flips). Kept for the benchmarks."""
    spread_weight: float = Field(default=10.0, ge=0.0, le=100.0)
    """DP only: weight of the prior that photos are spread round the object: this times the sum
    of the walk's squared gaps (in turns) is subtracted. Lower it, or 0, for partial walks."""
    model_choice: Literal["votes", "walk"] = "walk"
    """"votes": the model most photos' best views belong to (the paper, whose solver always
    votes). "walk": of the ``walk_models`` most voted, the one whose best ordered walk scores
    best. Kept for the benchmarks' comparison with the paper."""
    walk_models: int = Field(default=0, ge=0, le=10000)
    """DP, ``model_choice`` "walk": how many models, most voted first, have their best walk
    compared, and give the start's ``hypotheses``; 0: every model the library allows. With
    few photos the votes scatter, and the best walk is often a model no photo voted for, so
    every model competes (models that cannot win are not walked: ``walks.walk_bound``); a
    small number keeps the race to the most voted, where a basic shape's walk could edge out
    the right model's (``docs/presets.md``)."""
    appearance_weight: float = Field(default=0.2, ge=0.0, le=10.0)
    """DP only, photos given: IoU per unit of texture evidence by which the direction the
    photos' texture favours is preferred (0: silhouettes alone; more overrides them)."""
    appearance_threshold: float = Field(default=0.25, ge=0.0, le=10.0)
    """DP only: texture evidence weaker than this (in absolute value) is ignored."""
    start_evidence: float = Field(default=0.9, ge=0.0, le=100.0)
    """Texture evidence (in absolute value; one matched pair turning the walk's way gives
    ``matches.evidence_per_pair``) from which the start's hypotheses (``hypotheses``) walking
    against it are not fitted: their short silhouette fits cannot tell a walk from its mirror
    image. 0: every hypothesis is fitted."""
    ambiguity_margin: float = Field(default=0.05, ge=0.0, le=100.0)
    """DP, "auto" only: a best walk that leads the other direction's best by less than this
    (summed IoU), with no texture evidence, flags ``direction_ambiguous`` and a warning."""
    ambiguous_walk: Literal["ccw", "best"] = "ccw"
    """DP, "auto": the walk taken when ambiguous: "ccw" (the paper's order; a slight lead never
    decides) or "best" (the higher objective, however slight). Kept for the benchmarks."""
    hypotheses: int = Field(default=3, ge=1, le=10)
    """Start hypotheses (model, walking direction, poses, silhouette set) each given a short
    coarse silhouette fit before training, the best fit kept: the retrieved walk, then (where
    no focal length is known and ``perspective`` is "auto") the near set's best walk, then the
    next best walks of the ``walk_models`` either way round (1: the retrieved walk alone).
    Several hypotheses help most on objects the library has not seen."""
    hypothesis_steps: int = Field(default=60, ge=1, le=2000)
    """Phase-two steps of each hypothesis's coarse fit (phase one gets half as many)."""
    hypothesis_size: int = Field(default=32, ge=16, le=256)
    """Side in pixels of the crops a hypothesis is fitted and scored on."""
    hypothesis_pose_lr: float = Field(default=2e-3, gt=0.0, le=MAX_LR)
    """Learning rate of the poses in a hypothesis's coarse fit, whatever phase two's: the fits
    are compared with one another, so the rate that ranks the starts stays put when training
    learns the poses faster."""
    hypothesis_seeds: int = Field(default=1, ge=1, le=8)
    """Coarse fits of each hypothesis, each from its own seed, their scores averaged: one fit's
    score scatters between seeds about as much as hypotheses often differ. Each extra seed
    costs as much as the fits themselves. Kept for the benchmarks."""
    mirror_margin: float = Field(default=0.01, ge=0.0, le=1.0)
    """Mean silhouette IoU by which the retrieved model walked the other way round must out-fit
    the retrieved walk for the job to start from it (0: any lead). Silhouettes cannot tell a
    walk from its mirror image on an object that is nearly symmetric, so a slight lead is
    noise. The margin is kept to the mirror: another model's walk switches on any lead
    (``docs/presets.md``)."""
    order: Literal["walk", "any", "auto"] = "auto"
    """The photos' order: "walk" (they were taken walking round the object, in this order: the
    paper's assumption), "any" (no order: the walk is found from the silhouettes and the
    photos' colours, ``retrieval.ordering``), or "auto": the given order kept when it is a
    plausible walk, else the order found, with a warning that names it. The search walks the
    five most voted models; its cost is in ``docs/presets.md``."""
    order_margin: float = Field(default=0.12, ge=0.0, le=10.0)
    """"auto" only: IoU per photo by which the best walk in any order must beat the walk in the
    given order for the photos to be reordered. Silhouettes of a side and of its mirror side
    look alike, so walks taken in order lose to some other order by a little, more so with a
    phone's wide lens; a margin below that loss reorders true walks, while shuffled photos
    gain more where their walk is found clearly (``docs/presets.md``)."""
    order_ambiguity_margin: float = Field(default=0.003, ge=0.0, le=1.0)
    """"any", and "auto" when it reordered: IoU per photo by which the order found must beat
    the best walk of any other order, else the result says the order is a guess
    (``order_ambiguous``, with a warning)."""
    similarity_weight: float = Field(default=0.1, ge=0.0, le=10.0)
    """"any" and "auto": IoU a walk gains per neighbouring pair per unit of the pair's
    standardised likeness (colours and outlines, ``retrieval.ordering``) in the order search."""
    exclude_models: tuple[str, ...] = ()
    """Library model ids never retrieved (a leave-out evaluation: the object's own look-alike
    left out, so the figures say how the method does on objects the library has not seen).
    Ids the library lacks are an error when the job runs."""
    matches: MatchesConfig = Field(default_factory=MatchesConfig)
    """Matches between the photos: the walking direction and the cameras' relative rotations
    where the object has texture, and which photos neighbour each other in a searched order."""

    @model_validator(mode="after")
    def _check_excluded(self) -> RetrievalConfig:
        if any(not name.strip() for name in self.exclude_models):
            raise ValueError("exclude_models: model ids must not be empty")
        if len(set(self.exclude_models)) != len(self.exclude_models):
            raise ValueError(f"exclude_models lists a model twice: {list(self.exclude_models)}")
        return self

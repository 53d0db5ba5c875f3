"""The retrieval benchmark's synthetic walks: render a walk of a mesh, retrieve it with every
variant (ours, the paper's Algorithm 1, ablations) and at a phone's field of view
(``benchmarks.bench_retrieval``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import SEED, load_walk, rotation_error
from benchmarks.lookalikes import excluded

VIEW_COUNTS = (6, 9)


# Variants retrieved on every synthetic walk: ours (defaults), the paper's Algorithm 1, the bare
# DP (no spread prior, model by votes, no texture cue: "DP, bare"), and ablations of ours.
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "dp": ("**DP (ours)**", {}),
    "paper": ("Algorithm 1", {"solver": "paper"}),
    "bare": ("DP, bare", {"model_choice": "votes", "spread_weight": 0.0, "appearance_weight": 0.0,
                        "direction_margin": 0.005, "ambiguous_walk": "best"}),
    "votes": ("DP, model by votes", {"model_choice": "votes"}),
    # The best walk of the five most voted models only, not of every model.
    "five": ("DP, walks of the five most voted", {"walk_models": 5}),
    "nospread": ("DP, no spread prior", {"spread_weight": 0.0}),
    "notexture": ("DP, no texture cue", {"appearance_weight": 0.0}),
    # Where the direction is ambiguous, the walk with the higher objective rather than the
    # counter-clockwise one.
    "best": ("DP, ambiguous: best walk", {"ambiguous_walk": "best"}),
    # The photographer gives the walking direction (``RetrievalConfig.walk``; "given" is
    # replaced by the walk's true direction).
    "walk": ("DP, walk given", {"walk": "given"}),
    "paper_walk": ("Algorithm 1, walk given", {"solver": "paper", "walk": "given"}),
    # The photos' focal length known (a phone's EXIF): the silhouette set is chosen by it
    # (``RetrievalConfig.perspective``); these walks are the far set's 40 degrees.
    "focal": ("DP, focal length known", {"focal": True}),
    # Every variant above leaves the mesh's look-alikes out of the library
    # (``benchmarks.lookalikes``); this one keeps them.
    "lookalike": ("DP, look-alike in the library", {"lookalike": True}),
}
PHONE_FOV = 65.0  # a phone's main lens across the longer side, as ``--fov 65`` of bench_training
# The walks at each field of view: retrieval from each silhouette set, ours choosing by the
# focal length, and the choice a silhouette score would make.
PHONE_VARIANTS: dict[str, str] = {
    "far": "40-degree set only",
    "near": "near set only",
    "auto": "**set chosen by the focal length (ours)**",
    "iou": "set with the higher mean IoU",
    "five": "set chosen by the focal length, walks of the five most voted",
}


@dataclass
class SetResult:
    """One synthetic walk retrieved with every variant."""

    mesh: str
    views: int
    direction: int
    model: str
    mean_iou: float
    errors: dict[str, float]  # variant -> median rotation error (degrees) of kept photos
    dropped: dict[str, int]  # variant -> photos discarded
    directions: dict[str, int]  # variant -> walking direction found
    lead: float = float("nan")
    """Ours: the best walk's objective less the best walk's the other way."""
    ambiguous: bool = False
    """Ours flagged the walking direction as a guess."""
    dp_on_paper_kept: float = float("nan")
    """Ours, median rotation error over the photos Algorithm 1 kept (like for like: Algorithm
    1 discards 1-2 photos on many walks, and its median is over the rest)."""


def retrieve_all(masks: list[np.ndarray], names: list[str], library: Any,
                 images: list[np.ndarray], direction: int,
                 focals: list[float] | None = None,
                 exclude: tuple[str, ...] = ()) -> dict[str, Any]:
    """Retrieval with every variant of ``VARIANTS`` (``direction``: the walk's true one, for
    the variants that are given it; ``focals``: the photos' focal lengths in pixels, for the
    variant that knows them; ``exclude``: library models left out, but by "lookalike").
    Returns variant -> RetrievalResult."""
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.retrieval.search import retrieve

    walk = "ccw" if direction > 0 else "cw"
    out = {}
    for key, (_, options) in VARIANTS.items():
        own = {k: v for k, v in options.items() if k not in ("focal", "lookalike")}
        if not options.get("lookalike"):
            own["exclude_models"] = exclude
        if own.get("walk") == "given":
            own["walk"] = walk
        out[key] = retrieve(masks, names, library, RetrievalConfig(**own), images=images,
                            focals=focals if options.get("focal") else None)
    return out


def synthetic_set(name: str, views: int, direction: int, library: Any, work: Path) -> SetResult:
    """Render one walk of a mesh and retrieve it with every variant (its look-alikes left
    out but by the "lookalike" variant)."""
    data = load_walk(name, work / f"{name}_{views}_{direction}", views, seed=SEED + views,
                     direction=direction)
    results = retrieve_all(list(data.masks), data.names, library, list(data.images), direction,
                           [float(K[0, 0]) for K in data.K], excluded(name))
    dp, paper = results["dp"], results["paper"]
    model = dp.model_id if paper.model_id == dp.model_id else \
        f"{dp.model_id}; votes: {paper.model_id}"
    return SetResult(name, views, direction, f"{model} ({dp.category})",
                     float(np.mean([m.iou for m in dp.matches])),
                     {s: rotation_error(r, data.c2w) for s, r in results.items()},
                     {s: sum(m.discarded for m in r.matches) for s, r in results.items()},
                     {s: r.direction for s, r in results.items()},
                     dp.direction_lead if dp.direction_lead is not None else float("nan"),
                     dp.direction_ambiguous,
                     rotation_error(dp, data.c2w, {m.index for m in paper.kept}))


@dataclass
class PhoneResult:
    """One walk rendered at a field of view, retrieved from each silhouette set."""

    mesh: str
    views: int
    direction: int
    fov: float
    errors: dict[str, float]  # PHONE_VARIANTS key -> median rotation error (degrees)
    chosen: str  # the set ours chose


def phone_set(name: str, views: int, direction: int, library: Any, work: Path,
              fov: float = PHONE_FOV) -> PhoneResult:
    """Render one walk at ``fov`` degrees across (the object filling the same share of the
    frame: from nearer at a wider angle) and retrieve it with the photos' focal length known,
    the mesh's look-alikes left out."""
    from cadnerf_core.config import RetrievalConfig
    from cadnerf_core.retrieval.search import retrieve

    data = load_walk(name, work / f"fov{fov:g}_{name}_{views}_{direction}", views,
                     seed=SEED + views, direction=direction, fov_deg=fov)
    focals = [float(K[0, 0]) for K in data.K]
    results = {key: retrieve(list(data.masks), data.names, library,
                             RetrievalConfig(perspective=key,  # type: ignore[arg-type]
                                             exclude_models=excluded(name)),
                             images=list(data.images), focals=focals)
               for key in ("far", "near", "auto")}
    results["five"] = retrieve(list(data.masks), data.names, library,
                               RetrievalConfig(exclude_models=excluded(name), walk_models=5),
                               images=list(data.images), focals=focals)
    results["iou"] = max((results["far"], results["near"]),
                         key=lambda r: float(np.mean([m.iou for m in r.kept])))
    return PhoneResult(name, views, direction, fov,
                       {k: rotation_error(r, data.c2w) for k, r in results.items()},
                       results["auto"].perspective)

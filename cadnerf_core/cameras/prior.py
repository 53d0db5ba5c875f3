"""Which pairs' rotations are plausible: near the relative rotation of the two photos' retrieved
cameras. The mapper and the fusion (``cameras.stage``, ``cameras.fusion``) take only those."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cadnerf_core.cameras.conventions import rotation_angle_deg
from cadnerf_core.cameras.matches import PairMatch
from cadnerf_core.retrieval.result import RetrievalResult

PRIOR_DEG = 60.0
"""Most a pair's rotation may differ from the relative rotation of its two photos' retrieved
cameras. Retrieval's cameras err by 10 to 40 degrees each at the users' spacing, so a right pair
lies within; a wrong one mostly does not: the turn of a few degrees that features travelling
with the camera give two photos 40 degrees apart (highlights, the outline), or the half turn of
a print repeated on the object's other side (``docs/benchmarks.md``, the cameras at the users'
spacing: pairs right and wrong before and after)."""


def plausible(retrieval: RetrievalResult, pairs: Sequence[PairMatch]) -> list[PairMatch]:
    """The pairs whose rotation lies within ``PRIOR_DEG`` of the relative rotation of the two
    photos' retrieved cameras (``c2w_retrieved`` where the cameras were moved since), and the
    pairs without a rotation or of photos retrieval has no camera for, as given."""
    return plausible_at({m.index: (m.c2w if m.c2w_retrieved is None else m.c2w_retrieved)
                         for m in retrieval.matches}, pairs)


def plausible_at(cameras: dict[int, np.ndarray], pairs: Sequence[PairMatch]) -> list[PairMatch]:
    """``plausible`` against the given cameras (c2w [4, 4] by photo index)."""
    kept = []
    for p in pairs:
        if p.rotation is not None and p.i in cameras and p.j in cameras:
            prior = cameras[p.j][:3, :3].T @ cameras[p.i][:3, :3]
            if float(rotation_angle_deg((np.asarray(p.rotation) @ prior.T)[None])[0]) > PRIOR_DEG:
                continue
        kept.append(p)
    return kept

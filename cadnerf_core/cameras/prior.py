"""Which pairs' rotations are plausible: near the relative rotation of the two photos' retrieved
cameras, or confirmed by a triangle of pairs that all contradict them (``vouched``). The mapper
and the fusion (``cameras.stage``, ``cameras.fusion``) take only those."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cadnerf_core.cameras.conventions import rotation_angle_deg
from cadnerf_core.cameras.matches import PairMatch
from cadnerf_core.cameras.viewgraph import triangles
from cadnerf_core.retrieval.result import RetrievalResult

PRIOR_DEG = 60.0
"""Most a pair's rotation may differ from the relative rotation of its two photos' retrieved
cameras. Retrieval's cameras err by 10 to 40 degrees each at the users' spacing, so a right pair
lies within; a wrong one mostly does not: the turn of a few degrees that features travelling
with the camera give two photos 40 degrees apart (highlights, the outline), or the half turn of
a print repeated on the object's other side (``docs/benchmarks.md``, the cameras at the users'
spacing: pairs right and wrong before and after)."""


MIN_TURN_DEG = 15.0
"""Least rotation of each pair of a triangle that vouches for its pairs against the retrieved
cameras: the turns of a few degrees that features travelling with the camera give compose
into a closed triangle whatever the photos' true angles."""


def plausible(retrieval: RetrievalResult, pairs: Sequence[PairMatch]) -> list[PairMatch]:
    """The pairs whose rotation lies within ``PRIOR_DEG`` of the relative rotation of the two
    photos' retrieved cameras (``c2w_retrieved`` where the cameras were moved since), and the
    pairs without a rotation or of photos retrieval has no camera for, as given."""
    return plausible_at({m.index: (m.c2w if m.c2w_retrieved is None else m.c2w_retrieved)
                         for m in retrieval.matches}, pairs)


def plausible_at(cameras: dict[int, np.ndarray], pairs: Sequence[PairMatch]) -> list[PairMatch]:
    """``plausible`` against the given cameras (c2w [4, 4] by photo index), and the pairs far
    from them that close a triangle of such pairs (``vouched``)."""
    far = []
    for p in pairs:
        if p.rotation is not None and p.i in cameras and p.j in cameras:
            prior = cameras[p.j][:3, :3].T @ cameras[p.i][:3, :3]
            if _angle(np.asarray(p.rotation) @ prior.T) > PRIOR_DEG:
                far.append(p)
    rescued, left = vouched(far), {id(p) for p in far}
    return [p for p in pairs if id(p) not in left or (p.i, p.j) in rescued]


def vouched(pairs: Sequence[PairMatch]) -> set[tuple[int, int]]:
    """The pairs (``(i, j)``) of every triangle that pairs turning at least ``MIN_TURN_DEG``
    each close within ``viewgraph.CYCLE_DEG``. Three photos whose matches agree among
    themselves on turns that retrieval's cameras contradict tell that retrieval is wrong there
    (a look-alike's outline seen from another side, a walk mirrored), not all three pairs: a
    pair matched wrongly is off on its own, and two wrong pairs rarely compose into the third."""
    edges = {(p.i, p.j): np.asarray(p.rotation) for p in pairs
             if p.rotation is not None and _angle(np.asarray(p.rotation)) >= MIN_TURN_DEG}
    return {e if e in edges else (e[1], e[0])
            for (a, b, c), closes in triangles(edges) if closes
            for e in ((a, b), (b, c), (a, c))}


def _angle(R: np.ndarray) -> float:
    return float(rotation_angle_deg(np.asarray(R)[None])[0])

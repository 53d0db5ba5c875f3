"""How each photo's camera was placed, and how sure the job is of it.

Three sources, from surest to least: ``matches`` (COLMAP's mapper registered the photo: its
camera is bundle adjusted over the points it shares with the others), ``both`` (the pairs'
rotations fused with the retrieved cameras: two independent measurements that must agree), and
``silhouettes`` (the library view whose outline fits best, alone). The confidence is a ranking
in [0, 1] within those sources, not a calibrated probability: a fused camera counts the more
the nearer it stayed to its retrieved one (the outline and the matches agree), a silhouette's
the higher its IoU.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from cadnerf_core.cameras.conventions import rotation_angle_deg

Placed = Literal["matches", "both", "silhouettes"]
MAPPED_CONFIDENCE = 0.9
"""A camera the mapper registered."""
FUSED_BASE, FUSED_SPAN, AGREEMENT_DEG = 0.4, 0.5, 30.0
"""A fused camera: ``FUSED_BASE`` plus ``FUSED_SPAN`` times how little it moved from the
retrieved camera (none at ``AGREEMENT_DEG`` and beyond)."""
SILHOUETTE_SPAN = 0.4
"""A camera from its outline alone: this times its IoU."""


@dataclass(frozen=True)
class Placement:
    """One photo's camera: ``index`` (as uploaded), how it was ``placed`` and ``confidence``."""

    index: int
    placed: Placed
    confidence: float


def _moved_deg(match: dict[str, Any]) -> float:
    """Degrees between a photo's camera and its retrieved one (0 where it was not moved)."""
    if "c2w_retrieved" not in match:
        return 0.0
    a = np.asarray(match["c2w"], dtype=float)[:3, :3]
    b = np.asarray(match["c2w_retrieved"], dtype=float)[:3, :3]
    return float(rotation_angle_deg((a.T @ b)[None])[0])


def camera_placements(retrieval: dict[str, Any]) -> list[Placement]:
    """How every kept photo's camera was placed, from the job's ``retrieval.json``.

    Args:
        retrieval: ``RetrievalResult.to_json()`` of the chosen start.
    Returns:
        One ``Placement`` per kept (not discarded) photo, in upload order.
    """
    fusion = retrieval.get("fusion") or {}
    fused = set(fusion.get("photos", []))
    mapped = fused if fusion.get("start") == "mapper" else set(fusion.get("mapped", []))
    out = []
    for match in sorted(retrieval.get("matches", []), key=lambda m: m["index"]):
        if match.get("discarded"):
            continue
        index = int(match["index"])
        if index in mapped:
            out.append(Placement(index, "matches", MAPPED_CONFIDENCE))
        elif index in fused:
            agreement = max(0.0, 1.0 - _moved_deg(match) / AGREEMENT_DEG)
            out.append(Placement(index, "both", round(FUSED_BASE + FUSED_SPAN * agreement, 3)))
        else:
            iou = float(match.get("iou", 0.0))
            out.append(Placement(index, "silhouettes", round(SILHOUETTE_SPAN * iou, 3)))
    return out

"""The mapper's cameras carried into the CAD model's frame: the start a job keeps where COLMAP's
mapper registered its photos (``retrieval.mapper``).

The mapper's reconstruction has its own frame and scale. One rotation, fitted robustly to the
retrieved cameras (``fusion.anchor``), turns it into the CAD model's frame; a scale and a shift
put the camera centres nearest the retrieved cameras' positions.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from cadnerf_core.cameras.conventions import rotation_angle_deg
from cadnerf_core.cameras.fusion import MIN_PHOTOS, anchor, moved_to, scaled_focal
from cadnerf_core.cameras.mapper import Mapped
from cadnerf_core.retrieval.result import RetrievalResult

log = logging.getLogger(__name__)


def place(retrieval: RetrievalResult, mapped: Mapped,
          focal_known: bool) -> RetrievalResult:
    """The retrieval with its kept photos' cameras the mapper's, carried into the CAD model's
    frame: turned by the rotation that best carries them onto the retrieved cameras
    (``anchor``), then scaled and moved so that their centres sit nearest the retrieved
    cameras' positions (each at its retrieved distance from the centre, looking along its
    mapped axis); unless ``focal_known``, every camera takes the mapper's focal length. A kept
    photo the mapper did not register is discarded (training leaves it out)."""
    kept = [m for m in retrieval.kept if m.index in mapped.photos]
    if len(kept) < MIN_PHOTOS:
        return retrieval
    unplaced = {m.index for m in retrieval.kept} - set(mapped.photos)
    row = {photo: k for k, photo in enumerate(mapped.photos)}
    mapped_w = np.stack([mapped.c2w[row[m.index], :3, :3].T for m in kept])
    retrieved_w = np.stack([m.c2w[:3, :3].T for m in kept])
    G = anchor(mapped_w, retrieved_w)
    rotations = mapped_w @ G  # world-to-camera in the CAD frame
    centres = np.stack([G.T @ mapped.c2w[row[m.index], :3, 3] for m in kept])
    targets = np.stack([-np.linalg.norm(m.c2w[:3, 3]) * R[2] for m, R in zip(kept, rotations,
                                                                             strict=True)])
    spread = centres - centres.mean(axis=0)
    scale = float(np.sum(spread * (targets - targets.mean(axis=0))) / np.sum(spread * spread))
    shift = targets.mean(axis=0) - scale * centres.mean(axis=0)
    factor = 1.0 if focal_known else mapped.focal / float(retrieval.matches[0].K_photo[0, 0])
    cameras = {}
    for m, rotation, centre in zip(kept, rotations, centres, strict=True):
        c2w = np.eye(4)
        c2w[:3, :3] = rotation.T
        c2w[:3, 3] = scale * centre + shift
        cameras[m.index] = c2w
    matches = [dataclasses.replace(m, discarded=True) if m.index in unplaced else m
               for m in moved_to(scaled_focal(retrieval.matches, factor), cameras)]
    moved = rotation_angle_deg(np.swapaxes(rotations, 1, 2) @ retrieved_w)
    summary = {"photos": sorted(cameras), "start": "mapper", "points": mapped.points,
               "reprojection_px": round(mapped.reprojection_px, 3),
               "moved_deg": round(float(np.median(moved)), 2),
               "focal_factor": round(factor, 4), "unplaced": sorted(unplaced)}
    return dataclasses.replace(retrieval, matches=matches, fusion=summary)


def place_hypotheses(retrieval: RetrievalResult, mapped: Mapped,
                     focal_known: bool) -> RetrievalResult:
    """``place`` applied to the retrieval and to each of its alternatives."""
    placed = place(retrieval, mapped, focal_known)
    others = [place(a, mapped, focal_known) for a in retrieval.alternatives]
    log.info("started from the mapper's cameras (%d points, %.2f px; moved %.1f deg from the "
             "retrieved ones)", mapped.points, mapped.reprojection_px,
             float((placed.fusion or {}).get("moved_deg", 0.0)))
    return dataclasses.replace(placed, alternatives=others)

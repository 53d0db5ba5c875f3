"""Stage 5: every photo's camera: the photos' matches, COLMAP's mapper, fusion with the
retrieved cameras, placement into the CAD frame and the start's choice (``stage``); and the
camera conventions every stage shares (``conventions``).

The names below are the package's public face; each loads its module on first use, so
importing the package costs nothing (torch loads only with what needs it).
"""

from typing import TYPE_CHECKING

from cadnerf_core.cameras.conventions import (  # numpy only: loaded with the package
    CV_TO_GL,
    align_poses,
    from_transforms_json,
    intrinsics_from_fov,
    look_at,
    orbit_pose,
    pose_errors,
    project,
    rotation_angle_deg,
    scale_focal,
    to_transforms_json,
)
from cadnerf_core.facade import lazy_exports

EXPORTS = {
    "stage": ("place_cameras",),
    "matches": ("PairMatch", "match_photos"),
    "pairs_io": ("job_pairs",),
    "mapper": ("Mapped", "map_photos"),
    "fusion": ("fuse", "fuse_hypotheses"),
    "placement": ("place", "place_hypotheses"),
    "start": ("choose_start",),
}
"""Module -> the public names it holds."""
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
__all__ = ["CV_TO_GL", "Mapped", "PairMatch", "align_poses", "choose_start",
    "from_transforms_json", "fuse", "fuse_hypotheses", "intrinsics_from_fov", "job_pairs",
    "look_at", "map_photos", "match_photos", "orbit_pose", "place", "place_cameras",
    "place_hypotheses", "pose_errors", "project", "rotation_angle_deg", "scale_focal",
    "to_transforms_json"]

if TYPE_CHECKING:
    from cadnerf_core.cameras.fusion import fuse, fuse_hypotheses
    from cadnerf_core.cameras.mapper import Mapped, map_photos
    from cadnerf_core.cameras.matches import PairMatch, match_photos
    from cadnerf_core.cameras.pairs_io import job_pairs
    from cadnerf_core.cameras.placement import place, place_hypotheses
    from cadnerf_core.cameras.stage import place_cameras
    from cadnerf_core.cameras.start import choose_start

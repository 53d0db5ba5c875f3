"""The config section of the SIFT matches between photos (``retrieval.matches``,
``cadnerf_core.retrieval.matches``).

Its own module so that ``config`` stays one screenful per section; ``config`` nests it in
``RetrievalConfig`` and re-exports it. Torch-free, like ``config``.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from cadnerf_core.config_bounds import MAX_MATCH_SIZE


class MatchesConfig(BaseModel):
    """SIFT matches between the photos, and what retrieval takes from them."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = True
    """Match the photos (needs them, not only masks) and let the turns between consecutive
    photos tell the walking direction; off, or with too few inliers (a texture-less object),
    retrieval runs on silhouettes and the texture cue alone."""
    size: int = Field(default=640, ge=64, le=MAX_MATCH_SIZE)
    """Long side in pixels of the object's bounding-box crop features are found in (photos are
    only shrunk): about 0.3 s a photo at 640 on a CPU core, whatever the photo's size."""
    min_inliers: int = Field(default=20, ge=8, le=1000)
    """Fewest inliers of the essential matrix for a pair's relative rotation to be used."""
    threshold_px: float = Field(default=1.0, ge=0.1, le=10.0)
    """RANSAC threshold on the epipolar distance, in pixels of the searched crops."""
    min_turn_deg: float = Field(default=3.0, ge=0.0, le=90.0)
    """Turns smaller than this between consecutive photos say nothing about the direction."""
    evidence_per_pair: float = Field(default=2.5, ge=0.0, le=100.0)
    """Direction evidence each consecutive pair with a known turn adds, in the texture cue's
    unit (``RetrievalConfig.appearance_weight`` converts it to IoU; 2.5 is 1 IoU a pair at its
    default 0.2, more than silhouettes' usual lead: verified matches are rarely wrong)."""

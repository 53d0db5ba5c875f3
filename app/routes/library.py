"""`/v1/library`: the CAD models jobs are matched against (read from the manifest, no torch)."""

from __future__ import annotations

import json
from typing import Any

from fastapi import APIRouter

from app.deps import OwnerDep, SettingsDep
from app.errors import ApiError
from app.schemas import ErrorBody, LibraryModel, LibraryPublic, ServiceInfo

router = APIRouter(prefix="/v1", tags=["library"])

MANIFEST = "manifest.json"


def _n_views(spec: Any) -> int | None:
    if not isinstance(spec, dict):
        return None
    azimuths, elevations = spec.get("n_azimuths"), spec.get("elevations")
    if isinstance(azimuths, int) and isinstance(elevations, list):
        return azimuths * len(elevations)
    return None


@router.get("/library", response_model=LibraryPublic, summary="The library's models",
            responses={401: {"model": ErrorBody}, 503: {"model": ErrorBody}})
def get_library(settings: SettingsDep, owner: OwnerDep) -> LibraryPublic:
    """Models (id, category, kind, source, licence, triangles) from the library manifest."""
    del owner  # authentication only
    path = settings.library_dir / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError):
        raise ApiError(503, "library_missing", "the CAD library is not built",
                       hint="run `cadnerf library build`") from None
    entries = manifest.get("models", []) if isinstance(manifest, dict) else []
    models = [LibraryModel.model_validate(e) for e in entries
              if isinstance(e, dict) and isinstance(e.get("id"), str)]
    return LibraryPublic(models=models, n_views=_n_views(manifest.get("spec")))


@router.get("/info", response_model=ServiceInfo, summary="Presets and upload limits",
            responses={401: {"model": ErrorBody}})
def get_info(settings: SettingsDep, owner: OwnerDep) -> ServiceInfo:
    """What the web page (or any client) needs to build a valid upload."""
    del owner
    from cadnerf_core.config import PRESETS  # torch-free by contract

    return ServiceInfo(presets=sorted(PRESETS), default_preset=settings.default_preset,
                       min_photos=settings.min_photos, max_photos=settings.max_photos,
                       max_file_mb=settings.max_file_mb, max_total_mb=settings.max_total_mb,
                       max_megapixels=settings.max_megapixels, min_side_px=settings.min_side_px)

"""`/v1/library`: the CAD models jobs are matched against (read from the manifest, no torch)."""

from __future__ import annotations

import io
import json
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter
from fastapi import Path as PathParam
from fastapi.responses import Response

from app.deps import OwnerDep, SettingsDep, StoreDep
from app.errors import ApiError
from app.routes.usage import limits_public
from app.schemas import ErrorBody, LibraryModel, LibraryPublic, PresetTimePublic, ServiceInfo
from app.settings import Settings
from app.state import default_preset, preset_times, serving_device

router = APIRouter(prefix="/v1", tags=["library"])

MANIFEST = "manifest.json"
SILHOUETTE_CACHE_CONTROL = "private, max-age=3600"
"""A library is rebuilt rarely; an hour keeps the result page's pictures cheap to show again."""


def _n_views(spec: Any) -> int | None:
    if not isinstance(spec, dict):
        return None
    azimuths, elevations = spec.get("n_azimuths"), spec.get("elevations")
    if isinstance(azimuths, int) and isinstance(elevations, list):
        return azimuths * len(elevations)
    return None


def _manifest(settings: Settings) -> dict[str, Any]:
    """The library manifest; 503 when the library is not built."""
    try:
        manifest = json.loads((settings.library_dir / MANIFEST).read_text())
    except (OSError, ValueError):
        raise ApiError(503, "library_missing", "the CAD library is not built",
                       hint="run `cadnerf library build`") from None
    return manifest if isinstance(manifest, dict) else {}


@router.get("/library", response_model=LibraryPublic, summary="The library's models",
            responses={401: {"model": ErrorBody}, 503: {"model": ErrorBody}})
def get_library(settings: SettingsDep, owner: OwnerDep) -> LibraryPublic:
    """Models (id, category, kind, source, licence, triangles) from the library manifest."""
    del owner  # authentication only
    manifest = _manifest(settings)
    entries = manifest.get("models", [])
    models = [LibraryModel.model_validate(e) for e in entries
              if isinstance(e, dict) and isinstance(e.get("id"), str)]
    return LibraryPublic(models=models, n_views=_n_views(manifest.get("spec")))


@router.get("/info", response_model=ServiceInfo, summary="Presets and upload limits",
            responses={401: {"model": ErrorBody}})
def get_info(settings: SettingsDep, store: StoreDep, owner: OwnerDep) -> ServiceInfo:
    """What the web page (or any client) needs to build a valid upload and pick a preset."""
    del owner
    from app.core import PRESETS

    device = serving_device(store.workers, settings.device)
    times = {name: PresetTimePublic(seconds=t.seconds, measured=t.measured)
             for name, t in preset_times(store.history, sorted(PRESETS), device).items()}
    return ServiceInfo(presets=sorted(PRESETS), default_preset=default_preset(settings, device),
                       device=device, preset_times=times,  # type: ignore[arg-type]
                       min_photos=settings.min_photos, max_photos=settings.max_photos,
                       max_file_mb=settings.max_file_mb, max_total_mb=settings.max_total_mb,
                       max_megapixels=settings.max_megapixels, min_side_px=settings.min_side_px,
                       limits=limits_public(settings))


@lru_cache(maxsize=256)
def _silhouette_png(model_dir: Path, view: int, perspective: str, version: int) -> bytes | None:
    """PNG of one canonical silhouette (white = object), None for a view the set lacks.
    ``version`` (the manifest's mtime) keys the cache, so a rebuilt library is read anew."""
    del version
    import numpy as np
    from PIL import Image

    from app.core import library_silhouettes

    bits = library_silhouettes(model_dir, perspective == "near")
    if bits is None or bits.ndim != 3 or view >= bits.shape[0]:
        return None
    crop = np.unpackbits(bits[view], axis=-1, count=bits.shape[1]).astype(np.uint8) * 255
    buffer = io.BytesIO()
    Image.fromarray(crop, "L").save(buffer, format="PNG")
    return buffer.getvalue()


@router.get("/library/{model_id}/silhouette/{view}", response_class=Response,
            summary="A library model's silhouette from one of its views (PNG)",
            responses={200: {"content": {"image/png": {}}}, 401: {"model": ErrorBody},
                       404: {"model": ErrorBody}, 503: {"model": ErrorBody}})
def get_silhouette(settings: SettingsDep, owner: OwnerDep, model_id: str,
                   view: Annotated[int, PathParam(ge=0, le=100_000)],
                   perspective: Literal["far", "near"] = "far") -> Response:
    """The canonical silhouette a photo was matched to (a job result links each photo's)."""
    del owner
    from app.core import LibraryError

    ids = {e.get("id") for e in _manifest(settings).get("models", []) if isinstance(e, dict)}
    if model_id not in ids:  # only manifest ids ever become a path
        raise ApiError(404, "no_such_model", f"no library model {model_id[:80]!r}",
                       field="model_id", hint="see /v1/library for the models")
    version = (settings.library_dir / MANIFEST).stat().st_mtime_ns
    try:
        png = _silhouette_png(settings.library_dir / model_id, view, perspective, version)
    except LibraryError:
        png = None
    if png is None:
        raise ApiError(404, "no_such_view", f"model {model_id!r} has no {perspective} view "
                       f"{view}", field="view", hint="see the result's photos for their views")
    return Response(png, media_type="image/png",
                    headers={"Cache-Control": SILHOUETTE_CACHE_CONTROL})

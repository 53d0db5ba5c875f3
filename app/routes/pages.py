"""The web page at `/` (plain HTML, CSS and JavaScript in app/static) and the browser modules
it loads from npm packages (`/vendor/...`, installed into node_modules by `make setup`)."""

from __future__ import annotations

import mimetypes
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

from app.deps import SettingsDep
from app.errors import ApiError

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"
VENDOR: dict[str, str] = {
    "model-viewer.js": "@google/model-viewer/dist/model-viewer.min.js",
}
"""Browser modules served from our own server (no CDN): name -> file in ``web_modules``."""
# The page is ES modules, which browsers run only when served as JavaScript; some systems' type
# tables (the Windows registry) say text/plain for .js.
mimetypes.add_type("text/javascript", ".js")

router = APIRouter(tags=["pages"])


@router.get("/", include_in_schema=False)
def index() -> FileResponse:
    """The upload-and-watch page."""
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")


@router.get("/vendor/{name}", include_in_schema=False)
def vendor(name: str, settings: SettingsDep) -> FileResponse:
    """A browser module from an installed npm package (``CADNERF_WEB_MODULES``); 404 when it
    is not installed (the page then falls back to what it can do without it)."""
    path = settings.web_modules / VENDOR[name] if name in VENDOR else None
    if path is None or not path.is_file():
        raise ApiError(404, "not_installed", f"no browser module {name[:80]!r} on this server",
                       hint="run `make setup` (npm ci) to install the 3D viewer")
    return FileResponse(path, media_type="text/javascript", headers={"Cache-Control": "no-cache"})

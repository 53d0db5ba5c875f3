"""The web page at `/` (plain HTML, CSS and JavaScript in app/static)."""

from __future__ import annotations

import mimetypes
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"
# The page is ES modules, which browsers run only when served as JavaScript; some systems' type
# tables (the Windows registry) say text/plain for .js.
mimetypes.add_type("text/javascript", ".js")

router = APIRouter(tags=["pages"])


@router.get("/", include_in_schema=False)
def index() -> FileResponse:
    """The upload-and-watch page."""
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")

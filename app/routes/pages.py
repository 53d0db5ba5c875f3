"""The web page at `/` (plain HTML, CSS and JavaScript in app/static)."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"

router = APIRouter(tags=["pages"])


@router.get("/", include_in_schema=False)
def index() -> FileResponse:
    """The upload-and-watch page."""
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")

"""The masks a job uses, checked from the outside: photos and masks go in over HTTP, a real worker
runs the job with the suite's tiny config, and the result says (and shows) which mask each photo
used: its source, its warnings, the mask itself and its overlay as artifacts."""

from __future__ import annotations

import io
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.configs import tiny_request_json

pytestmark = pytest.mark.slow


def _jpeg_on_white(path: Path) -> bytes:
    """A photo without alpha: the RGBA render composited on white, as JPEG."""
    with Image.open(path) as image:
        rgba = image.convert("RGBA")
    white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
    out = io.BytesIO()
    Image.alpha_composite(white, rgba).convert("RGB").save(out, format="JPEG", quality=95)
    return out.getvalue()


def _rectangle_mask(path: Path, shift: int) -> np.ndarray:
    """A mask no background removal would find: the object's bounding box, shrunk by 3 px and
    shifted right by ``shift`` px. Returns [H, W] bool."""
    with Image.open(path) as image:
        alpha = np.asarray(image.convert("RGBA"))[..., 3] > 127
    rows, cols = np.nonzero(alpha)
    mask = np.zeros_like(alpha)
    mask[rows.min() + 3:rows.max() - 2, cols.min() + 3 + shift:cols.max() - 2 + shift] = True
    return mask


def _png(mask: np.ndarray) -> bytes:
    out = io.BytesIO()
    Image.fromarray(mask.astype(np.uint8) * 255, "L").save(out, format="PNG")
    return out.getvalue()


def _run(url: str, files: list[tuple[str, tuple[str, bytes, str]]],
         log_tail: Any) -> tuple[str, dict[str, Any]]:
    """Submit a tiny job, wait for it to succeed; its id and result."""
    response = httpx.post(f"{url}/v1/jobs", files=files, data={"config": tiny_request_json()},
                          timeout=30)
    assert response.status_code == 202, response.text
    job_id = response.json()["id"]
    deadline = time.monotonic() + 300
    status: dict[str, Any] = {}
    while time.monotonic() < deadline:
        status = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).json()
        if status["state"] in ("succeeded", "failed", "cancelled"):
            break
        time.sleep(0.3)
    assert status.get("state") == "succeeded", f"{status}\n{log_tail()}"
    result: dict[str, Any] = httpx.get(f"{url}/v1/jobs/{job_id}/result", timeout=10).json()
    return job_id, result


def _download(url: str, link: str, content_type: str) -> Image.Image:
    """An image artifact (or library picture), decoded."""
    response = httpx.get(f"{url}{link}", timeout=10)
    assert response.status_code == 200 and response.headers["content-type"] == content_type
    image = Image.open(io.BytesIO(response.content))
    image.load()
    return image


def _used_mask(url: str, job_id: str, result: dict[str, Any], index: int) -> np.ndarray:
    """The mask photo ``index`` used (``masks/NNN.png``: 8-bit, 0 or 255), downloaded from the
    job's artifacts; the result's photo names the same file."""
    name = f"masks/{index:03d}.png"
    assert name in result["artifacts"] and result["photos"][index]["mask"] == name
    image = _download(url, f"/v1/jobs/{job_id}/artifacts/{name}", "image/png")
    assert image.mode == "L"
    pixels = np.asarray(image)
    assert set(np.unique(pixels)) <= {0, 255}
    return pixels > 127


def test_uploaded_masks_named_unlike_their_photos_are_the_masks_the_job_uses(
        live_service, photo_set: list[Path]) -> None:
    sources = photo_set[:3]
    masks = [_rectangle_mask(path, shift) for path, shift in zip(sources, (2, -2, 1), strict=True)]
    files = [("images", (f"{stem}.jpg", _jpeg_on_white(path), "image/jpeg"))
             for stem, path in zip("abc", sources, strict=True)]
    files += [("masks", (f"{stem}_mask.png", _png(mask), "image/png"))
              for stem, mask in zip("abc", masks, strict=True)]
    job_id, result = _run(live_service.url, files, live_service.log_tail)
    assert [p["name"] for p in result["photos"]] == ["000_a.jpg", "001_b.jpg", "002_c.jpg"]
    assert [p["mask_source"] for p in result["photos"]] == ["uploaded"] * 3
    for index, mask in enumerate(masks):
        assert np.array_equal(_used_mask(live_service.url, job_id, result, index), mask), index


def test_without_uploaded_masks_a_photo_uses_its_alpha_else_background_removal(
        live_service, photo_set: list[Path]) -> None:
    sources = photo_set[:3]
    files = [("images", ("a.png", sources[0].read_bytes(), "image/png"))]
    files += [("images", (f"{stem}.jpg", _jpeg_on_white(path), "image/jpeg"))
              for stem, path in zip("bc", sources[1:], strict=True)]
    job_id, result = _run(live_service.url, files, live_service.log_tail)
    photos = result["photos"]
    assert photos[0]["mask_source"] == "alpha"
    assert all(p["mask_source"] == "learned" for p in photos[1:])
    assert all(isinstance(p["mask_warnings"], list) for p in photos)
    assert [w for p in photos for w in p["mask_warnings"]] == [
        w for w in result["warnings"]
        if "walking direction" not in w and "focal length" not in w
        and "share too few points" not in w and "The object spans fewer than" not in w]
    # No photo carried EXIF: the result says what to send.
    assert any("focal length (EXIF)" in w for w in result["warnings"])
    with Image.open(sources[0]) as image:
        alpha = np.asarray(image.convert("RGBA"))[..., 3] > 127
    assert np.array_equal(_used_mask(live_service.url, job_id, result, 0), alpha)
    for index, source in enumerate(sources):
        with Image.open(source) as image:
            size = image.size
        assert _used_mask(live_service.url, job_id, result, index).shape == size[::-1]
        name = f"masks/{index:03d}_overlay.jpg"
        assert name in result["artifacts"] and photos[index]["overlay"] == name
        overlay = _download(live_service.url, f"/v1/jobs/{job_id}/artifacts/{name}", "image/jpeg")
        assert overlay.size == size and overlay.mode == "RGB"
    matched = [p for p in photos if not p["discarded"]]
    assert matched and all(isinstance(p["view"], int) for p in matched)
    model = result["model"]
    near = "?perspective=near" if model["perspective"] == "near" else ""
    silhouette = _download(live_service.url, f"/v1/library/{model['id']}/silhouette/"
                           f"{matched[0]['view']}{near}", "image/png")
    assert silhouette.size[0] == silhouette.size[1] > 0

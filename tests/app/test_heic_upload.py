"""HEIC (and AVIF) photos over HTTP: sniffed from their content, checked from their header, and
stored so that the job reads them upright with their EXIF focal length."""

from __future__ import annotations

import io

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image, features

from app.main import create_app
from app.settings import Settings
from app.uploads import PHOTO_TYPES, sniff_type
from cadnerf_core.intake.photos import load_photo
from cadnerf_core.jobfolder import JobFolder
from tests.app.conftest import MakeSettings
from tests.app.images import image_bytes
from tests.configs import tiny_request_json
from tests.heic_images import claiming_size, gradient, phone_photo, stored_pixels

Files = list[tuple[str, tuple[str, bytes, str]]]


def _phone_files(n: int = 3, fmt: str = "HEIF") -> Files:
    """``n`` upright 96x64 photos stored portrait (EXIF orientation 6), 35 mm focal 26."""
    ext, media = {"HEIF": ("HEIC", "image/heic"), "AVIF": ("avif", "image/avif")}[fmt]
    return [("images", (f"IMG_{i:04d}.{ext}", phone_photo(gradient(96, 64), 6, 26, fmt), media))
            for i in range(n)]


def _stored_masks(n: int = 3) -> tuple[Files, np.ndarray]:
    """PNG masks drawn on the stored (portrait) pixels, and the upright mask they show."""
    upright = np.zeros((64, 96), np.uint8)
    upright[16:48, 24:72] = 255
    upright[:8, :8] = 255  # top-left marker: a wrong turn would move it
    buffer = io.BytesIO()
    Image.fromarray(stored_pixels(upright, 6)).save(buffer, format="PNG")
    return [("masks", (f"mask_{i}.png", buffer.getvalue(), "image/png")) for i in range(n)], \
        upright > 0


def test_a_heic_set_is_accepted_and_the_job_reads_it_upright(client: TestClient,
                                                             settings: Settings) -> None:
    masks, upright_mask = _stored_masks()
    response = client.post("/v1/jobs", files=_phone_files() + masks,
                           data={"config": tiny_request_json()})
    assert response.status_code == 202, response.text
    folder = JobFolder(settings.data_root / response.json()["id"])
    inputs = folder.photos()
    assert [p.path.name for p in inputs] == [
        "000_IMG_0000.heic", "001_IMG_0001.heic", "002_IMG_0002.heic"]
    for entry in inputs:  # what the job will read
        assert entry.mask is not None
        photo = load_photo(entry.path, entry.index, entry.mask)
        assert photo.rgb.shape == (64, 96, 3) and photo.focal_35mm == 26.0
        assert np.abs(photo.rgb * 255.0 - gradient(96, 64)).mean() < 4.0
        assert photo.mask is not None and np.array_equal(photo.mask, upright_mask)


@pytest.mark.skipif(not features.check("avif"), reason="this Pillow was built without AVIF")
def test_an_avif_set_is_accepted(client: TestClient, settings: Settings) -> None:
    response = client.post("/v1/jobs", files=_phone_files(3, "AVIF"),
                           data={"config": tiny_request_json()})
    assert response.status_code == 202, response.text
    inputs = JobFolder(settings.data_root / response.json()["id"]).photos()
    assert [p.path.suffix for p in inputs] == [".avif"] * 3
    photo = load_photo(inputs[0].path)
    assert photo.rgb.shape == (64, 96, 3) and photo.focal_35mm == 26.0


def test_a_heic_mask_of_the_wrong_size_names_the_photo(client: TestClient) -> None:
    wrong = [("masks", (f"m{i}.png", image_bytes((80, 64)), "image/png")) for i in range(3)]
    response = client.post("/v1/jobs", files=_phone_files() + wrong)
    assert response.status_code == 422
    error = response.json()["error"]
    assert error["code"] == "mask_size" and error["photo"] == "IMG_0000.HEIC"
    assert "the photo is 96x64" in error["message"]  # its upright size


def test_a_heic_mask_is_refused_as_a_mask(client: TestClient) -> None:
    photos = [("images", (f"p{i}.png", image_bytes((80, 64)), "image/png")) for i in range(3)]
    heic_mask = phone_photo(np.full((64, 80, 3), 255, np.uint8), 1, None)
    masks = [("masks", (f"m{i}.heic", heic_mask, "image/heic")) for i in range(3)]
    response = client.post("/v1/jobs", files=photos + masks)
    assert response.status_code == 415
    error = response.json()["error"]
    assert error["code"] == "unsupported_image_type" and error["photo"] == "m0.heic"
    assert "PNG" in error["hint"] and "HEIC" not in error["hint"]


def test_size_limits_hold_for_heic(make_settings: MakeSettings) -> None:
    settings = make_settings(max_megapixels=0.005)  # 96x64 is 0.006 MP
    with TestClient(create_app(settings)) as client:
        response = client.post("/v1/jobs", files=_phone_files())
    assert response.status_code == 422
    assert response.json()["error"]["code"] == "image_too_large"


@pytest.mark.parametrize("side", [8000, 20000])  # over the limit; over Pillow's bomb limit
def test_a_heic_claiming_too_many_pixels_is_refused_from_its_header(client: TestClient,
                                                                    side: int) -> None:
    files = _phone_files()
    name, data, media = files[0][1]
    files[0] = ("images", (name, claiming_size(data, side), media))
    response = client.post("/v1/jobs", files=files)
    assert response.status_code == 422
    error = response.json()["error"]
    assert error["code"] == "image_too_large" and error["photo"] == "IMG_0000.HEIC"


def test_a_truncated_heic_is_refused_naming_the_photo(client: TestClient) -> None:
    files = _phone_files()
    name, data, media = files[1][1]
    files[1] = ("images", (name, data[: len(data) // 2], media))
    response = client.post("/v1/jobs", files=files)
    assert response.status_code == 422
    error = response.json()["error"]
    assert error["code"] == "unreadable_image" and error["photo"] == "IMG_0001.HEIC"


def _ftyp(major: bytes, *compatible: bytes) -> bytes:
    body = major + b"\0\0\0\0" + b"".join(compatible)
    return (8 + len(body)).to_bytes(4, "big") + b"ftyp" + body + b"\0\0\0\x08meta"


@pytest.mark.parametrize(("head", "expected"), [
    (_ftyp(b"heic", b"mif1", b"heic"), "heic"),
    (_ftyp(b"heix", b"mif1"), "heic"),
    (_ftyp(b"mif1", b"mif1", b"heic"), "heic"),  # generic major brand, codec in the list
    (_ftyp(b"mif1", b"mif1", b"miaf"), "heif"),
    (_ftyp(b"avif", b"avif", b"mif1"), "avif"),
    (_ftyp(b"mif1", b"mif1", b"avif"), "avif"),
    (_ftyp(b"isom", b"isom", b"mp41"), None),  # an MP4 video
    (_ftyp(b"hevc", b"mif1"), None),  # an image sequence (a burst), not a photo
])
def test_the_type_is_read_from_the_ftyp_box(head: bytes, expected: str | None) -> None:
    assert sniff_type(head) == expected


def test_heic_is_a_photo_type_and_avif_where_pillow_reads_it() -> None:
    assert {"heic", "heif"} <= PHOTO_TYPES
    assert ("avif" in PHOTO_TYPES) == features.check("avif")

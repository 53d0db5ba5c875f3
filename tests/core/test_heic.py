"""Phone formats: HEIC (and AVIF where Pillow reads it) come out upright, rotated once, with
their EXIF focal length, through intake and through a whole ``cadnerf reconstruct`` job."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image, features

from cadnerf_core.errors import InputError
from cadnerf_core.intake.photos import PHOTO_FORMATS, load_photo
from cadnerf_core.jobfolder import JobFolder
from tests.configs import tiny_cli_options
from tests.heic_images import claiming_size, gradient, phone_photo, stored_pixels

FORMATS = ["HEIF", pytest.param("AVIF", marks=pytest.mark.skipif(
    not features.check("avif"), reason="this Pillow was built without AVIF"))]


def _error(photo: np.ndarray, upright: np.ndarray) -> float:
    """Mean absolute difference in 8-bit levels (inf for another shape)."""
    if photo.shape != upright.shape:
        return float("inf")
    return float(np.abs(photo * 255.0 - upright).mean())


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("orientation", [1, 3, 6, 8, 5])
def test_a_phone_photo_comes_out_upright_once_with_its_focal(fmt: str, orientation: int) -> None:
    upright = gradient(96, 64)
    photo = load_photo(("IMG_0001.HEIC", phone_photo(upright, orientation, 26, fmt)))
    assert photo.rgb.shape == (64, 96, 3)
    error = _error(photo.rgb, upright)
    assert error < 4.0  # lossy coding only
    # Not left as stored, nor turned twice (a second turn by the EXIF tag).
    stored = stored_pixels(upright, orientation)
    twice = np.asarray(Image.fromarray(upright).transpose(
        {1: Image.Transpose.ROTATE_180, 3: Image.Transpose.ROTATE_90,
         6: Image.Transpose.ROTATE_270, 8: Image.Transpose.ROTATE_90,
         5: Image.Transpose.ROTATE_90}[orientation]))
    for wrong in ([stored] if orientation != 1 else []) + [twice]:
        assert _error(photo.rgb, wrong) > 10 * error + 10
    assert photo.focal_35mm == 26.0
    assert photo.focal_pixels == pytest.approx(26.0 * np.hypot(96, 64) / np.hypot(36, 24))
    assert photo.mask is None and photo.mask_source is None


def test_heic_is_a_photo_format_and_avif_follows_pillow() -> None:
    assert "HEIF" in PHOTO_FORMATS
    assert ("AVIF" in PHOTO_FORMATS) == features.check("avif")


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_mask_drawn_on_the_stored_pixels_is_turned_like_its_photo(fmt: str) -> None:
    upright_mask = np.zeros((64, 96), np.uint8)
    upright_mask[:20, :30] = 255  # top-left once upright
    buffer = io.BytesIO()
    Image.fromarray(stored_pixels(upright_mask, 6)).save(buffer, format="PNG")
    assert Image.open(buffer).size == (64, 96)  # the stored pixels are portrait
    photo = load_photo(("p.heic", phone_photo(gradient(96, 64), 6, 26, fmt)), 0,
                       ("m.png", buffer.getvalue()))
    assert photo.mask is not None and photo.mask_source == "uploaded"
    assert np.array_equal(photo.mask, upright_mask > 0)
    # A mask already drawn upright is kept as it is.
    buffer = io.BytesIO()
    Image.fromarray(upright_mask).save(buffer, format="PNG")
    photo = load_photo(("p.heic", phone_photo(gradient(96, 64), 6, 26, fmt)), 0,
                       ("m.png", buffer.getvalue()))
    assert photo.mask is not None and np.array_equal(photo.mask, upright_mask > 0)


def test_a_damaged_heic_is_refused_naming_the_photo() -> None:
    data = phone_photo(gradient(96, 64), 6, 26)
    with pytest.raises(InputError) as caught:
        load_photo(("IMG_0002.HEIC", data[: len(data) // 2]))
    assert caught.value.item == "IMG_0002.HEIC"


def test_a_heic_claiming_too_many_pixels_is_refused_before_decoding() -> None:
    data = claiming_size(phone_photo(gradient(96, 64), 6, 26), 8000)
    with pytest.raises(InputError, match="8000x8000 pixels, over 40 megapixels"):
        load_photo(("IMG_0003.HEIC", data))


def _render_phone_job(src: Path, library: Any, n: int = 3) -> tuple[list[Path], list[Path],
                                                                   list[np.ndarray]]:
    """HEIC photos (orientation 6, 35 mm focal 37) of the library's mug walking round it, with
    PNG masks drawn on their stored (portrait) pixels; returns photos, masks, upright masks."""
    from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
    from cadnerf_core.mesh.renderer import MeshRenderer

    renderer = MeshRenderer(library.mesh("mug"))
    K = intrinsics_from_fov(40.0, 64)
    K[0, 2] += 16  # an 96x64 landscape photo, the object in the middle
    photos, masks, uprights = [], [], []
    src.mkdir()
    for i in range(n):
        result = renderer.render(K, orbit_pose(20.0 + 50.0 * i, 20.0, 4.0), 96, 64)
        rgb = (result.rgb * 255).astype(np.uint8)
        photos.append(src / f"IMG_{i:04d}.HEIC")
        photos[-1].write_bytes(phone_photo(rgb, 6, 37))
        masks.append(src / f"mask_{i}.png")
        mask = result.mask.astype(np.uint8) * 255
        Image.fromarray(stored_pixels(mask, 6)).save(masks[-1])
        uprights.append(result.mask.astype(bool))
    return photos, masks, uprights


@pytest.mark.usefixtures("one_torch_thread")
def test_cli_reconstructs_from_heic_keeping_orientation_and_focal(
        tmp_path: Path, tiny_library: Any, tiny_library_dir: Path) -> None:
    from typer.testing import CliRunner

    from cadnerf_cli.main import app

    photos, masks, uprights = _render_phone_job(tmp_path / "phone", tiny_library)
    out = tmp_path / "job"
    result = CliRunner().invoke(app, ["reconstruct", *map(str, photos), "--out", str(out),
                                      *[arg for m in masks for arg in ("--masks", str(m))],
                                      *tiny_cli_options(), "--device", "cpu", "--library",
                                      str(tiny_library_dir), "--walk", "ccw"])
    assert result.exit_code == 0, result.output
    folder = JobFolder(out)
    assert [p.path.name for p in folder.photos()] == [
        "000_IMG_0000.heic", "001_IMG_0001.heic", "002_IMG_0002.heic"]
    assert [m.source for m in folder.read_mask_sources()] == ["uploaded"] * 3
    for i, upright in enumerate(uprights):  # the stored-pixel masks were turned upright
        assert np.array_equal(folder.read_mask(i), upright)
    assert (out / "mesh.glb").is_file()
    retrieved = CliRunner().invoke(app, ["retrieve", *map(str, photos), "--json", "--library",
                                         str(tiny_library_dir), "--walk", "ccw",
                                         *[arg for m in masks for arg in ("--masks", str(m))]])
    assert retrieved.exit_code == 0, retrieved.output
    for retrieval in (folder.read_retrieval(), json.loads(retrieved.stdout)):
        assert retrieval is not None and retrieval["model_id"] == "mug"
        _assert_upright_with_exif_focal(retrieval, focal_35mm=37.0, width=96, height=64)


def _assert_upright_with_exif_focal(retrieval: dict[str, Any], focal_35mm: float, width: int,
                                    height: int) -> None:
    """Every photo's camera has the EXIF focal length and its principal point near the middle
    of the upright photo (not of the stored, turned one)."""
    focal_pixels = focal_35mm * np.hypot(width, height) / np.hypot(36, 24)
    for match in retrieval["matches"]:
        K = np.asarray(match["K_photo"])
        assert K[0, 0] == pytest.approx(focal_pixels, rel=1e-4)
        assert abs(K[0, 2] - width / 2) < 6.0 and abs(K[1, 2] - height / 2) < 6.0

"""Photo intake: formats, EXIF, alpha, masks, and errors that name the photo."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cadnerf_core.errors import InputError
from cadnerf_core.intake.photos import canonical_masks, canonical_views, load_photos


def _gradient(width: int, height: int) -> np.ndarray:
    """RGB uint8 [H, W, 3] whose red grows to the right and green downward."""
    x = np.linspace(0, 255, width)[None, :].repeat(height, 0)
    y = np.linspace(0, 255, height)[:, None].repeat(width, 1)
    return np.stack([x, y, np.full_like(x, 60)], -1).astype(np.uint8)


def _save(path: Path, array: np.ndarray, fmt: str = "PNG", **kwargs: object) -> Path:
    Image.fromarray(array).save(path, format=fmt, **kwargs)
    return path


def test_reads_jpeg_png_webp_of_different_sizes(tmp_path: Path) -> None:
    paths = [_save(tmp_path / "a.jpg", _gradient(80, 64), "JPEG"),
             _save(tmp_path / "b.png", _gradient(200, 120)),
             _save(tmp_path / "c.webp", _gradient(64, 96), "WEBP", lossless=True)]
    photos = load_photos(paths)
    assert [p.name for p in photos] == ["a.jpg", "b.png", "c.webp"]
    assert [p.rgb.shape for p in photos] == [(64, 80, 3), (120, 200, 3), (96, 64, 3)]
    for photo in photos:
        assert photo.rgb.dtype == np.float32 and photo.mask is None
        assert photo.rgb.min() >= 0.0 and photo.rgb.max() <= 1.0
    assert np.allclose(photos[2].rgb * 255, _gradient(64, 96), atol=0.5)


def test_bytes_and_named_bytes_are_accepted(tmp_path: Path) -> None:
    data = _save(tmp_path / "a.png", _gradient(70, 70)).read_bytes()
    photos = load_photos([data, ("mine.png", data)])
    assert [p.name for p in photos] == ["photo 1", "mine.png"]


def test_exif_rotated_jpeg_comes_out_upright(tmp_path: Path) -> None:
    stored = _gradient(120, 80)  # stored landscape; orientation 6 = shown rotated 90 cw
    exif = Image.Exif()
    exif[0x0112] = 6
    path = tmp_path / "rot.jpg"
    Image.fromarray(stored).save(path, format="JPEG", exif=exif.tobytes(), quality=95)
    photo = load_photos([path])[0]
    assert photo.rgb.shape == (120, 80, 3)
    # Rotated clockwise: the stored left column (red 0) becomes the top row.
    assert photo.rgb[0, :, 0].mean() < 0.1 and photo.rgb[-1, :, 0].mean() > 0.9


def test_mask_drawn_on_stored_pixels_of_a_rotated_photo_is_rotated_too(tmp_path: Path) -> None:
    exif = Image.Exif()
    exif[0x0112] = 6
    photo_path = tmp_path / "rot.jpg"
    Image.fromarray(_gradient(120, 80)).save(photo_path, format="JPEG", exif=exif.tobytes())
    stored_mask = np.zeros((80, 120), np.uint8)
    stored_mask[:, :30] = 255  # left of the stored pixels = top once upright
    photo = load_photos([photo_path], [_save(tmp_path / "m.png", stored_mask)])[0]
    assert photo.mask is not None and photo.mask.shape == (120, 80)
    assert photo.mask[:30].all() and not photo.mask[30:].any()


def test_rgba_alpha_becomes_the_mask_and_rgb_is_on_white(tmp_path: Path) -> None:
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[..., 0] = 255
    rgba[16:48, 16:48, 3] = 255
    rgba[0, 0, 3] = 100  # below one half: background
    photo = load_photos([_save(tmp_path / "a.png", rgba)])[0]
    assert photo.mask is not None
    assert photo.mask.sum() == 32 * 32 and photo.mask[16:48, 16:48].all()
    assert np.allclose(photo.rgb[20, 20], [1.0, 0.0, 0.0])
    assert np.allclose(photo.rgb[2, 2], [1.0, 1.0, 1.0])  # transparent -> white
    opaque = rgba.copy()
    opaque[..., 3] = 255
    assert load_photos([_save(tmp_path / "b.png", opaque)])[0].mask is None


def test_user_masks_follow_photo_order(tmp_path: Path) -> None:
    photos = [_save(tmp_path / f"{i}.png", _gradient(64, 64)) for i in range(2)]
    masks = []
    for i in range(2):
        mask = np.zeros((64, 64), np.uint8)
        mask[: 10 * (i + 1)] = 1  # nonzero = object, any value
        masks.append(_save(tmp_path / f"m{i}.png", mask))
    loaded = load_photos(photos, masks)
    assert [int(p.mask.sum()) for p in loaded if p.mask is not None] == [640, 1280]


@pytest.mark.parametrize("case", ["empty", "truncated", "text", "tiny", "mask_size",
                                  "mask_count", "missing"])
def test_bad_inputs_raise_input_error_naming_the_photo(tmp_path: Path, case: str) -> None:
    good = _save(tmp_path / "good.png", _gradient(64, 64))
    bad = tmp_path / "bad.jpg"
    masks = None
    if case == "empty":
        bad.write_bytes(b"")
    elif case == "truncated":
        buffer = io.BytesIO()
        Image.fromarray(_gradient(256, 256)).save(buffer, format="JPEG")
        bad.write_bytes(buffer.getvalue()[: len(buffer.getvalue()) // 2])
    elif case == "text":
        bad.write_text("this is not a photo\n")
    elif case == "tiny":
        _save(bad, _gradient(63, 200), "JPEG")
    elif case == "missing":
        bad = tmp_path / "nowhere" / "bad.jpg"
    else:
        _save(bad, _gradient(64, 64), "JPEG")
        masks = [good, _save(tmp_path / "m.png", np.ones((65, 64), np.uint8))]
        if case == "mask_count":
            masks = masks[:1]
    with pytest.raises(InputError) as info:
        load_photos([good, bad], masks)
    expected = "masks" if case == "mask_count" else "bad.jpg"
    assert info.value.item == expected and info.value.hint
    assert str(info.value).startswith(expected)


def test_huge_photo_is_refused_from_its_header(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    path = _save(tmp_path / "big.png", _gradient(300, 200))
    monkeypatch.setattr("cadnerf_core.intake.photos.MAX_PIXELS", 50_000)
    loaded = []
    monkeypatch.setattr(Image.Image, "load", lambda self: loaded.append(1))
    with pytest.raises(InputError, match="megapixels") as info:
        load_photos([path])
    assert info.value.item == "big.png" and not loaded  # refused before decoding


def test_canonical_views_frame_the_object_like_the_library(tmp_path: Path) -> None:
    rgb = np.zeros((100, 160, 3), np.float32)
    rgb[..., 2] = 1.0
    mask = np.zeros((100, 160), bool)
    mask[20:60, 90:110] = True  # 40 tall, 20 wide, off-centre
    from cadnerf_core.intake.photos import Photo

    images, crops, boxes = canonical_views([Photo("a", rgb, mask)], [mask], 50, margin=0.1)
    assert images.shape == (1, 50, 50, 3) and crops.shape == (1, 50, 50)
    rows, cols = np.nonzero(crops[0])
    assert rows.min() == 5 and rows.max() == 44  # object spans 1 - 2 * margin of the crop
    assert np.allclose(images[0, 25, 25], [0, 0, 1]) and np.allclose(images[0, 25, 2], 1.0)
    assert boxes[0].side == pytest.approx(50.0)
    again, _ = canonical_masks([mask], 50, margin=0.1)
    assert np.array_equal(again, crops)


def test_a_phones_exif_focal_length_is_kept_in_pixels(tmp_path: Path) -> None:
    exif = Image.Exif()
    exif[0x0112] = 6  # rotated: the focal length does not care
    exif.get_ifd(0x8769)[0xA405] = 27  # FocalLengthIn35mmFilm, as a Pixel phone writes it
    phone = tmp_path / "phone.jpg"
    Image.fromarray(_gradient(400, 300)).save(phone, format="JPEG", exif=exif.tobytes())
    zero = Image.Exif()
    zero.get_ifd(0x8769)[0xA405] = 0  # "unknown" in the EXIF standard
    unknown = _save(tmp_path / "unknown.jpg", _gradient(400, 300), "JPEG", exif=zero.tobytes())
    plain = _save(tmp_path / "plain.png", _gradient(400, 300))
    photos = load_photos([phone, unknown, plain])
    assert photos[0].focal_35mm == 27.0
    # 27 mm on the 43.27 mm full-frame diagonal, over a 500 px diagonal.
    assert photos[0].focal_pixels == pytest.approx(27.0 * 500.0 / np.hypot(36.0, 24.0))
    assert [p.focal_35mm for p in photos[1:]] == [None, None]
    assert [p.focal_pixels for p in photos[1:]] == [None, None]


def test_a_cameras_focal_length_comes_from_its_focal_plane_resolution(tmp_path: Path) -> None:
    from PIL.TiffImagePlugin import IFDRational

    # A camera that writes no 35 mm equivalent: 4.25 mm on a 5.6 x 4.2 mm sensor (7 mm
    # diagonal) whose 4000 x 3000 pixels are saved downscaled to 400 x 300.
    exif = Image.Exif()
    tags = exif.get_ifd(0x8769)
    tags[0x920A] = IFDRational(425, 100)  # FocalLength
    tags[0xA002], tags[0xA003] = 4000, 3000  # PixelX/YDimension of the sensor's image
    tags[0xA20E] = tags[0xA20F] = IFDRational(400000, 56)  # pixels per cm: 4000 px / 0.56 cm
    tags[0xA210] = 3  # centimetres
    camera = _save(tmp_path / "camera.jpg", _gradient(400, 300), "JPEG", exif=exif.tobytes())
    inch = Image.Exif()
    inch_tags = inch.get_ifd(0x8769)
    inch_tags[0x920A] = IFDRational(425, 100)
    inch_tags[0xA20E] = inch_tags[0xA20F] = IFDRational(400 * 254, 56)  # per inch, 400 px
    no_unit = _save(tmp_path / "inch.jpg", _gradient(400, 300), "JPEG", exif=inch.tobytes())
    partial = Image.Exif()
    partial.get_ifd(0x8769)[0x920A] = IFDRational(425, 100)  # no sensor size: unknown
    bare = _save(tmp_path / "partial.jpg", _gradient(400, 300), "JPEG", exif=partial.tobytes())
    photos = load_photos([camera, no_unit, bare])
    expected = 4.25 * np.hypot(36.0, 24.0) / 7.0  # 26.3 mm equivalent
    assert photos[0].focal_35mm == pytest.approx(expected, rel=1e-3)
    # The default unit is the inch and the stored size stands in for the pixel dimensions.
    assert photos[1].focal_35mm == pytest.approx(expected, rel=1e-3)
    assert photos[2].focal_35mm is None
    # The focal length in pixels of the saved photo: 4.25 mm at 400 px / 5.6 mm.
    assert photos[0].focal_pixels == pytest.approx(4.25 * 400 / 5.6, rel=1e-3)


def test_shipped_phone_photos_carry_their_focal_length() -> None:
    folder = Path(__file__).resolve().parents[2] / ".." / "shared" / "eval" / "photos" / \
        "ners_espresso" / "images"
    if not folder.is_dir():
        pytest.skip("../shared/eval is absent")
    photos = load_photos(sorted(folder.glob("*.jpg"))[:2])
    assert all(p.focal_35mm is not None and 10.0 < p.focal_35mm < 100.0 for p in photos)


@pytest.mark.parametrize("fmt", ["JPEG", "PNG"])
def test_a_photo_over_the_working_size_is_worked_on_scaled_down(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fmt: str) -> None:
    """A photo over ``WORKING_PIXELS`` comes out at that many pixels, aspect kept, its uploaded
    mask scaled alike (nearest: still 0/1), and its uploaded size kept for the exports."""
    monkeypatch.setattr("cadnerf_core.intake.limits.WORKING_PIXELS", 20_000)
    path = _save(tmp_path / f"big.{fmt.lower()}", _gradient(400, 200), fmt)
    mask = np.zeros((200, 400), np.uint8)
    mask[50:150, 100:300] = 255
    [photo] = load_photos([path], [_save(tmp_path / "mask.png", mask)])
    height, width = photo.rgb.shape[:2]
    assert width * height <= 20_000 and abs(width / height - 2.0) < 0.05
    assert photo.size == (400, 200) and photo.scale == pytest.approx(400 / width)
    assert photo.mask is not None and photo.mask.shape == (height, width)
    assert photo.mask.mean() == pytest.approx(0.25, abs=0.03)
    # The gradient survives the scaling: red still grows to the right.
    assert photo.rgb[height // 2, -1, 0] > photo.rgb[height // 2, 0, 0] + 0.8
    small = _save(tmp_path / "small.png", _gradient(100, 100))
    [kept] = load_photos([small])
    assert kept.rgb.shape == (100, 100, 3) and kept.scale == 1.0


@pytest.mark.parametrize(("width", "height"), [(64, 2000), (1000, 100)])
def test_a_strip_is_refused_naming_the_photo(tmp_path: Path, width: int, height: int) -> None:
    path = _save(tmp_path / "strip.png", _gradient(width, height))
    with pytest.raises(InputError, match="times longer than wide") as info:
        load_photos([path])
    assert info.value.item == "strip.png" and info.value.hint

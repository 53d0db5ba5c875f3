"""``cadnerf masks``: mask files of the photo's size, overlays, the method and the warnings."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from cadnerf_cli.main import app


def _write_photo(path: Path, width: int = 160, height: int = 120, orientation: int = 1) -> None:
    """A red box on a grey wall, saved as JPEG with an EXIF orientation."""
    rgb = np.full((height, width, 3), 200, np.uint8)
    cv2.rectangle(rgb, (width // 3, height // 4), (2 * width // 3, 3 * height // 4),
                  (200, 30, 20), -1)
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(rgb).save(path, exif=exif, quality=95)


def test_cli_writes_masks_of_the_photo_size_and_prints_the_method(tmp_path: Path) -> None:
    photos = [tmp_path / "a.jpg", tmp_path / "b.jpg"]
    _write_photo(photos[0])
    _write_photo(photos[1], orientation=6)  # shown rotated: 120 wide, 160 high
    out = tmp_path / "masks"
    result = CliRunner().invoke(app, ["masks", *map(str, photos), "--out", str(out),
                                      "--method", "grabcut"])
    assert result.exit_code == 0, result.output
    assert "000 a.jpg: grabcut" in result.output and "001 b.jpg: grabcut" in result.output
    for name, size in (("000", (160, 120)), ("001", (120, 160))):
        mask = Image.open(out / f"{name}.png")
        assert mask.mode == "L" and mask.size == size
        values = np.asarray(mask)
        assert set(np.unique(values)) == {0, 255}
        assert Image.open(out / f"{name}_overlay.jpg").size == size
    # The box covers the middle third by half of the photo: its mask does too.
    values = np.asarray(Image.open(out / "000.png")) > 0
    assert values[60, 80] and not values[5, 5] and 0.1 < values.mean() < 0.35


def test_cli_json_lists_each_photo_and_its_warnings(tmp_path: Path) -> None:
    photo = tmp_path / "a.jpg"
    _write_photo(photo)
    result = CliRunner().invoke(app, ["masks", str(photo), "--out", str(tmp_path / "m"),
                                      "--method", "grabcut", "--json"])
    assert result.exit_code == 0, result.output
    records = json.loads(result.output)
    assert [r["photo"] for r in records] == ["a.jpg"] and records[0]["method"] == "grabcut"
    assert records[0]["warnings"] == [] and Path(records[0]["mask"]).is_file()


@pytest.mark.parametrize("method", ["auto", "learned"])
def test_cli_missing_user_model_is_a_clear_error(tmp_path: Path, method: str) -> None:
    photo = tmp_path / "a.jpg"
    _write_photo(photo)
    result = CliRunner().invoke(app, ["masks", str(photo), "--out", str(tmp_path / "m"),
                                      "--method", method, "--mask-model",
                                      str(tmp_path / "mine.onnx")])
    assert result.exit_code == 2
    assert "mine.onnx" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "m").exists()

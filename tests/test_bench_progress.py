"""The preview-job benchmark's pieces (``benchmarks.bench_progress``): a capture's photos as a
phone uploads them, the command that measures a job, and which runs become headline figures."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from benchmarks import bench_progress
from tests.core.test_eval_captures import BACKGROUND, make_capture


def test_a_capture_becomes_phone_photos_with_their_focal_length(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from cadnerf_core.intake.photos import FULL_FRAME_DIAGONAL_MM, exif_focal_35mm

    shutil.move(make_capture(tmp_path, views=3, size=64), tmp_path / "captures" / "box")
    monkeypatch.setattr(bench_progress, "CAPTURES", tmp_path / "captures")
    paths = bench_progress.phone_photos("box", 2, 400, tmp_path / "phone")
    assert [p.name for p in paths] == ["000.jpg", "001.jpg"]  # the first two of three
    frame = json.loads((tmp_path / "captures" / "box" / "cameras.json").read_text())["frames"][0]
    with Image.open(paths[0]) as photo:
        assert photo.format == "JPEG" and photo.size == (400, 400)
        focal_35mm = exif_focal_35mm(photo)
        big = np.asarray(photo.convert("RGB"))
    # The focal length grows with the photo: the same field of view.
    expected = frame["K"][0][0] * 400 / 64 * FULL_FRAME_DIAGONAL_MM / np.hypot(400, 400)
    assert focal_35mm == pytest.approx(round(expected))
    # The background stays in (the job makes its own masks).
    assert (np.abs(big.astype(int) - BACKGROUND).sum(-1) < 30).mean() > 0.2


def test_the_command_names_the_job_and_its_settings() -> None:
    walk = {"mesh": "ycb_mug", "fov": 40.0, "capture": None, "threads": 2, "settings": {}}
    assert bench_progress.command(walk, False) == (
        "python -m benchmarks.bench_progress --mesh ycb_mug --fov 40 --threads 2")
    user = {**walk, "capture": "temple_ring", "settings": {"export.orbit_size": 512}}
    assert bench_progress.command(user, True) == (
        "python -m benchmarks.bench_progress --capture temple_ring --threads 2 "
        "--set export.orbit_size=512 --quick")


def test_only_default_full_runs_become_headline_figures(monkeypatch: pytest.MonkeyPatch,
                                                        tmp_path: Path) -> None:
    from benchmarks import results

    monkeypatch.setattr(results, "RESULTS", tmp_path / "results.json")
    base = {"mesh": "ycb_mug", "fov": 40.0, "threads": 2, "settings": {}, "total_s": 150.0}
    bench_progress.record_job({**base, "capture": "temple_ring", "photos": 10}, quick=False)
    bench_progress.record_job({**base, "capture": "temple_ring", "photos": 10,
                               "settings": {"seed": 1}, "total_s": 99.0}, quick=False)
    bench_progress.record_job({**base, "capture": None, "photos": 6, "total_s": 140.0},
                              quick=True)
    found = results.read_results()
    assert found["preview_job_photos"].value == 150.0
    assert "10 phone photos" in found["preview_job_photos"].quantity
    assert found["preview_job_photos"].command.endswith("--capture temple_ring --threads 2")
    assert "preview_job_cpu" not in found

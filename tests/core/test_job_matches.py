"""A job's matches: stored in the job folder and read back instead of matching again, a
picture of each neighbouring pair among the artifacts, the cameras fused with them, and a
warning when the photos share too little."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
from cadnerf_core.job_warnings import MATCHES_FEW_WARNING, too_small_warning
from cadnerf_core.jobfolder import JobFolder
from cadnerf_core.progress import Progress
from tests.configs import tiny_config
from tests.core.test_matches import _ball

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SIZE = 192


def _job(job_dir: Path, textured: bool, size: int = SIZE, **overrides: Any) -> JobFolder:
    from cadnerf_core.mesh.renderer import MeshRenderer

    renderer = MeshRenderer(_ball(textured))
    K = intrinsics_from_fov(40.0, size)
    folder = JobFolder(job_dir)
    for i in range(5):
        shot = renderer.render(K, orbit_pose(30.0 * i, 20.0, 3.0), size, size)
        rgba = np.dstack([(shot.rgb * 255).astype(np.uint8), shot.mask.astype(np.uint8) * 255])
        Image.fromarray(rgba, "RGBA").save(folder.new_photo_path(i, "p", "png"))
    folder.write_config(tiny_config(**overrides))
    return folder


def _intake(job_dir: Path, library: Any) -> Any:
    from cadnerf_core.pipeline import read_job_config, run_intake

    return run_intake(job_dir, library, read_job_config(job_dir), Progress())


def test_matches_are_kept_pictured_and_fused(tmp_path: Path, tiny_library: Any,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    from cadnerf_core.retrieval import search as retrieve

    folder = _job(tmp_path, textured=True)
    intake = _intake(tmp_path, tiny_library)
    data = folder.read_retrieval()
    assert data is not None
    with_rotation = [p for p in data["photo_pairs"] if p["turn_deg"] is not None]
    assert len(with_rotation) >= 4
    assert len(data["fusion"]["photos"]) >= 3
    assert all("c2w_retrieved" in m for m in data["matches"]
               if m["index"] in data["fusion"]["photos"])
    assert intake.retrieval.fusion == data["fusion"]
    pictures = [n for n in folder.artifacts() if n.startswith("matches/")]
    assert pictures == ["matches/000_001.jpg", "matches/000_004.jpg", "matches/001_002.jpg",
                        "matches/002_003.jpg", "matches/003_004.jpg"]
    with Image.open(folder.file("matches/000_001.jpg")) as picture:
        assert picture.height == 480 and picture.width == 2 * 480
    assert "matches/pairs.npz" not in folder.artifacts()  # kept, not offered

    def fail(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("the stored matches must be read, not made again")

    monkeypatch.setattr(retrieve, "photo_pairs", fail)
    again = _intake(tmp_path, tiny_library)
    assert [p.to_json() for p in again.retrieval.pairs] == \
        [p.to_json() for p in intake.retrieval.pairs]
    folder.write_config(tiny_config(retrieval={"hypotheses": 1, "matches": {"size": 512}}))
    with pytest.raises(AssertionError, match="stored matches"):
        _intake(tmp_path, tiny_library)  # other settings: matched again


def test_photos_sharing_nothing_train_on_silhouettes_and_say_so(tmp_path: Path,
                                                                 tiny_library: Any) -> None:
    folder = _job(tmp_path, textured=False)
    intake = _intake(tmp_path, tiny_library)
    data = folder.read_retrieval()
    assert data is not None and data["fusion"]["photos"] == []
    assert all("c2w_retrieved" not in m for m in data["matches"])
    assert all(np.array_equal(m.c2w, np.array(d["c2w"]))
               for m, d in zip(intake.retrieval.matches, data["matches"], strict=True))
    assert MATCHES_FEW_WARNING in (folder.read_warnings() or [])


def test_photos_too_small_to_match_are_named_in_the_warnings(tmp_path: Path,
                                                             tiny_library: Any) -> None:
    # The textured ball whose pairs are fused at 192 px spans about 75 px at 96 px.
    folder = _job(tmp_path, textured=True, size=SIZE // 2)
    intake = _intake(tmp_path, tiny_library)
    data = folder.read_retrieval()
    assert data is not None and data["too_small"] == [0, 1, 2, 3, 4]
    assert intake.retrieval.too_small == [0, 1, 2, 3, 4]
    assert all(p["inliers"] == 0 for p in data["photo_pairs"])
    names = [m["name"] for m in sorted(data["matches"], key=lambda m: m["index"])]
    warnings = folder.read_warnings() or []
    assert warnings[-1] == too_small_warning(names) and MATCHES_FEW_WARNING not in warnings


def test_matching_off_neither_fuses_nor_warns(tmp_path: Path, tiny_library: Any) -> None:
    folder = _job(tmp_path, textured=True,
                  retrieval={"hypotheses": 1, "matches": {"enabled": False}})
    _intake(tmp_path, tiny_library)
    data = folder.read_retrieval()
    assert data is not None and "fusion" not in data and "photo_pairs" not in data
    assert folder.read_warnings() is not None
    assert MATCHES_FEW_WARNING not in (folder.read_warnings() or [])
    assert not (tmp_path / "matches").exists()
    assert json.loads((tmp_path / "config.json").read_text())["retrieval"]["matches"][
        "enabled"] is False

"""The job's result: the photos' entries (each camera, how it was placed), and the file's round
trip."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from cadnerf_core.export.result import job_result
from cadnerf_core.intake.crop import CropBox
from cadnerf_core.jobfolder import JobFolder, MaskRecord
from cadnerf_core.jobresult import JobResult, PhotoResult
from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult


def _retrieval(fusion: dict[str, object] | None, order: list[int]) -> RetrievalResult:
    matches = [PhotoMatch(index=i, name=f"00{i}_p.png", view=4 * i, azimuth=40.0 * i,
                          elevation=20.0, iou=0.8, discarded=i == 2, c2w=np.eye(4),
                          K_canon=np.eye(3), box=CropBox(0.0, 0.0, 64.0, 64),
                          K_photo=np.eye(3)) for i in range(3)]
    return RetrievalResult(model_id="mug_02", category="mug", top_models=[], matches=matches,
                           solver="dp", direction=1, score=2.4, perspective="near",
                           fusion=fusion, order=order, reordered=order != [0, 1, 2])


def _poses() -> list[dict[str, object]]:
    return [{"index": i, "name": f"00{i}_p.png", "discarded": i == 2, "iou": 0.8,
             "c2w": None if i == 2 else (2 * np.eye(4)).tolist(), "c2w_initial": np.eye(4).tolist(),
             "K_photo": np.eye(3).tolist(), "width": 640, "height": 480,
             "placed": None if i == 2 else "matches", "confidence": None if i == 2 else 0.9}
            for i in range(3)]


def test_the_result_holds_each_photos_camera_metrics_mask_and_the_walk() -> None:
    metrics = {"photos": [{"name": "000_p.png", "psnr": float("inf"), "ssim": 0.9,
                           "pose_change_deg": 1.5}, {"name": "001_p.png", "psnr": 20.0}],
               "mean_psnr": 20.0, "mean_ssim": 0.8, "device": "cpu",
               "timings_s": {"phase1_s": 2.0}}
    masks = [MaskRecord(index=i, name=f"00{i}_p.png", source="alpha", mask=f"masks/00{i}.png",
                        warnings=[f"00{i}_p.png: the mask touches the border"] if i == 1 else [])
             for i in range(3)]
    result = job_result(_retrieval({"photos": [0, 1], "start": "mapper"}, [1, 2, 0]), _poses(),
                        metrics, masks, ["orbit.mp4"])
    first, second, third = result.photos
    assert result.model.id == "mug_02" and result.model.perspective == "near"
    assert first.psnr is None and first.ssim == 0.9 and second.psnr == 20.0  # inf: no JSON
    assert first.placement == "matches" and first.confidence == 0.9  # as poses.json says
    assert third.placement is None and third.confidence is None and third.discarded
    assert third.c2w is None and third.K is None and third.c2w_initial is not None
    assert first.c2w == (2 * np.eye(4)).tolist() and first.width == 640
    assert (first.view, second.azimuth) == (0, 40.0)
    assert result.discarded == ["002_p.png"] and result.reordered
    assert result.order == ["001_p.png", "002_p.png", "000_p.png"]
    assert second.mask_warnings and result.warnings[0] == second.mask_warnings[0]
    assert not any("walked in this order" in w for w in result.warnings)  # asked: "walk"
    assert result.metrics.timings_s == {"phase1_s": 2.0} and result.artifacts == ["orbit.mp4"]


def test_the_file_reads_back_equal_and_refuses_another_shape(tmp_path: Path) -> None:
    result = job_result(_retrieval(None, []), _poses(), {"mean_psnr": 19.0}, [], ["a.png"])
    folder = JobFolder(tmp_path)
    assert folder.read_result() is None
    folder.write_result(result)
    assert folder.read_result() == result
    assert JobResult.model_validate(json.loads(folder.file("result.json").read_text())) == result
    folder.file("result.json").write_text(json.dumps({**result.model_dump(), "extra": 1}))
    with pytest.raises(ValueError):
        folder.read_result()
    with pytest.raises(ValidationError):
        PhotoResult(index=0, name="a", discarded=False, confidence=1.5)

"""End to end over HTTP: a real worker process runs the real pipeline (the suite's tiny config)."""

from __future__ import annotations

import json
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.configs import TINY_OVERRIDES, TINY_PRESET, tiny_request

pytestmark = pytest.mark.slow


def _submit(url: str, photos: list[Path], config: dict[str, Any]) -> dict[str, Any]:
    with ExitStack() as stack:
        files = [("images", (p.name, stack.enter_context(p.open("rb")), "image/png"))
                 for p in photos]
        response = httpx.post(f"{url}/v1/jobs", files=files,
                              data={"config": json.dumps(config)}, timeout=30)
    assert response.status_code == 202, response.text
    return response.json()


def _follow(url: str, job_id: str, timeout_s: float, until: tuple[str, ...] = (
        "succeeded", "failed", "cancelled")) -> list[dict[str, Any]]:
    seen = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).json()
        seen.append(status)
        if status["state"] in until:
            return seen
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} did not reach {until}: last {seen[-1]}")


def test_a_job_runs_to_its_artifacts(live_service, photo_set: list[Path]) -> None:
    url = live_service.url
    job = _submit(url, photo_set, tiny_request())
    seen = _follow(url, job["id"], timeout_s=300)
    final = seen[-1]
    assert final["state"] == "succeeded", f"{final}\n{live_service.log_tail()}"
    assert final["progress"] == 1.0 and final["started_at"] <= final["finished_at"]
    progress = [s["progress"] for s in seen]
    assert progress == sorted(progress)  # never goes backwards
    result = httpx.get(f"{url}/v1/jobs/{job['id']}/result", timeout=10).json()
    assert result["model"]["id"] and len(result["photos"]) == len(photo_set)
    kept = [p for p in result["photos"] if not p["discarded"]]
    assert len(kept) >= len(photo_set) - 2
    for photo in kept:
        assert 0.0 <= photo["iou"] <= 1.0 and len(photo["c2w"]) == 4
    base = f"{url}/v1/jobs/{job['id']}/artifacts"
    video = httpx.get(f"{base}/orbit.mp4", timeout=10)
    assert video.headers["content-type"] == "video/mp4" and video.content[4:8] == b"ftyp"
    head = httpx.get(f"{base}/orbit.mp4", headers={"Range": "bytes=0-99"}, timeout=10)
    assert head.status_code == 206 and head.content == video.content[:100]
    assert httpx.get(f"{base}/mesh.glb", timeout=10).content[:4] == b"glTF"
    poses = httpx.get(f"{base}/poses.json", timeout=10).json()
    assert poses
    transforms = httpx.get(f"{base}/transforms.json", timeout=10).json()
    assert "camera_angle_x" in transforms and transforms["frames"]
    assert set(result["artifacts"]) >= {"orbit.mp4", "orbit.gif", "mesh.glb", "poses.json",
                                        "transforms.json", "metrics.json"}
    folder = live_service.settings.data_root / job["id"]
    assert json.loads((folder / "state.json").read_text())["state"] == "succeeded"


def test_delete_stops_a_running_job_within_seconds(live_service, photo_set: list[Path]) -> None:
    url = live_service.url
    # Long enough to be caught in phase three; the core reports (and checks) 50 times a phase.
    slow = tiny_request(phase3={"steps": 10000})
    job = _submit(url, photo_set, slow)
    deadline = time.monotonic() + 180
    status = {}
    while time.monotonic() < deadline:  # wait until it is deep in training
        status = httpx.get(f"{url}/v1/jobs/{job['id']}", timeout=10).json()
        if status["stage"] == "phase3" or status["state"] not in ("queued", "running"):
            break
        time.sleep(0.2)
    assert status["state"] == "running" and status["stage"] == "phase3", status
    started = time.monotonic()
    response = httpx.delete(f"{url}/v1/jobs/{job['id']}", timeout=60)
    assert response.status_code == 200
    assert response.json()["worker_stopped"] is True, live_service.log_tail()
    assert time.monotonic() - started < 15
    assert httpx.get(f"{url}/v1/jobs/{job['id']}", timeout=10).status_code == 404
    assert not (live_service.settings.data_root / job["id"]).exists()
    # The worker is free again: a new job runs to the end.
    again = _submit(url, photo_set, tiny_request())
    assert _follow(url, again["id"], timeout_s=300)[-1]["state"] == "succeeded"


def test_an_unusable_photo_fails_the_job_with_its_name(live_service, tmp_path: Path) -> None:
    from PIL import Image

    blank = []
    for i in range(3):  # uniform photos: no object to find
        path = tmp_path / f"blank_{i}.png"
        Image.new("RGB", (64, 64), "white").save(path)
        blank.append(path)
    job = _submit(live_service.url, blank, tiny_request())
    final = _follow(live_service.url, job["id"], timeout_s=120)[-1]
    assert final["state"] == "failed" and "blank_0.png" in final["error"], final


def test_the_demo_command_follows_a_job_to_its_orbit(live_service, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    from cadnerf_cli.service_cmd import run_demo

    final = run_demo(live_service.url, preset=TINY_PRESET, overrides=TINY_OVERRIDES, views=4,
                     size=64, out=tmp_path)
    assert final["state"] == "succeeded"
    assert (tmp_path / "orbit.mp4").read_bytes()[4:8] == b"ftyp"
    printed = capsys.readouterr().out
    assert f"/v1/jobs/{final['id']}/artifacts/orbit.mp4" in printed and "%" in printed
    # The demo tells its renders' lens: no warning asks for EXIF the renders cannot carry.
    from cadnerf_core.job_warnings import FOCAL_UNKNOWN_WARNING

    assert FOCAL_UNKNOWN_WARNING not in printed

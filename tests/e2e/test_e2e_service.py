"""End to end over HTTP: a real worker process runs the real pipeline (the suite's tiny config)."""

from __future__ import annotations

import json
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import httpx
import pytest

from app.embedded import free_port
from cadnerf_core.config_bounds import MAX_STEPS
from tests.configs import TINY_PRESET, tiny_request
from tests.e2e.conftest import _start_api

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
        "succeeded", "failed", "cancelled"), stage: str | None = None) -> list[dict[str, Any]]:
    """The job's statuses until its state is in ``until`` (and its stage ``stage``, when
    given), or it ended; ``timeout_s`` only guards against a hang."""
    seen = []
    give_up = time.monotonic() + timeout_s
    while time.monotonic() < give_up:
        status = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).json()
        seen.append(status)
        if status["state"] in until and stage in (None, status["stage"]):
            return seen
        if status["state"] in ("succeeded", "failed", "cancelled"):
            break
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} did not reach {until} (stage {stage}): "
                         f"last {seen[-1]}")


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
    written = httpx.get(f"{url}/v1/jobs/{job['id']}/artifacts/result.json", timeout=10)
    assert written.json() == result  # the pipeline's result.json is the API's result
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


def test_delete_stops_a_running_job(live_service, photo_set: list[Path]) -> None:
    """DELETE of a job deep in phase three answers once the worker stopped it at a step. This
    API waits up to a minute for that (a guard against a hang, not a measure); phase three at
    the step bound could not end by itself in that minute, so ``worker_stopped`` says the
    cancel reached the running job, not that the job ran out."""
    settings = live_service.settings.model_copy(update={"delete_wait_s": 60.0})
    server, thread = _start_api(settings, port := free_port())
    url = f"http://127.0.0.1:{port}"
    try:
        job = _submit(url, photo_set, tiny_request(phase3={"steps": MAX_STEPS}))
        status = _follow(url, job["id"], timeout_s=300, until=("running",),
                         stage="phase3")[-1]
        assert status["state"] == "running" and status["stage"] == "phase3", status
        response = httpx.delete(f"{url}/v1/jobs/{job['id']}", timeout=120)
        assert response.status_code == 200
        assert response.json()["worker_stopped"] is True, \
            f"the worker did not stop the job within a minute of DELETE\n{live_service.log_tail()}"
        assert httpx.get(f"{url}/v1/jobs/{job['id']}", timeout=10).status_code == 404
        assert not (settings.data_root / job["id"]).exists()
        # The worker is free again: a new job runs to the end.
        again = _submit(url, photo_set, tiny_request())
        assert _follow(url, again["id"], timeout_s=300)[-1]["state"] == "succeeded"
    finally:
        server.should_exit = True  # type: ignore[attr-defined]
        thread.join(15)


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


def test_the_demo_command_follows_a_job_to_its_orbit_and_says_what_to_open(
        live_service, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The demo's flow at a tiny size, matching off (the photos' own matching is the slow part
    of a demo job; ``tests/core/test_demo_photos.py`` checks the photos are matchable)."""
    from cadnerf_cli.demo_cmd import run_demo
    from cadnerf_core.job_warnings import FOCAL_UNKNOWN_WARNING

    final = run_demo(live_service.url, preset=TINY_PRESET, views=4, size=96, out=tmp_path,
                     overrides={"seed": 1, "retrieval": {"matches": {"enabled": False}}})
    assert final["state"] == "succeeded"
    assert (tmp_path / "orbit.mp4").read_bytes()[4:8] == b"ftyp"
    printed = capsys.readouterr().out
    lines = printed.splitlines()
    assert lines[-2] == f"open the result page: {live_service.url}/?job={final['id']}"
    assert lines[-1].startswith(f"the orbit video: {tmp_path / 'orbit.mp4'} ")
    assert "%" in printed  # the progress was shown
    assert FOCAL_UNKNOWN_WARNING not in printed  # the photos' EXIF gives the lens

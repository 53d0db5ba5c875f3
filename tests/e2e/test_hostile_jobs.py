"""What a hostile but legitimate client sends, over HTTP to a real API and worker: configs that
would hold a worker for days, photos and masks the worker cannot use, and a delete while the
job still renders."""

from __future__ import annotations

import io
import json
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import redis
from PIL import Image

from app.embedded import free_port
from app.state import StageHistory, keys, stage_work
from app.state.eta import expected_job_seconds, preset_history
from cadnerf_core.config import resolve_config
from tests.configs import TINY_OVERRIDES, TINY_PRESET, tiny_request
from tests.e2e.conftest import _start_api
from tests.reliability.jobs import submit, wait_state

pytestmark = pytest.mark.slow


def _png(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, format="PNG")
    return buffer.getvalue()


def _post(url: str, files: list[Any], config: dict[str, Any] | None = None) -> httpx.Response:
    data = {"config": json.dumps(config or {"preset": TINY_PRESET})}
    return httpx.post(f"{url}/v1/jobs", files=files, data=data, timeout=60)


def _photos(photo_set: list[Path]) -> list[Any]:
    return [("images", (p.name, p.read_bytes(), "image/png")) for p in photo_set[:3]]


# Settings a client may send answer with their bound; the preset's own values (rays, samples,
# learning rates, widths, which could multiply past memory) are refused as settings at all
# (their bounds and the points budget: tests/core/test_config.py).
NOT_A_SETTING = "not a setting a client may send"


@pytest.mark.parametrize(("overrides", "field", "bound"), [
    ({"phase3.steps": 1e9}, "phase3.steps", "50000"),
    ({"export.orbit_frames": 720, "export.orbit_size": 2048}, "export.orbit_frames", "240"),
    ({"export.orbit_size": 2048}, "export.orbit_size", "1024"),
    ({"export.mesh_resolution": 512}, "export.mesh_resolution", "256"),
    ({"export.texture_size": 1e9}, "export.texture_size", "4096"),
    ({"image_size": 4096}, "image_size", "1024"),
    ({"seed": 1e23}, "seed", "2147483647"),
    ({"phase1.batch_points": 1e9}, "phase1.batch_points", NOT_A_SETTING),
    ({"phase2.rays": 1e9}, "phase2.rays", NOT_A_SETTING),
    ({"render.samples_per_ray": 1024}, "render.samples_per_ray", NOT_A_SETTING),
    ({"phase3.lr": 1e308}, "phase3.lr", NOT_A_SETTING),
    ({"phase2": {"pose_lr": 1e308}}, "phase2.pose_lr", NOT_A_SETTING),
    ({"field.hidden": 512}, "field.hidden", NOT_A_SETTING),
])
def test_configs_that_scale_work_past_their_bounds_answer_422(
        live_service, photo_set: list[Path], overrides: dict[str, Any], field: str,
        bound: str) -> None:
    response = _post(live_service.url, _photos(photo_set),
                     {"preset": TINY_PRESET, "overrides": overrides})
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == "invalid_config" and error["field"] == "config"
    assert field in error["message"] and bound in error["message"], error


def test_strips_and_unusable_masks_answer_422_naming_the_photo(live_service,
                                                                photo_set: list[Path]) -> None:
    url = live_service.url
    for width, height in ((64, 20000), (100, 10000)):
        files = _photos(photo_set)
        strip = np.full((height, width, 3), 200, np.uint8)
        files[1] = ("images", ("strip.png", _png(strip), "image/png"))
        response = _post(url, files)
        assert response.status_code == 422, response.text
        error = response.json()["error"]
        assert error["code"] == "image_shape" and error["photo"] == "strip.png", error
        assert f"{width}x{height}" in error["message"] and error["hint"]
    size = Image.open(photo_set[0]).size[::-1]
    good = np.zeros(size, np.uint8)
    good[size[0] // 4: 3 * size[0] // 4, size[1] // 4: 3 * size[1] // 4] = 255
    for name, bad in (("white", np.full(size, 255, np.uint8)), ("black", np.zeros(size, np.uint8))):
        masks = [("masks", (f"m{i}.png", _png(good), "image/png")) for i in range(3)]
        masks[2] = ("masks", (f"{name}.png", _png(bad), "image/png"))
        response = _post(url, _photos(photo_set) + masks)
        assert response.status_code == 422, response.text
        error = response.json()["error"]
        assert error["code"] == "mask_unusable" and error["photo"] == photo_set[2].name, error
        assert error["field"] == "masks" and "send no mask" in error["hint"]
    assert not [p for p in live_service.settings.data_root.iterdir() if not p.name.startswith(".")]


def test_a_job_deleted_while_rendering_stays_deleted(live_service,
                                                     photo_set: list[Path]) -> None:
    """DELETE while the worker renders views, answered without waiting for the worker (so it
    is still inside a view when the folder goes): after the worker has moved on (the next job
    done) the job is in neither GET, the list, Redis's running set nor on disk, also after
    the heartbeats and the orphan grace period that once brought it back."""
    settings = live_service.settings.model_copy(update={"delete_wait_s": 0.0})
    server, thread = _start_api(settings, port := free_port())
    url, root = f"http://127.0.0.1:{port}", settings.data_root
    try:
        slow_views = tiny_request(image_size=128, export={"novel_views": 64})
        job_id = submit(url, photo_set, slow_views)["id"]
        wait_state(url, job_id, 240, until=("running",), stage="render", every_s=0.05,
                   context=live_service.log_tail)
        answer = httpx.delete(f"{url}/v1/jobs/{job_id}", timeout=60)
        assert answer.status_code == 200 and answer.json()["deleted"] is True
        assert not (root / job_id).exists()
        follow = submit(url, photo_set, tiny_request())["id"]
        final, _ = wait_state(url, follow, 240, context=live_service.log_tail)
        assert final["state"] == "succeeded", live_service.log_tail()
        time.sleep(8)  # heartbeats (every 1.5 s) and one orphan grace (5 s) later
        client = redis.Redis.from_url(settings.redis_url, decode_responses=True)
        assert httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).status_code == 404
        listed = httpx.get(f"{url}/v1/jobs", params={"limit": 100}, timeout=10).json()["items"]
        assert job_id not in {item["id"] for item in listed}
        assert not client.sismember(keys.RUNNING, job_id) and not client.exists(keys.job(job_id))
        assert not [p for p in root.iterdir() if job_id in p.name], list(root.iterdir())
    finally:
        server.should_exit = True  # type: ignore[attr-defined]
        thread.join(15)


def test_a_queued_job_with_ten_times_the_steps_expects_that_much_longer(
        live_service, photo_set: list[Path]) -> None:
    """Against the live worker: one tiny job done (the measured history), one holding the
    worker, then plain, ten times the steps, plain queued behind it. In one listing, each
    queued job's ETA exceeds the one before it by that job's own expected seconds; the longer
    job's own seconds are its preset's measured ones scaled by ``stage_work``, more than the
    plain one's."""
    url = live_service.url
    done = submit(url, photo_set, tiny_request())["id"]
    assert wait_state(url, done, 240, context=live_service.log_tail)[0]["state"] == "succeeded", \
        live_service.log_tail()
    blocker = submit(url, photo_set, tiny_request(phase3={"steps": 20000}))["id"]
    queued: list[str] = []
    try:
        wait_state(url, blocker, 240, until=("running",), context=live_service.log_tail)
        steps = {phase: {"steps": 10 * TINY_OVERRIDES[phase]["steps"]}
                 for phase in ("phase1", "phase2", "phase3")}
        configs = [tiny_request(), tiny_request(**steps), tiny_request()]
        queued = [submit(url, photo_set, config)["id"] for config in configs]
        listed = httpx.get(f"{url}/v1/jobs", params={"limit": 100}, timeout=10).json()["items"]
        jobs = {item["id"]: item for item in listed}
        assert [jobs[i]["state"] for i in queued] == ["queued"] * 3, listed
        assert [jobs[i]["queue_position"] for i in queued] == [0, 1, 2], listed
        first, longer, last = (float(jobs[i]["eta_s"]) for i in queued)
        own_plain, own_longer = last - longer, longer - first  # one worker: nothing divided
        client = redis.Redis.from_url(live_service.settings.redis_url, decode_responses=True)
        measured = preset_history(StageHistory(client).measured("cpu"), TINY_PRESET)
        assert measured, "the finished job left no measured stage times"
        expect = [expected_job_seconds(TINY_PRESET, "cpu", measured,
                                       stage_work(resolve_config(c["preset"], c["overrides"])))
                  for c in configs[:2]]
        assert own_plain == pytest.approx(expect[0], abs=0.25), (own_plain, expect, jobs)
        assert own_longer == pytest.approx(expect[1], abs=0.25), (own_longer, expect, jobs)
        assert own_longer > own_plain > 0
    finally:
        for job_id in [*queued, blocker]:  # the queued ones first: the worker takes none
            httpx.delete(f"{url}/v1/jobs/{job_id}", timeout=60)

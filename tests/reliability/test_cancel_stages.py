"""Cancel during every stage: the job ends `cancelled` in the stage it was cancelled in (a
checkpoint inside the stage saw the flag; it did not run the stage out), and the worker is free
for the next job. The cancel is the one DELETE sends (the job's Redis flag), set as soon as the
job reports the stage; each job is made long in its target stage by its config. How soon the
job stops is not measured here (``tests/core/test_nerf_phases.py`` checks that training looks
at every step); waits only guard against a hang."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest

from cadnerf_core.config_bounds import MAX_STEPS
from cadnerf_core.progress import STAGES
from tests.configs import tiny_request
from tests.reliability import jobs
from tests.reliability.support import NEEDS_PIPELINE, Live, pipeline_ready, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not pipeline_ready(), reason=NEEDS_PIPELINE)]

LONG = MAX_STEPS  # the most steps accepted; progress comes every LONG / 50 of them
# The config that keeps a job in each stage for seconds, and the photos it needs.
PLANS: dict[str, tuple[dict[str, Any], str]] = {
    "masks": ({}, "plain"),  # ten photos without alpha: background removal per photo
    "retrieval": ({}, "plain"),
    "phase1": ({"phase1": {"steps": LONG}}, "rgba"),
    "phase2": ({"phase2": {"steps": 3000}}, "rgba"),
    "phase3": ({"phase3": {"steps": 3000}}, "rgba"),
    "render": ({"image_size": 256, "export": {"novel_views": 64}}, "rgba"),
    "export": ({"export": {"mesh_resolution": 192}}, "rgba"),  # marching cubes on 192^3 points
}
HANG_S = 120.0  # a wait that only guards against a hang
# Stages too short to be caught every time (under a second on the tiny library): the cancel may
# land in a later stage (phase one of the tiny config is a few steps too); the job must still end
# cancelled, at the latest in phase two.
SHORT = ("masks", "retrieval")


@pytest.fixture(scope="module")
def plain_photos(photo_set: list[Path], tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Ten 384 px RGB photos (no alpha) of the box, so masks are found by GrabCut."""
    from PIL import Image

    folder = tmp_path_factory.mktemp("plain")
    out = []
    for i in range(10):
        with Image.open(photo_set[i % len(photo_set)]) as rgba:
            white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
            flat = Image.alpha_composite(white, rgba.convert("RGBA")).convert("RGB")
        path = folder / f"plain_{i:02d}.png"
        flat.resize((384, 384)).save(path)
        out.append(path)
    return out


@pytest.mark.parametrize("stage", STAGES)
def test_cancel_in_each_stage(service: Live, photo_set: list[Path], plain_photos: list[Path],
                              stage: str) -> None:
    from app.state import JobStore, connect

    overrides, photos = PLANS[stage]
    job = jobs.submit(service.url, plain_photos if photos == "plain" else photo_set,
                      tiny_request(**overrides))
    seen, _ = jobs.wait_state(service.url, job["id"], 240, until=("running",), stage=stage,
                              every_s=0.02)
    store = JobStore(connect(service.env["CADNERF_REDIS_URL"]), service.data_root)
    try:
        store.request_cancel(job["id"])  # what DELETE does before it waits and removes
        try:
            final, _ = jobs.wait_state(service.url, job["id"], HANG_S, every_s=0.05)
        except AssertionError as exc:
            raise AssertionError(f"the job did not stop after a cancel in {stage}: {exc}\n"
                                 f"{service.logs()}") from None
    finally:
        store.close()
        if jobs.status(service.url, job["id"])["state"] == "running":  # free the worker
            httpx.delete(f"{service.url}/v1/jobs/{job['id']}", timeout=60)
    assert final["state"] == "cancelled", f"{final}\n{service.logs()}"
    ended = STAGES.index(final["stage"])
    latest = STAGES.index("phase2") if stage in SHORT else STAGES.index(stage)
    assert STAGES.index(stage) <= ended <= latest, \
        f"cancelled in {stage} but stopped in {final['stage']} ({seen})"
    assert jobs.status(service.url, job["id"])["state"] == "cancelled"  # and it stays so
    assert httpx.delete(f"{service.url}/v1/jobs/{job['id']}", timeout=30).status_code == 200
    assert wait_for(lambda: not (service.data_root / job["id"]).exists(), HANG_S), \
        "the deleted job's folder stayed"

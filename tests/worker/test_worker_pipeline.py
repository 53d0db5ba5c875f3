"""The runner around the real pipeline (the suite's tiny config and library), in this process."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.settings import load_settings
from app.state import STAGES, JobState, JobStore, keys
from cadnerf_core.jobfolder import JobFolder
from tests.configs import TINY_PRESET, tiny_config
from worker import runner

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def renders(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Four 64 px RGBA renders of a box walked around."""
    import trimesh

    from cadnerf_core.evaluation.dataset import render_dataset

    folder = tmp_path_factory.mktemp("renders")
    trimesh.creation.box((1.0, 0.6, 0.4)).export(folder / "box.ply")
    dataset = render_dataset(folder / "box.ply", folder / "dataset", n_views=4, size=64, seed=1)
    return sorted((dataset / "images").glob("*.png"))


def test_a_job_runs_to_succeeded_with_progress_and_measured_stage_times(
        store: JobStore, new_job, redis_url: str, tiny_library_dir: Path,
        renders: list[Path], clean_redis) -> None:
    record = new_job()
    folder = store.job_dir(record.id)
    job = JobFolder(folder)
    for index, path in enumerate(renders):
        job.add_photo(index, path)
    job.write_config(tiny_config())
    settings = load_settings(redis_url=redis_url, data_root=store.data_root,
                             library_dir=tiny_library_dir, device="cpu")
    updates: list[dict] = []
    outcome = runner.execute(record.id, settings, store, updates.append)
    assert outcome == {"id": record.id, "state": "succeeded", "error": None}
    final = store.get(record.id)
    assert final is not None and final.state == JobState.succeeded and final.progress == 1.0
    assert final.started_at is not None and final.finished_at is not None
    stages = [u["stage"] for u in updates]
    assert stages and set(stages) <= set(STAGES) and "phase1" in stages
    fractions = [u["progress"] for u in updates]
    assert fractions == sorted(fractions)
    measured = clean_redis.hgetall(keys.stage_seconds("cpu"))  # this device's history only
    assert set(measured) >= {f"{TINY_PRESET}/retrieval", f"{TINY_PRESET}/phase1"}
    assert all(float(v) > 0 for v in measured.values())
    assert clean_redis.hgetall(keys.stage_seconds("cuda")) == {}
    assert store.history.expected(TINY_PRESET, "cpu")["phase1"] == pytest.approx(
        float(measured[f"{TINY_PRESET}/phase1"]))
    assert json.loads((folder / "state.json").read_text())["state"] == "succeeded"
    assert (folder / "orbit.mp4").is_file() and (folder / "poses.json").is_file()

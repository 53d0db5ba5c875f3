"""The mask benchmark's training comparison: both jobs get the values a lever sets."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from PIL import Image

from benchmarks import bench_masks
from benchmarks.lookalikes import excluded
from cadnerf_core import pipeline
from cadnerf_core.jobfolder import JobFolder


def _photos(folder: Path, count: int) -> tuple[list[Path], list[Path]]:
    """``count`` small photos of a grey square and their masks."""
    paths, masks = [], []
    for i in range(count):
        rgb = np.full((48, 64, 3), 250, np.uint8)
        rgb[12:36, 20:44] = 90
        mask = np.zeros((48, 64), np.uint8)
        mask[12:36, 20:44] = 255
        paths.append(folder / f"p{i}.png")
        masks.append(folder / f"p{i}_mask.png")
        Image.fromarray(rgb).save(paths[-1])
        Image.fromarray(mask).save(masks[-1])
    return paths, masks


def test_training_sets_the_overrides_in_both_jobs(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[dict[str, Any]] = []

    def fake_job(job: Path, library: Any, *args: Any) -> SimpleNamespace:
        folder = JobFolder(job)
        config = folder.read_config()
        seen.append({"doubt": config.masks.doubt_weight, "seed": config.seed,
                     "exclude": list(config.retrieval.exclude_models)})
        folder.write_metrics({"mean_psnr": 20.0 + len(seen)})
        return SimpleNamespace(model=SimpleNamespace(id=f"model{len(seen)}"))

    monkeypatch.setattr(pipeline, "run_job", fake_job)
    paths, masks = _photos(tmp_path, 3)
    line = bench_masks.training("ners_espresso", paths, masks, None,
                                {"masks.doubt_weight": 0, "seed": 3})
    assert [s["doubt"] for s in seen] == [0.0, 0.0] and [s["seed"] for s in seen] == [3, 3]
    # The set's look-alike (the espresso machine) left out of both jobs' libraries.
    assert seen[0]["exclude"] == seen[1]["exclude"] == list(excluded("ners_espresso"))
    assert seen[0]["exclude"]
    assert "built-in masks 21.00 dB (model1), shipped masks 22.00 dB (model2)" in line
    assert "difference -1.00 dB" in line


def test_training_runs_both_jobs_for_each_seed_and_reports_the_mean(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seeds: list[int] = []
    psnr = {0: (24.0, 26.0), 1: (25.0, 25.5)}  # seed: (built-in, shipped)

    def fake_job(job: Path, library: Any, *args: Any) -> SimpleNamespace:
        folder = JobFolder(job)
        seed = folder.read_config().seed
        shipped = len(seeds) % 2  # each seed: the built-in masks' job, then the shipped one's
        seeds.append(seed)
        folder.write_metrics({"mean_psnr": psnr[seed][shipped]})
        return SimpleNamespace(model=SimpleNamespace(id="m"))

    monkeypatch.setattr(pipeline, "run_job", fake_job)
    paths, masks = _photos(tmp_path, 3)
    line = bench_masks.training("raydiffusion_robot", paths, masks, None, seeds=(0, 1))
    assert seeds == [0, 0, 1, 1]
    assert "built-in masks **24.50** dB, shipped masks **25.75** dB" in line
    assert "difference **-1.25 dB**" in line
    assert "seed 0: built-in masks 24.00 dB (m), shipped masks 26.00 dB (m), " \
           "difference -2.00 dB" in line


def test_walk_scores_rank_the_model_the_masks_were_drawn_from_first(tiny_library: Any) -> None:
    # Masks drawn from the mug's own silhouettes along a walk (every other azimuth, level):
    # the mug's best walk fits them best.
    lib = tiny_library
    mug = [m.id for m in lib.models].index("mug")
    views = [v for v in range(len(lib.az_el)) if lib.az_el[v, 1] == 0.0][::2]
    masks = [np.pad(lib.silhouettes[mug, v], 16) for v in views]
    names = [f"p{i}.png" for i in range(len(masks))]
    images = [np.repeat(np.where(m[..., None], 0.3, 1.0), 3, axis=2).astype(np.float32)
              for m in masks]
    scores = bench_masks.walk_scores(masks, names, images, [None] * len(masks), lib,
                                     ["mug", "chair_wood"])
    assert scores[0] > scores[1]
    # The mug alone scores what retrieval over the whole library scores when it picks the mug.
    from cadnerf_core.retrieval.search import retrieve

    whole = retrieve(masks, names, lib, images=images)
    assert whole.model_id == "mug"
    assert scores[0] == pytest.approx(whole.score / len(masks))

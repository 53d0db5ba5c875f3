"""The start's choice among retrieval's hypotheses (``nerf.start.choose_start``)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
import torch

from cadnerf_core.config import PipelineConfig
from cadnerf_core.intake.crop import CropBox
from cadnerf_core.nerf import start
from cadnerf_core.progress import Progress
from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult


def _walk(direction: int, evidence: float, model_id: str = "bottle") -> RetrievalResult:
    matches = [PhotoMatch(i, f"{i}.png", i, 60.0 * i * direction, 20.0, 0.8, False, np.eye(4),
                          np.eye(3), CropBox(0.0, 0.0, 32.0, 32), np.eye(3)) for i in range(3)]
    return RetrievalResult(model_id, "bottle", [], matches, "dp", direction, 2.4, evidence)


@pytest.mark.parametrize(("evidence", "fitted"), [(5.0, 2), (1.0, 2), (0.5, 3), (-5.0, 2)])
def test_a_walk_against_strong_texture_evidence_is_not_fitted(
        evidence: float, fitted: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The mirrored walk fits the silhouettes a little better (as it can on a bottle), but
    where the photos' matches say which way the walk went it is not even tried."""
    retrieved = _walk(1 if evidence > 0 else -1, evidence)
    mirrored = _walk(-retrieved.direction, evidence)
    other = _walk(retrieved.direction, evidence, "vase")
    retrieval = dataclasses.replace(retrieved, alternatives=[mirrored, other])
    fits = {("bottle", retrieved.direction): 0.80, ("bottle", mirrored.direction): 0.81,
            ("vase", retrieved.direction): 0.70}

    def fit(hypothesis: RetrievalResult, *args: Any) -> float:
        return fits[(hypothesis.model_id, hypothesis.direction)]

    monkeypatch.setattr(start, "fit_hypothesis", fit)
    chosen = start.choose_start(retrieval, [], [], None, PipelineConfig(),  # type: ignore[arg-type]
                                torch.device("cpu"), False, Progress())
    assert len(chosen.hypotheses) == fitted
    expected = mirrored.direction if fitted == 3 else retrieved.direction
    assert chosen.direction == expected


def test_a_hypothesis_is_scored_by_the_mean_of_its_seeds_fits(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """With ``hypothesis_seeds`` 3 the score is the mean of three fits from three different
    seeds, less the discard penalty; the job's own seed comes first."""
    seeds: list[int] = []

    def fit(hypothesis: RetrievalResult, photos: Any, masks: Any, library: Any,
            config: PipelineConfig, *args: Any) -> float:
        seeds.append(config.seed)
        return {7: 0.60, 7 + start.SEED_STEP: 0.66, 7 + 2 * start.SEED_STEP: 0.69}[config.seed]

    monkeypatch.setattr(start, "coarse_fit", fit)
    walk = _walk(1, 0.0)
    walk.matches[2] = dataclasses.replace(walk.matches[2], discarded=True)
    config = PipelineConfig.model_validate({"seed": 7, "retrieval": {"hypothesis_seeds": 3}})
    score = start.fit_hypothesis(walk, [], [], None,  # type: ignore[arg-type]
                                 config, torch.device("cpu"), False)
    assert seeds == [7, 7 + start.SEED_STEP, 7 + 2 * start.SEED_STEP]
    penalty = config.retrieval.discard_penalty / 3
    assert score == pytest.approx(0.65 - penalty)

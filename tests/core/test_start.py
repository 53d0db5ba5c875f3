"""The start's choice among retrieval's hypotheses (``cameras.start.choose_start``)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
import torch

from cadnerf_core.cameras import start
from cadnerf_core.config import PipelineConfig
from cadnerf_core.intake.crop import CropBox
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
    config = PipelineConfig.model_validate({"retrieval": {"mirror_margin": 0.0}})
    chosen = start.choose_start(retrieval, [], [], None, config,  # type: ignore[arg-type]
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



@pytest.mark.parametrize(("fits", "margin", "chosen"), [
    ((0.822, 0.825, 0.70), 0.01, 0),  # the mirror leads within the margin: kept as retrieved
    ((0.822, 0.825, 0.70), 0.0, 1),  # no margin: any lead switches
    ((0.80, 0.85, 0.70), 0.01, 1),  # a clear lead switches to the mirror
    ((0.822, 0.823, 0.825), 0.01, 2),  # another model needs no margin
    ((0.822, 0.830, 0.824), 0.01, 2),  # the mirror left out, the next best fit wins
])
def test_the_mirrored_walk_needs_a_lead_beyond_the_margin(
        fits: tuple[float, float, float], margin: float, chosen: int,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Hypotheses: the retrieved walk, its mirror image (same model, other way round) and
    another model's walk; the record marks the one the job starts from."""
    retrieved = _walk(1, 0.0)
    candidates = [retrieved, _walk(-1, 0.0), _walk(1, 0.0, "vase")]
    retrieval = dataclasses.replace(retrieved, alternatives=candidates[1:])
    score = {(h.model_id, h.direction): f for h, f in zip(candidates, fits, strict=True)}
    monkeypatch.setattr(start, "fit_hypothesis",
                        lambda hypothesis, *args: score[(hypothesis.model_id,
                                                         hypothesis.direction)])
    config = PipelineConfig.model_validate({"retrieval": {"mirror_margin": margin}})
    result = start.choose_start(retrieval, [], [], None, config,  # type: ignore[arg-type]
                                torch.device("cpu"), False, Progress())
    assert [h["chosen"] for h in result.hypotheses] == [i == chosen for i in range(3)]
    assert (result.model_id, result.direction) == (candidates[chosen].model_id,
                                                   candidates[chosen].direction)


@pytest.mark.parametrize(("unfused_fit", "chosen"), [
    (0.87, 2),  # the pairs pulled every fused hypothesis off the silhouettes: set aside
    (0.84, 0),  # fusing cost a little fit, as right pairs do: kept
])
def test_the_retrieval_left_unfused_needs_a_clear_lead_over_every_fused_hypothesis(
        unfused_fit: float, chosen: int, monkeypatch: pytest.MonkeyPatch) -> None:
    from cadnerf_core.cameras.fusion import SET_ASIDE

    retrieved = dataclasses.replace(_walk(1, 0.0), fusion={"photos": [0, 1, 2]})
    other = dataclasses.replace(_walk(1, 0.0, "vase"), fusion={"photos": [0, 1]})
    unfused = dataclasses.replace(_walk(1, 0.0), fusion=dict(SET_ASIDE))
    retrieval = dataclasses.replace(retrieved, alternatives=[other, unfused])
    fits = {("bottle", False): 0.76, ("vase", False): 0.70, ("bottle", True): unfused_fit}
    monkeypatch.setattr(start, "fit_hypothesis",
                        lambda h, *args: fits[(h.model_id, start._set_aside(h))])
    result = start.choose_start(retrieval, [], [], None, PipelineConfig(),  # type: ignore[arg-type]
                                torch.device("cpu"), False, Progress())
    assert [h["chosen"] for h in result.hypotheses] == [i == chosen for i in range(3)]
    assert [h["fused"] for h in result.hypotheses] == [True, True, False]
    assert 0.76 + start.UNFUSED_MARGIN > 0.84  # the second case lies inside the margin


@pytest.mark.parametrize(("retrieved_fit", "chosen"), [
    (0.834, 1),  # the silhouettes lead a little: the pairs' walk is the start
    (0.93, 0),  # a lead beyond the margin: the retrieved walk stays
])
def test_a_mirrored_walk_the_pairs_join_outranks_a_retrieved_walk_they_all_contradict(
        retrieved_fit: float, chosen: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Retrieval walked the object the wrong way round: every pair contradicts its cameras
    (none fused) while the mirrored walk's cameras take them all (fused). Silhouettes cannot
    tell a walk from its mirror image, so neither the mirror's margin nor a small lead of the
    unfused walk keeps it."""
    retrieved = dataclasses.replace(_walk(-1, 0.0), fusion={"photos": [], "implausible": 3})
    mirrored = dataclasses.replace(_walk(1, 0.0), fusion={"photos": [0, 1, 2]})
    other = dataclasses.replace(_walk(-1, 0.0, "vase"), fusion={"photos": []})
    retrieval = dataclasses.replace(retrieved, alternatives=[mirrored, other])
    fits = {("bottle", -1): retrieved_fit, ("bottle", 1): 0.806, ("vase", -1): 0.85}
    monkeypatch.setattr(start, "fit_hypothesis",
                        lambda h, *args: fits[(h.model_id, h.direction)])
    result = start.choose_start(retrieval, [], [], None, PipelineConfig(),  # type: ignore[arg-type]
                                torch.device("cpu"), False, Progress())
    assert [h["chosen"] for h in result.hypotheses] == [i == chosen for i in range(3)]
    assert [h["fused"] for h in result.hypotheses] == [False, True, False]
    assert result.direction == (-1, 1)[chosen]


@pytest.mark.parametrize("ambiguous", [True, False])
def test_a_switch_leaves_a_guessed_direction_a_guess(
        ambiguous: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Retrieval guessed the direction; a fit that prefers the mirrored walk does not make it
    known: the result still says it is a guess, and its hint names the way it was taken."""
    from cadnerf_core.job_warnings import job_warnings

    retrieved = dataclasses.replace(_walk(1, 0.0), direction_ambiguous=ambiguous)
    mirrored = _walk(-1, 0.0)
    retrieval = dataclasses.replace(retrieved, alternatives=[mirrored])
    score = {1: 0.80, -1: 0.85}
    monkeypatch.setattr(start, "fit_hypothesis", lambda h, *args: score[h.direction])
    config = PipelineConfig.model_validate({"retrieval": {"mirror_margin": 0.01}})
    result = start.choose_start(retrieval, [], [], None, config,  # type: ignore[arg-type]
                                torch.device("cpu"), False, Progress())
    assert result.direction == -1
    assert result.direction_ambiguous is ambiguous
    names = [m.name for m in result.matches]
    warnings = job_warnings(result.to_json(), names)
    if ambiguous:
        assert len(warnings) == 1 and "taken clockwise" in warnings[0]
        assert 'retrieval.walk to "ccw"' in warnings[0]
    else:
        assert warnings == []


def test_a_coarse_fit_learns_the_poses_at_its_own_rate() -> None:
    """Training may learn the poses faster; the fits that rank the starts keep their rate."""
    config = PipelineConfig.model_validate({"phase2": {"pose_lr": 4e-3},
                                            "retrieval": {"hypothesis_pose_lr": 1e-3}})
    coarse = start.coarse_config(config)
    assert coarse.phase2.pose_lr == 1e-3
    assert config.phase2.pose_lr == 4e-3  # the job's own configuration is untouched
    default = start.coarse_config(PipelineConfig.model_validate({"phase2": {"pose_lr": 4e-3}}))
    assert default.phase2.pose_lr == PipelineConfig().retrieval.hypothesis_pose_lr == 2e-3

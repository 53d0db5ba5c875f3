"""Retrieval's model choice: a model the walk prefers replaces the voted one only by a margin."""

from __future__ import annotations

import numpy as np
import pytest

from cadnerf_core.config import RetrievalConfig
from cadnerf_core.retrieval.retrieve import _choose_walk

N_AZIMUTHS = 8


def _table(voted: float, other: float) -> np.ndarray:
    """[4 photos, 2 models, 8 views]: photo p matches view 2p of each model, with IoU
    ``voted`` (model 0) or ``other`` (model 1), and nothing else."""
    iou = np.zeros((4, 2, N_AZIMUTHS), np.float32)
    for p in range(4):
        iou[p, 0, 2 * p] = voted
        iou[p, 1, 2 * p] = other
    return iou


@pytest.mark.parametrize(("other", "chosen"), [(0.803, 0), (0.79, 0), (0.82, 1)])
def test_another_model_must_beat_the_voted_walk_by_the_margin(other: float, chosen: int) -> None:
    iou = _table(0.8, other)
    ranking = [(0, 3, 3.2), (1, 1, 4 * other)]
    config = RetrievalConfig(model_margin=0.005)
    m, walk = _choose_walk(iou, 0, ranking, np.arange(N_AZIMUTHS), N_AZIMUTHS, config, 0.0)
    assert m == chosen
    assert list(walk.views) == [0, 2, 4, 6]


def test_without_a_margin_the_best_walk_wins_however_slight() -> None:
    iou = _table(0.8, 0.81)
    ranking = [(0, 3, 3.2), (1, 1, 3.24)]
    config = RetrievalConfig(model_margin=0.0)
    m, _ = _choose_walk(iou, 0, ranking, np.arange(N_AZIMUTHS), N_AZIMUTHS, config, 0.0)
    assert m == 1
    votes = RetrievalConfig(model_choice="votes")
    assert _choose_walk(iou, 0, ranking, np.arange(N_AZIMUTHS), N_AZIMUTHS, votes, 0.0)[0] == 0

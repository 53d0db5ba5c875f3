"""The model race of retrieval: each candidate model's best walk through the photos (the
configured pose solver), the winner among the models, and the next best walks that become the
start's hypotheses; a bound on a model's walk spares walking models that cannot win."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence

import numpy as np

from cadnerf_core.config import RetrievalConfig
from cadnerf_core.retrieval.posesearch import PoseSearchResult, cyclic_dp, paper_algorithm1

log = logging.getLogger(__name__)

BOUND_SLACK = 1e-4  # summed IoU: float32 rounding of ``vote_models``' sums, with room to spare


def solve_poses(iou: np.ndarray, az_index: np.ndarray, n_azimuths: int,
                config: RetrievalConfig, evidence: float = 0.0) -> PoseSearchResult:
    """Run the configured pose solver on one model's IoU table.

    Args:
        iou: [P, V] IoU of each photo with each view.
        az_index: [V] azimuth bin of each view.
        n_azimuths: number of azimuth bins.
        evidence: texture evidence for the walking direction (> 0: increasing azimuth),
            used by the DP when it reaches ``config.appearance_threshold``.
    Returns:
        chosen views (-1 = discarded), score and direction.
    """
    given = {"ccw": 1, "cw": -1}.get(config.walk, 0)
    if given:
        # A clockwise walk is a counter-clockwise one over mirrored azimuth bins; the chosen
        # view indices do not depend on the bins' numbering.
        bins = az_index if given > 0 else (-np.asarray(az_index)) % n_azimuths
        forward = config.model_copy(update={"walk": "auto", "both_directions": False})
        found = solve_poses(iou, bins, n_azimuths, forward)
        return dataclasses.replace(found, direction=given, direction_lead=None)
    if config.solver == "paper":
        found = paper_algorithm1(iou, az_index, config.top_k, config.max_discard)
        if np.isfinite(found.score):
            return found
        # No ordered choice among the top-k: fall back on each photo's own best view.
        log.warning("the paper's solver found no ordered poses; using each photo's best view")
        return PoseSearchResult(np.argmax(iou, axis=1), float(iou.max(axis=1).sum()), 1)
    backward_cost = config.direction_margin * len(iou)
    if abs(evidence) >= config.appearance_threshold:
        # Each direction gains (or loses) weight * evidence: the decreasing walk pays twice.
        backward_cost += 2.0 * config.appearance_weight * evidence
    return cyclic_dp(iou, az_index, n_azimuths, config.discard_penalty, config.max_discard,
                     config.both_directions, config.cyclic, backward_cost=backward_cost,
                     spread_weight=config.spread_weight)


def choose_walk(iou: np.ndarray, m: int, ranking: Sequence[tuple[int, int, float]],
                az_index: np.ndarray, n_azimuths: int, config: RetrievalConfig,
                evidence: float) -> tuple[int, PoseSearchResult]:
    """The model and its walk: the voted model ``m``'s, or (``model_choice`` "walk", DP) the
    best walk of the ``walk_models`` most voted. Returns (model index, its walk)."""
    found = solve_poses(iou[:, m, :], az_index, n_azimuths, config, evidence)
    if config.model_choice == "walk" and config.solver == "dp":
        for entry in walk_pool(ranking, config)[1:]:
            if walk_bound(entry, len(iou), config) <= found.score:
                continue  # no walk of this model can score more
            other = entry[0]
            walk = solve_poses(iou[:, other, :], az_index, n_azimuths, config, evidence)
            if walk.score > found.score:
                m, found = other, walk
    return m, found


def walk_pool(ranking: Sequence[tuple[int, int, float]],
              config: RetrievalConfig) -> Sequence[tuple[int, int, float]]:
    """The models whose best walks compete (``RetrievalConfig.walk_models``), most voted
    first."""
    return ranking[:config.walk_models] if config.walk_models else ranking


def walk_bound(entry: tuple[int, int, float], n_photos: int, config: RetrievalConfig) -> float:
    """The most any walk of the model of ``entry`` (a ``vote_models`` ranking entry: model,
    votes, summed best IoU) can score: every photo at its own best view, less, for the DP, the
    least spread penalty (gaps summing to one turn over at most ``n_photos`` kept photos cost
    at least ``spread_weight / n_photos``; discards only lower it). A little above it, for the
    float32 sum of the ranking."""
    spread = config.spread_weight / n_photos if config.solver == "dp" else 0.0
    return entry[2] - spread + BOUND_SLACK


def alternatives(iou: np.ndarray, ranking: Sequence[tuple[int, int, float]],
                 az_index: np.ndarray, n_azimuths: int, config: RetrievalConfig,
                 evidence: float,
                 chosen: tuple[int, int]) -> list[tuple[int, PoseSearchResult]]:
    """The best walks after the ``chosen`` (model, direction), best score first: each of the
    ``walk_models`` most voted models walked each allowed way round; ``config.hypotheses`` - 1
    of them. Returns (model index, walk) pairs."""
    if config.hypotheses <= 1:
        return []
    walks = [config.model_copy(update={"walk": walk})
             for walk in {"ccw": ("ccw",), "cw": ("cw",)}.get(config.walk, ("ccw", "cw"))]
    wanted = config.hypotheses - 1
    found: list[tuple[int, PoseSearchResult]] = []
    for entry in walk_pool(ranking, config):
        if len(found) == wanted and walk_bound(entry, len(iou), config) < found[-1][1].score:
            continue  # none of its walks can join the best
        other = entry[0]
        for given in walks:
            result = solve_poses(iou[:, other, :], az_index, n_azimuths, given, evidence)
            if (other, result.direction) != chosen:
                found.append((other, result))
        found.sort(key=lambda pair: -pair[1].score)  # stable: ties stay most voted first
        del found[wanted:]
    return found

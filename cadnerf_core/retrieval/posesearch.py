"""Multi-view pose retrieval: one library view per photo, in walking order.

Both solvers take an IoU table ``iou [P, V]`` (photo p against library view v of one model) and
the azimuth bin of every view (``az_index [V]``, in ``0 .. n_az - 1``; the library's views are
azimuth-major, ``v = a * n_el + e``). They return the chosen view per photo (``-1`` = the photo
is discarded) and the objective's value.

``paper_algorithm1`` is the paper's Algorithm 1. Its objective: maximise
``sum over kept photos of iou[p, view_p]`` where each kept photo's view is one of its ``top_k``
highest-IoU views, the kept photos' azimuth bins are non-decreasing in photo order (no wrap),
and at most ``max_skip`` photos are skipped (skipping costs nothing). It is a depth-first
backtracking search that prunes a branch once its score plus the best remaining candidates
cannot beat the best complete assignment found so far. Here the same search solves each
sub-search (next photo, azimuth bin of the last kept photo, skips used) once (memoised), which
gives the same optimum and the same choice among equal ones (the first in the backtracking's
visiting order) in polynomial time: the pruned backtracking took up to 3 minutes on 9-photo
walks of the 9-elevation library where a photo had to be skipped (many candidates share an
azimuth bin, and the bound prunes little).

``cyclic_dp`` is ours. Its objective: maximise

    sum over kept photos p of iou[p, view_p]
    + sum over discarded photos p of (max_v iou[p, v] - discard_penalty)
    - spread_weight * sum over the walk's gaps g of (g / n_az) ** 2

over all views (no top-k cut), with ``n_discarded <= min(max_discard, P - 1)``, such that for
one walking direction ``s`` in {+1, -1} (or +1 only) the kept photos' azimuth bins
``a_1 .. a_k`` satisfy ``sum_j ((s * (a_{j+1} - a_j)) mod n_az) < n_az``: the walk goes one
way round, may start at any azimuth and wraps at most once (it never travels a full turn).
Equivalently, some rotation ``r`` makes ``(s * a_j - r) mod n_az`` non-decreasing. Equal bins
are allowed, as in the paper. The walk's gaps, in bins, are its ``k - 1`` steps
``(s * (a_{j+1} - a_j)) mod n_az`` and the closing gap back to the first photo,
``n_az - sum of the steps``; they add up to ``n_az``, so the spread term is smallest for photos
evenly spread around the object and largest (``spread_weight``) when every photo sits at one
azimuth, a degenerate "walk" that a rotationally symmetric or poorly matching model otherwise
wins. A discarded photo scores as if it sat at its own best view, less the penalty, so it is
discarded exactly when keeping it in order costs it more than ``discard_penalty``. Since the
elevation is free, only the best view per (photo, azimuth bin) matters, and the problem is an
exact dynamic programme over (photo, discards used, azimuth bin of the last kept photo) states,
run for every first-photo bin and direction at once; with ``cyclic=False`` the bins may not
pass the end of the turn (bin ``n_az - 1`` going up, bin 0 going down), as in the paper. An
optional ``backward_cost`` is subtracted from the objective of a decreasing walk (not from
the returned score); at equal objectives the increasing walk (the paper's order), then fewer
discards, win.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

NEG_INF = -np.inf


@dataclass(frozen=True)
class PoseSearchResult:
    """A solver's answer.

    ``views [P]``: chosen view per photo, ``-1`` for a discarded photo; ``score``: the value of
    the solver's objective; ``direction``: +1 when the azimuth grows along the photos, -1 when
    it shrinks; ``direction_lead``: the DP's objective of its best walk in the chosen direction
    less that of its best walk the other way (None when one direction was searched). Near 0,
    the silhouettes cannot tell which way round the photos were taken; below 0, a
    ``backward_cost`` chose the direction against them.
    """

    views: np.ndarray
    score: float
    direction: int
    direction_lead: float | None = None


def paper_algorithm1(iou: np.ndarray, az_index: np.ndarray, top_k: int = 10,
                     max_skip: int = 2) -> PoseSearchResult:
    """The paper's Algorithm 1: backtracking over top-k candidates with order and skips.

    Args:
        iou: [P, V] IoU of each photo with each view of one model.
        az_index: [V] azimuth bin of each view.
        top_k: candidate views kept per photo (highest IoU first).
        max_skip: most photos that may be skipped.
    Returns:
        The chosen views (``-1`` = skipped), the summed IoU of kept photos, direction +1. When
        no ordered choice exists among the candidates, every view is -1 and the score -inf.
    """
    iou = np.asarray(iou, dtype=np.float64)
    n_photos = iou.shape[0]
    k = min(top_k, iou.shape[1])
    cands = np.argsort(-iou, axis=1, kind="stable")[:, :k]  # [P, k], best first
    cand_iou = np.take_along_axis(iou, cands, axis=1)
    cand_az = np.asarray(az_index)[cands]

    @functools.cache
    def best(p: int, last_az: int, skips: int) -> float:
        """The most photos p.. can add after a kept photo at bin ``last_az``."""
        if p == n_photos:
            return 0.0
        out = NEG_INF
        for i in range(k):
            if cand_az[p, i] >= last_az:
                out = max(out, float(cand_iou[p, i]) + best(p + 1, int(cand_az[p, i]), skips))
        if skips < max_skip:
            out = max(out, best(p + 1, last_az, skips + 1))
        return out

    total = best(0, -1, 0)
    views = np.full(n_photos, -1)
    if not np.isfinite(total):
        return PoseSearchResult(views, NEG_INF, 1)
    # Walk down in the backtracking's visiting order (candidates best first, then the skip),
    # taking the first branch that reaches the optimum: the assignment it finds first.
    last_az, skips, score = -1, 0, 0.0
    for p in range(n_photos):
        for i in range(k):
            if cand_az[p, i] >= last_az and score + float(cand_iou[p, i]) + best(
                    p + 1, int(cand_az[p, i]), skips) >= total - 1e-9:
                views[p], last_az = cands[p, i], int(cand_az[p, i])
                score += float(cand_iou[p, i])
                break
        else:
            skips += 1
    return PoseSearchResult(views, float(total), 1)


def _bin_table(iou: np.ndarray, az_index: np.ndarray,
               n_az: int) -> tuple[np.ndarray, np.ndarray]:
    """Best IoU and its view per (photo, azimuth bin). Returns [P, n_az] f64, [P, n_az] int."""
    best = np.full((iou.shape[0], n_az), NEG_INF)
    arg = np.full((iou.shape[0], n_az), -1, dtype=np.int64)
    for a in range(n_az):
        views = np.flatnonzero(az_index == a)
        if len(views):
            col = np.argmax(iou[:, views], axis=1)
            arg[:, a] = views[col]
            best[:, a] = iou[np.arange(iou.shape[0]), arg[:, a]]
    return best, arg


def _gap_gain(n_az: int, spread_weight: float) -> np.ndarray:
    """Objective gain of a gap of g bins, g = 0 .. n_az. Returns [n_az + 1] f64."""
    return -spread_weight * (np.arange(n_az + 1) / n_az) ** 2


def _forward(table: np.ndarray, drop: np.ndarray, max_discard: int, gap: np.ndarray,
             ) -> tuple[np.ndarray, list[tuple[np.ndarray, ...]]]:
    """Run the DP for a batch of bin-reordered tables (the first kept photo sits at bin 0).

    Args:
        table: [B, P, n_az] gain of keeping photo p at (reordered) bin j.
        drop: [P] gain of discarding photo p.
        max_discard: D, the most discards.
        gap: [n_az + 1] gain of a gap of g bins.
    Returns:
        G [B, D + 1, n_az]: best score of all photos with d discards and the last kept photo
        at bin j (before the closing gap); and per photo the back pointers (previous bin
        [B, D + 1, n_az], first-kept flag, discard flag), all of the same shape.
    """
    n_batch, n_photos, n_az = table.shape
    j = np.arange(n_az)
    step = j[None, :] - j[:, None]  # [j_prev, j]
    step_gain = np.where(step >= 0, gap[np.clip(step, 0, n_az)], NEG_INF)
    g = np.full((n_batch, max_discard + 1, n_az), NEG_INF)
    empty = np.full(max_discard + 1, NEG_INF)  # nothing kept yet, d discards
    empty[0] = 0.0
    pointers: list[tuple[np.ndarray, ...]] = []
    for p in range(n_photos):
        moves = g[..., :, None] + step_gain  # [B, D + 1, j_prev, j]
        prev = moves.argmax(axis=2)
        keep = np.take_along_axis(moves, prev[:, :, None, :], axis=2)[:, :, 0, :]
        first = np.zeros(keep.shape, dtype=bool)
        first[:, :, 0] = empty[None, :] > keep[:, :, 0]
        keep[:, :, 0] = np.maximum(keep[:, :, 0], empty[None, :])
        keep = keep + table[:, None, p, :]
        skip = np.full_like(g, NEG_INF)
        skip[:, 1:, :] = g[:, :-1, :] + drop[p]
        dropped = skip > keep
        g = np.where(dropped, skip, keep)
        pointers.append((prev, first, dropped))
        empty = np.concatenate([[NEG_INF], empty[:-1] + drop[p]])
    return g, pointers


def _backtrack(pointers: list[tuple[np.ndarray, ...]], c: int, d: int, j: int) -> np.ndarray:
    """Recover the chosen (reordered) bins of batch item c ending at (d, j). Returns [P]."""
    bins = np.full(len(pointers), -1)
    for p in range(len(pointers) - 1, -1, -1):
        prev, first, dropped = (a[c, d, j] for a in pointers[p])
        if dropped:
            d -= 1
            continue
        bins[p] = j
        if first:
            break  # every earlier photo was discarded
        j = int(prev)
    return bins


def _walks(n_az: int, both_directions: bool) -> tuple[list[int], np.ndarray]:
    """Candidate walks: direction of each, and order[c, j] = bin visited j-th by walk c."""
    signs = [sign for sign in ((1, -1) if both_directions else (1,)) for _ in range(n_az)]
    order = np.array([[(s + sign * j) % n_az for j in range(n_az)]
                      for sign in ((1, -1) if both_directions else (1,)) for s in range(n_az)])
    return signs, order


def cyclic_dp(iou: np.ndarray, az_index: np.ndarray, n_az: int, discard_penalty: float = 0.3,
              max_discard: int = 2, both_directions: bool = True, cyclic: bool = True,
              backward_cost: float = 0.0, spread_weight: float = 0.0) -> PoseSearchResult:
    """Exact cyclic-order pose search by dynamic programming (see the module docstring).

    Args:
        iou: [P, V] IoU of each photo with each view of one model.
        az_index: [V] azimuth bin of each view, in ``0 .. n_az - 1``.
        n_az: number of azimuth bins.
        discard_penalty: IoU a discard costs (a photo is kept unless keeping it in order
            loses more than this against its own best view).
        max_discard: most photos that may be discarded.
        both_directions: also try the walk with decreasing azimuth.
        cyclic: allow the walk to wrap past the end of the turn (else it may not, as in the
            paper).
        backward_cost: subtracted from the objective of a decreasing walk (not counted in the
            returned score), so it must win by this much to be chosen.
        spread_weight: weight of the gap-spread term (0: none).
    Returns:
        Chosen views (``-1`` = discarded), the objective's value, and the walking direction.
    """
    iou = np.asarray(iou, dtype=np.float64)
    n_photos = iou.shape[0]
    best_bin, arg_bin = _bin_table(iou, np.asarray(az_index), n_az)
    signs, order = _walks(n_az, both_directions)
    table = best_bin[:, order].transpose(1, 0, 2)  # [B, P, n_az]
    if not cyclic:  # reordered bin j of walk c wraps when it passes the end of the turn
        unrolled = order[:, :1] + np.array(signs)[:, None] * np.arange(n_az)
        table = np.where(((unrolled < 0) | (unrolled >= n_az))[:, None, :], NEG_INF, table)
    drop = iou.max(axis=1) - discard_penalty  # a discarded photo: its own best, less the fee
    gap = _gap_gain(n_az, spread_weight)
    g, pointers = _forward(table, drop, min(max_discard, n_photos - 1), gap)
    ends = g + gap[n_az - np.arange(n_az)]  # the closing gap, [B, D + 1, n_az]
    charged = ends - np.array([backward_cost if s < 0 else 0.0 for s in signs])[:, None, None]
    per_discard = charged.max(axis=(0, 2))
    # Among (numerically) equal optima: fewest discards, then the first (increasing) walk.
    d = int(np.flatnonzero(per_discard >= per_discard.max() - 1e-12)[0])
    c, j = np.unravel_index(int(np.argmax(charged[:, d, :] >= per_discard[d] - 1e-12)),
                            charged[:, d, :].shape)
    bins = _backtrack(pointers, int(c), d, int(j))
    views = np.array([arg_bin[p, order[c, b]] if b >= 0 else -1 for p, b in enumerate(bins)])
    lead = None
    if both_directions:
        sign = np.array(signs)
        lead = float(ends[sign == signs[c]].max() - ends[sign != signs[c]].max())
    return PoseSearchResult(views, float(ends[c, d, j]), signs[c], lead)

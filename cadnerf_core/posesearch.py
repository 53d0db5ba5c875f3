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
cannot beat the best complete assignment found so far.

``cyclic_dp`` is ours. Its objective: maximise

    sum over kept photos p of iou[p, view_p]
    + sum over discarded photos p of (max_v iou[p, v] - discard_penalty)

over all views (no top-k cut), with ``n_discarded <= min(max_discard, P - 1)``, such that for
one walking direction ``s`` in {+1, -1} (or +1 only) the kept photos' azimuth bins
``a_1 .. a_k`` satisfy ``sum_j ((s * (a_{j+1} - a_j)) mod n_az) < n_az``: the walk goes one
way round, may start at any azimuth and wraps at most once (it never travels a full turn).
Equivalently, some rotation ``r`` makes ``(s * a_j - r) mod n_az`` non-decreasing. Equal bins
are allowed, as in the paper. A discarded photo scores as if it sat at its own best view, less
the penalty, so it is discarded exactly when keeping it in order costs it more than
``discard_penalty`` of IoU. (With equal bins allowed a photo never blocks the others, so a
costless skip, as in the paper, would only ever be taken because of the top-k cut.) Since the
elevation is free, only the best view per (photo, azimuth bin) matters, and the problem is an
exact dynamic programme over (photo, discards used, azimuth bin) states, run for every start
bin and direction at once. An optional ``backward_cost`` is subtracted from the objective of a
decreasing walk (a mirror-symmetric object's walk and its front/back flip, which runs the other
way, nearly tie; the paper assumes increasing azimuth).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEG_INF = -np.inf


@dataclass(frozen=True)
class PoseSearchResult:
    """A solver's answer.

    ``views [P]``: chosen view per photo, ``-1`` for a discarded photo; ``score``: the value of
    the solver's objective; ``direction``: +1 when the azimuth grows along the photos, -1 when
    it shrinks.
    """

    views: np.ndarray
    score: float
    direction: int


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
    # Bound: the best any suffix of photos can still add.
    suffix_best = np.concatenate([np.cumsum(cand_iou[::-1, 0])[::-1], [0.0]])
    best_score = NEG_INF
    best_views = np.full(n_photos, -1)
    chosen = np.full(n_photos, -1)

    def search(p: int, last_az: int, skips: int, score: float) -> None:
        nonlocal best_score, best_views
        if p == n_photos:
            if score > best_score:
                best_score, best_views = score, chosen.copy()
            return
        if score + suffix_best[p] <= best_score:
            return
        for view, value in zip(cands[p], cand_iou[p], strict=True):
            if az_index[view] >= last_az:
                chosen[p] = view
                search(p + 1, int(az_index[view]), skips, score + float(value))
        if skips < max_skip:
            chosen[p] = -1
            search(p + 1, last_az, skips + 1, score)
        chosen[p] = -1

    search(0, -1, 0, 0.0)
    return PoseSearchResult(best_views, float(best_score), 1)


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


def _forward(table: np.ndarray, drop: np.ndarray, max_discard: int) -> list[np.ndarray]:
    """Run the DP for a batch of bin-reordered tables.

    Args:
        table: [B, P, n_az] gain of keeping photo p at (reordered) bin b.
        drop: [P] gain of discarding photo p.
    Returns:
        P + 1 arrays G_i [B, D + 1, n_az]: best score of photos < i with d discards and the
        last kept bin <= b (G_0 is the empty prefix).
    """
    n_batch, n_photos, n_az = table.shape
    g = np.full((n_batch, max_discard + 1, n_az), NEG_INF)
    g[:, 0, :] = 0.0
    out = [g]
    for p in range(n_photos):
        keep = np.maximum.accumulate(g + table[:, None, p, :], axis=2)
        skip = np.full_like(g, NEG_INF)
        skip[:, 1:, :] = g[:, :-1, :] + drop[p]
        g = np.maximum(keep, skip)
        out.append(g)
    return out


def _backtrack(gs: list[np.ndarray], table: np.ndarray, d: int) -> np.ndarray:
    """Recover chosen (reordered) bins from one batch item's DP tables. Returns [P], -1 = drop.

    Args:
        gs: P + 1 arrays [D + 1, n_az] for the chosen batch item.
        table: [P, n_az] its gains.
        d: discards used by the optimum.
    """
    n_photos, n_az = table.shape
    bins = np.full(n_photos, -1)
    bound = n_az - 1
    target = gs[n_photos][d, bound]
    for p in range(n_photos - 1, -1, -1):
        prev = gs[p]
        keep = prev[d, : bound + 1] + table[p, : bound + 1]
        b = int(np.argmax(keep))
        if np.isclose(keep[b], target, rtol=0.0, atol=1e-9) and np.isfinite(keep[b]):
            bins[p], bound, target = b, b, prev[d, b]
        else:
            d -= 1
            target = prev[d, bound]
    return bins


def cyclic_dp(iou: np.ndarray, az_index: np.ndarray, n_az: int, discard_penalty: float = 0.3,
              max_discard: int = 2, both_directions: bool = True, cyclic: bool = True,
              backward_cost: float = 0.0) -> PoseSearchResult:
    """Exact cyclic-order pose search by dynamic programming (see the module docstring).

    Args:
        iou: [P, V] IoU of each photo with each view of one model.
        az_index: [V] azimuth bin of each view, in ``0 .. n_az - 1``.
        n_az: number of azimuth bins.
        discard_penalty: IoU a discard costs (a photo is kept unless keeping it in order
            loses more than this against its own best view).
        max_discard: most photos that may be discarded.
        both_directions: also try the walk with decreasing azimuth.
        cyclic: allow any start bin (else the walk starts at bin 0 and never wraps, as in the
            paper).
        backward_cost: subtracted from the objective of a decreasing walk (not counted in the
            returned score), so it must win by this much to be chosen.
    Returns:
        Chosen views (``-1`` = discarded), the objective's value, and the walking direction.
    """
    iou = np.asarray(iou, dtype=np.float64)
    az_index = np.asarray(az_index)
    n_photos = iou.shape[0]
    best_bin, arg_bin = _bin_table(iou, az_index, n_az)
    walks = [(sign, s) for sign in ((1, -1) if both_directions else (1,))
             for s in (range(n_az) if cyclic else [0 if sign > 0 else n_az - 1])]
    # order[c, j] = the original bin visited j-th by candidate walk c.
    order = np.array([[(s + sign * j) % n_az for j in range(n_az)] for sign, s in walks])
    table = best_bin[:, order].transpose(1, 0, 2)  # [B, P, n_az]
    drop = iou.max(axis=1) - discard_penalty  # a discarded photo: its own best, less the fee
    gs = _forward(table, drop, min(max_discard, n_photos - 1))
    cost = np.array([backward_cost if sign < 0 else 0.0 for sign, _ in walks])
    ends = gs[-1][:, :, -1] - cost[:, None]  # [B, D + 1]
    final = ends.max(axis=0)  # best over walks per discard count
    # Fewest discards among (numerically) equal optima.
    d = int(np.flatnonzero(final >= final.max() - 1e-12)[0])
    c = int(np.argmax(ends[:, d]))
    score = float(gs[-1][c, d, -1])
    bins = _backtrack([g[c] for g in gs], table[c], d)
    views = np.array([arg_bin[p, order[c, b]] if b >= 0 else -1 for p, b in enumerate(bins)])
    return PoseSearchResult(views, score, walks[c][0])

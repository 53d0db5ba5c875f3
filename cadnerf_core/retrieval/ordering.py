"""Photos in any order: find the walk from the photos themselves.

A walk round an object is the cyclic order of its photos' azimuths. Given one model's IoU table
``iou [P, V]``, ``any_order`` chooses, per photo, an azimuth bin (and the best elevation in it)
so that the photos, sorted by azimuth, form the best walk. Its objective is that of the walk
solver (``posesearch.cyclic_dp``) with the order free and no discards:

    sum over photos p of best[p, bin_p]
    - spread_weight * sum over the walk's gaps g of (g / n_az) ** 2
    + similarity_weight * sum over the walk's neighbours (p, q) of similarity[p, q]

where ``best[p, a]`` is the photo's highest IoU among the views at azimuth bin ``a`` and the
gaps are the azimuth steps between consecutive photos of the walk, the closing step included.
The last term is the prior that neighbours in a walk look alike (``neighbour_similarity``).

Solved exactly by dynamic programming over subsets (Held-Karp): the walk is a cycle, so it may
start at photo 0, which sits at an absolute bin ``b0``; the state is (the set of photos placed
after photo 0, the last photo placed, its bin relative to ``b0``), with the walk's bins never
decreasing, run for every ``b0`` at once. ``2^(P-1) * P * n_az^3`` operations for
``P`` photos: about 10^8 for 10 photos and 36 azimuths, vectorised layer by layer (sets of one
size at a time). Branch and bound over the candidate tables gives the same optimum but its
running time depends on how well the bound prunes, which on look-alike views (many bins
scoring alike) is poorly; the DP's time is fixed by the sizes alone.

Both walking directions are the same cycle read either way, so the solver returns the walk with
increasing azimuth; the retrieval then runs the ordinary walk solver on the photos in this
order, which chooses the direction (texture cue included) and may discard photos.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from cadnerf_core.retrieval.posesearch import _bin_table, _gap_gain, cyclic_dp

NEG = np.float32(-1e9)  # "impossible" in float32 (sums of a few stay far below any real score)
CHUNK = 24  # sets of one layer processed at once (bounds the temporary to ~100 MB at P = 10)
HIST_BINS = (12, 4)  # hue x saturation bins of the appearance histogram


@dataclass(frozen=True)
class OrderSearch:
    """``any_order``'s answer: ``order``, the photos in walking order (photo 0 first, azimuth
    increasing); ``views [P]``, each photo's chosen view; ``score``, the objective's value."""

    order: list[int]
    views: np.ndarray
    score: float


def _layers(n_bits: int) -> list[np.ndarray]:
    """Subsets of ``n_bits`` bits as integers, grouped by their number of members."""
    sets = np.arange(1 << n_bits)
    counts = np.array([bin(s).count("1") for s in sets])
    return [sets[counts == k] for k in range(n_bits + 1)]


def any_order(iou: np.ndarray, az_index: np.ndarray, n_az: int, spread_weight: float,
              similarity: np.ndarray | None = None, similarity_weight: float = 0.0,
              check: Callable[[], None] | None = None) -> OrderSearch:
    """The best walk through photos in any order (see the module docstring).

    Args:
        iou: [P, V] IoU of each photo with each view of one model.
        az_index: [V] azimuth bin of each view, in ``0 .. n_az - 1``.
        n_az: number of azimuth bins.
        spread_weight: weight of the gap-spread term.
        similarity: [P, P] symmetric appearance similarity of the photos (None: none).
        similarity_weight: weight of the neighbours' similarity.
        check: called every few milliseconds of the search (a cancelled job's check raises).
    Returns:
        The walk: photo order, view per photo, objective.
    """
    iou = np.asarray(iou, dtype=np.float64)
    n_photos = iou.shape[0]
    best, arg = _bin_table(iou, np.asarray(az_index), n_az)
    best = np.where(np.isfinite(best), best, NEG).astype(np.float32)
    # table[p, b0, j]: photo p at bin b0 + j, the walk starting at bin b0.
    absolute = (np.arange(n_az)[:, None] + np.arange(n_az)[None, :]) % n_az
    table = best[:, absolute]
    gap = _gap_gain(n_az, spread_weight).astype(np.float32)
    step = np.arange(n_az)[None, :] - np.arange(n_az)[:, None]  # [j_prev, j]
    kernel = np.where(step >= 0, gap[np.clip(step, 0, n_az)], NEG).astype(np.float32)
    sim = np.zeros((n_photos, n_photos), np.float32)
    if similarity is not None and similarity_weight:
        sim = (similarity_weight * np.asarray(similarity)).astype(np.float32)
    others = n_photos - 1
    # g[S, last, b0, j]: best walk from photo 0 through the photos of S (bit i = photo i + 1),
    # ending at photo ``last`` at relative bin j.
    g = np.full((1 << others, n_photos, n_az, n_az), NEG, np.float32)
    g[0, 0, :, 0] = table[0, :, 0]
    for layer in _layers(others)[:-1]:
        for start in range(0, len(layer), CHUNK):
            if check is not None:
                check()
            sets = layer[start:start + CHUNK]
            # h[s, last, b0, j]: best over j' <= j of g[s, last, b0, j'] plus the step's gain,
            # computed only where ``last`` is photo 0 or a member of s (elsewhere impossible)
            member = np.ones((len(sets), n_photos), bool)
            member[:, 1:] = (sets[:, None] >> np.arange(others)[None, :]) & 1 == 1
            member[:, 0] = sets == 0
            s_at, last_at = np.nonzero(member)
            h = np.full((len(sets), n_photos, n_az, n_az), NEG, np.float32)
            h[s_at, last_at] = _steps(g[sets[s_at], last_at], gap)
            for p in range(1, n_photos):
                bit = 1 << (p - 1)
                free = (sets & bit) == 0
                if not free.any():
                    continue
                moved = (h[free] + sim[:, p][None, :, None, None]).max(axis=1)
                g[sets[free] | bit, p] = moved + table[p][None]
    full = (1 << others) - 1
    closing = gap[n_az - np.arange(n_az)]  # back from relative bin j to photo 0 at n_az
    ends = g[full] + closing[None, None, :] + sim[:, 0][:, None, None]  # [last, b0, j]
    last, b0, j = np.unravel_index(int(np.argmax(ends)), ends.shape)
    score = float(ends[last, b0, j])
    order, bins = _backtrack(g, kernel, sim, table, int(last), int(b0), int(j))
    views = np.array([arg[p, (b0 + bins[p]) % n_az] for p in range(n_photos)])
    return OrderSearch(order, views, score)


def runner_up(iou: np.ndarray, az_index: np.ndarray, n_az: int, spread_weight: float,
              found: Sequence[int], similarity: np.ndarray | None = None,
              similarity_weight: float = 0.0,
              check: Callable[[], None] | None = None) -> float:
    """The objective of the best walk whose cycle differs from ``found``'s.

    Exact: a different cycle lacks at least one of ``found``'s neighbouring pairs, so the best
    one is the best of the walks that each forbid one of its pairs (``any_order`` with that
    pair's likeness impossible), ``P`` searches for ``P`` photos.

    Returns:
        That objective (the found walk's lead over it says how sure the order is); -inf for
        three photos or fewer, which make a single cycle.
    """
    n_photos = len(found)
    if n_photos <= 3:
        return float("-inf")
    base = np.zeros((n_photos, n_photos)) if similarity is None or not similarity_weight \
        else similarity_weight * np.asarray(similarity, dtype=np.float64)
    best = float("-inf")
    for a, b in zip(found, [*found[1:], found[0]], strict=True):
        forbidden = base.copy()
        forbidden[a, b] = forbidden[b, a] = NEG
        other = any_order(iou, az_index, n_az, spread_weight, forbidden, 1.0, check)
        if other.score > NEG / 2:  # a walk that needs the forbidden pair is none
            best = max(best, other.score)
    return best


def _steps(values: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """``out[..., j] = max over d >= 0 of values[..., j - d] + gap[d]`` (a walk's next photo at
    bin j after one at bin j - d), by one shifted maximum per step size."""
    out = values + gap[0]
    for d in range(1, values.shape[-1]):
        np.maximum(out[..., d:], values[..., :-d] + gap[d], out=out[..., d:])
    return out


def _backtrack(g: np.ndarray, kernel: np.ndarray, sim: np.ndarray, table: np.ndarray,
               last: int, b0: int, j: int) -> tuple[list[int], dict[int, int]]:
    """Recover the walk ending at (all photos, ``last``, ``b0``, ``j``) by recomputing each
    step's best predecessor. Returns the photo order and each photo's relative bin."""
    sets = g.shape[0] - 1
    walk, bins = [last], {last: j}
    while sets:
        p = walk[-1]
        prev_sets = sets & ~(1 << (p - 1))
        want = g[sets, p, b0, bins[p]] - table[p, b0, bins[p]]
        options = g[prev_sets, :, b0, :] + kernel[:, bins[p]][None, :] + sim[:, p][:, None]
        prev, prev_j = np.unravel_index(int(np.argmax(options)), options.shape)
        if not np.isclose(options[prev, prev_j], want, atol=1e-3):
            raise AssertionError("order search: inconsistent back-tracking")
        walk.append(int(prev))
        bins[int(prev)] = int(prev_j)
        sets = prev_sets
    return walk[::-1], bins


def walk_score(iou: np.ndarray, az_index: np.ndarray, n_az: int, order: Sequence[int],
               spread_weight: float, similarity: np.ndarray | None = None,
               similarity_weight: float = 0.0) -> float:
    """``any_order``'s objective for the photos walked in ``order`` (either way round, any
    start, no discards): what the given order scores in the same terms."""
    order = list(order)
    found = cyclic_dp(np.asarray(iou)[order], az_index, n_az, max_discard=0,
                      spread_weight=spread_weight)
    if similarity is None or not similarity_weight:
        return found.score
    pairs = zip(order, order[1:] + order[:1], strict=True)
    return found.score + similarity_weight * float(sum(similarity[a, b] for a, b in pairs))


def same_cycle(a: Sequence[int], b: Sequence[int]) -> bool:
    """True when the walks ``a`` and ``b`` visit the photos in the same cyclic order, read
    either way round from any start."""
    a, b = list(a), list(b)
    if sorted(a) != sorted(b):
        return False
    if len(a) < 3:
        return True
    i = b.index(a[0])
    forward = b[i:] + b[:i]
    backward = [forward[0], *forward[1:][::-1]]
    return a in (forward, backward)


def standardised(values: np.ndarray) -> np.ndarray:
    """``values`` [P, P] less the mean of its off-diagonal entries, over their standard
    deviation (all 0 where they do not vary: a cue that says nothing)."""
    off = values[~np.eye(len(values), dtype=bool)]
    spread = float(off.std()) if off.size else 0.0
    if spread < 1e-6:
        return np.zeros_like(values, dtype=np.float64)
    return (values - float(off.mean())) / spread


def neighbour_similarity(images: Sequence[np.ndarray],
                         masks: Sequence[np.ndarray]) -> np.ndarray:
    """How alike the photos look, for the prior that neighbours in a walk look alike: the mean
    of two standardised cues (``standardised``), the histogram intersection of their
    hue-saturation histograms inside the masks (the colours of the side they see) and the IoU
    of their masks' canonical crops (their outlines).

    Args:
        images: P canonical crops [S, S, 3] float in [0, 1].
        masks: P canonical masks [S, S] bool.
    Returns:
        [P, P] float: 0 on average off the diagonal, a unit of spread; all 0 for a cue
        that does not vary.
    """
    hists = []
    for image, mask in zip(images, masks, strict=True):
        rgb8 = np.clip(np.asarray(image) * 255.0, 0, 255).astype(np.uint8)
        hsv = cv2.cvtColor(rgb8, cv2.COLOR_RGB2HSV)
        hist = cv2.calcHist([hsv], [0, 1], np.asarray(mask, np.uint8), list(HIST_BINS),
                            [0, 180, 0, 256]).ravel()
        hists.append(hist / max(float(hist.sum()), 1.0))
    stacked = np.stack(hists)
    colour = np.minimum(stacked[:, None, :], stacked[None, :, :]).sum(axis=-1)
    flat = np.stack([np.asarray(m, bool).ravel() for m in masks]).astype(np.float64)
    inter = flat @ flat.T
    area = flat.sum(axis=1)
    outline = inter / np.maximum(area[:, None] + area[None, :] - inter, 1.0)
    return (standardised(colour) + standardised(outline)) / 2.0


@dataclass(frozen=True)
class OrderChoice:
    """The order retrieval walks the photos in: ``order`` (photo indices), whether it differs
    from the given one as a cycle (``reordered``), the model whose silhouettes found it, and
    the objective of the best walk in any order and of the walk in the given order."""

    order: list[int]
    reordered: bool
    model: int
    found_score: float
    given_score: float
    runner_up: float | None = None  # ``runner_up`` of the order found (None: not searched)

    @property
    def lead(self) -> float | None:
        """How far the order used leads the best walk in any other order (None: the given
        order was kept, so none was needed)."""
        if self.runner_up is None:
            return None
        return self.found_score - self.runner_up


def choose_order(iou: np.ndarray, candidates: Sequence[int], az_index: np.ndarray, n_az: int,
                 mode: str, margin: float, spread_weight: float,
                 similarity: np.ndarray | None = None, similarity_weight: float = 0.0,
                 check: Callable[[], None] | None = None) -> OrderChoice:
    """The walking order of photos given in any order (``mode`` "any") or perhaps in walking
    order ("auto": kept unless the best walk beats it by more than ``margin`` IoU a photo),
    with the best walk in any other order (``runner_up``) where the order was searched for.

    Args:
        iou: [P, M, V] IoU of each photo with each view of each model.
        candidates: the models (indices into M) whose best walks compete, best voted first.
        az_index, n_az: the views' azimuth bins and their number.
        check: called often during the search (a cancelled job's check raises).
    Returns:
        The order, from the candidate model with the best walk in any order.
    """
    n_photos = iou.shape[0]
    given = list(range(n_photos))
    best: tuple[float, int, list[int]] | None = None
    for m in candidates:
        found = any_order(iou[:, m, :], az_index, n_az, spread_weight, similarity,
                          similarity_weight, check)
        if best is None or found.score > best[0]:
            best = (found.score, m, found.order)
    assert best is not None, "no candidate model"
    score, model, order = best
    given_score = walk_score(iou[:, model, :], az_index, n_az, given, spread_weight,
                             similarity, similarity_weight)
    keep = same_cycle(order, given) or (mode == "auto"
                                         and score - given_score <= margin * n_photos)
    second = None
    if mode == "any" or not keep:
        second = runner_up(iou[:, model, :], az_index, n_az, spread_weight, order, similarity,
                           similarity_weight, check)
    return OrderChoice(given if keep else order, not keep, model, score, given_score, second)

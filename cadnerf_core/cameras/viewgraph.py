"""The view graph of the verified pairs: the triangles they close (``triangles``), which pairs'
rotations those triangles confirm (``consistent_edges``), the largest set of photos the pairs
connect (``component``), and the rotations a spanning tree of the surest pairs chains from one
photo (``spanning_tree_start``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cadnerf_core.cameras.conventions import rotation_angle_deg

CYCLE_DEG = 6.0
"""Most a pair's rotation may differ from the product of two others closing a triangle for
the three to agree."""


def _angle(R: np.ndarray) -> float:
    return float(rotation_angle_deg(np.asarray(R)[None])[0])


def consistent_edges(edges: dict[tuple[int, int], np.ndarray]) -> set[tuple[int, int]]:
    """The edges (i < j, ``R_ij``: camera i's axes to camera j's) no triangle contradicts.

    An edge is confirmed by a triangle of edges whose rotations compose within ``CYCLE_DEG``;
    it is contradicted by a triangle that does not close while its two other edges are
    confirmed. Edges neither confirmed nor contradicted are kept: the averaging's robust
    weights judge them.
    """
    closing: dict[tuple[int, int], list[tuple[int, int, int]]] = {e: [] for e in edges}
    failing: dict[tuple[int, int], list[tuple[int, int, int]]] = {e: [] for e in edges}
    for (a, b, c), closes in triangles(edges):
        for e in ((a, b), (b, c), (a, c)):
            key = e if e in edges else (e[1], e[0])
            (closing if closes else failing)[key].append((a, b, c))
    confirmed = {e for e, found in closing.items() if found}

    def others_confirmed(e: tuple[int, int], tri: tuple[int, int, int]) -> bool:
        rest = [n for n in tri if n not in e]
        return all(tuple(sorted((n, rest[0]))) in confirmed or (rest[0], n) in confirmed
                   for n in e)

    return {e for e in edges if e in confirmed
            or not any(others_confirmed(e, tri) for tri in failing[e])}


def triangles(edges: dict[tuple[int, int], np.ndarray]
              ) -> list[tuple[tuple[int, int, int], bool]]:
    """Every triangle ``a < b < c`` the edges close (``R_ij``, either way round), and whether
    its rotations compose within ``CYCLE_DEG``."""
    def rel(i: int, j: int) -> np.ndarray | None:
        if (i, j) in edges:
            return edges[(i, j)]
        return edges[(j, i)].T if (j, i) in edges else None

    nodes = sorted({n for e in edges for n in e})
    found = []
    for k, a in enumerate(nodes):
        for m, b in enumerate(nodes[k + 1:], k + 1):
            for c in nodes[m + 1:]:
                R_ab, R_bc, R_ac = rel(a, b), rel(b, c), rel(a, c)
                if R_ab is None or R_bc is None or R_ac is None:
                    continue
                found.append(((a, b, c), _angle(R_ac.T @ (R_bc @ R_ab)) <= CYCLE_DEG))
    return found


def component(nodes: Sequence[int], edges: Sequence[tuple[int, int]]) -> list[int]:
    """The largest set of ``nodes`` the edges connect (sorted)."""
    parent = {n: n for n in nodes}

    def root(n: int) -> int:
        while parent[n] != n:
            parent[n] = parent[parent[n]]
            n = parent[n]
        return n

    for i, j in edges:
        parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for n in nodes:
        groups.setdefault(root(n), []).append(n)
    largest: list[int] = max(groups.values(), key=len)
    return sorted(largest)


def spanning_tree_start(n: int, edges: dict[tuple[int, int], np.ndarray],
                        weights: dict[tuple[int, int], float],
                        start: np.ndarray) -> np.ndarray:
    """World-to-camera rotations [n, 3, 3] chained along the maximum-weight spanning tree of
    ``edges`` (slots ``i < j``, ``W_j = R_ij W_i``) from the photo with the most weight, which
    keeps its rotation in ``start`` [n, 3, 3]; photos no edge reaches keep theirs too.

    The start of robust rotation averaging (as Theia's and GLOMAP's solvers take one): from
    cameras that disagree with the pairs by tens of degrees, robust weights judge a right pair
    as an outlier and the solve settles with it unexplained; from a tree every tree edge holds
    exactly and only the loops' residuals are left to judge.
    """
    W = np.array(start, dtype=np.float64, copy=True)
    degree = np.zeros(n)
    for (i, j), w in weights.items():
        if (i, j) in edges:
            degree[i] += w
            degree[j] += w
    if not edges:
        return W
    root = int(np.argmax(degree))
    reached = {root}
    while True:  # Prim: the heaviest edge leaving the reached photos, until none is left
        best = None
        for (i, j) in edges:
            if (i in reached) != (j in reached):
                w = weights.get((i, j), 0.0)
                if best is None or w > best[0]:
                    best = (w, i, j)
        if best is None:
            return W
        _, i, j = best
        R = np.asarray(edges[(i, j)])
        if i in reached:
            W[j] = R @ W[i]
            reached.add(j)
        else:
            W[i] = R.T @ W[j]
            reached.add(i)

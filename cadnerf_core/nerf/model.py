"""A trained job's NeRF, for rendering: load from a job folder, render images in chunks."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from cadnerf_core.nerf.checkpoint import last_checkpoint, load_payload, restore_state
from cadnerf_core.nerf.fields import FieldOutputs
from cadnerf_core.nerf.grid import REFINE_FACTOR, SkipGrid
from cadnerf_core.nerf.rays import image_rays
from cadnerf_core.nerf.state import TrainState
from cadnerf_core.nerf.volrend import march_rays

# ``render.chunk_rays`` 0: rays per display chunk. On a GPU a chunk is a few hundred kernel
# launches and host syncs whatever its size, so a 512-px orbit frame in 64 chunks of 4096 took
# 2.7 s on an H100 (the standard job's 60 frames: 164 s); on the CPU larger chunks only cost
# memory.
GPU_CHUNK_RAYS, CPU_CHUNK_RAYS = 65_536, 4096
# Samples marched between two checks for opaque rays (``volrend.march_rays``). On the CPU every
# sample costs arithmetic, so checking every 4 rather than 8 evaluates fewer behind the surface:
# a 256-px frame of a preview job's mug in 1.64 s against 2.01 s (2 cores, median of 5 rounds),
# within 0.00075 a pixel. On a GPU each check is launches and a host sync: 8, as measured there.
GPU_BLOCK, CPU_BLOCK = 8, 4


def resolve_device(device: str = "auto") -> torch.device:
    """``auto`` is CUDA when available, else the CPU; anything else is passed to torch."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


class TrainedModel:
    """Rendering and density queries over a TrainState (fields, refined poses, skip grid)."""

    def __init__(self, state: TrainState, extra: dict[str, Any] | None = None) -> None:
        self.state = state
        self.extra = extra or {}
        self._render_grid: SkipGrid | None = None
        state.fields.eval()

    @torch.inference_mode()
    def render_grid(self) -> SkipGrid | None:
        """The skip grid of display renders, ``REFINE_FACTOR`` times finer than training's and
        made once from the trained field (training's grid is dilated so the shape can grow,
        which a finished field no longer needs); None when the configuration has no grid."""
        st = self.state
        rcfg = st.config.render
        if not rcfg.use_grid:
            return None
        if self._render_grid is None:
            self._render_grid = st.grid.refined(
                lambda p: st.fields.query(p, None).occupancy, REFINE_FACTOR,
                rcfg.grid_threshold)
        return self._render_grid

    @classmethod
    def load(cls, job_dir: Path, device: str = "auto") -> TrainedModel:
        """The model of a job folder's last checkpoint.

        Raises:
            FileNotFoundError: the folder has no checkpoint.
        """
        found = last_checkpoint(Path(job_dir))
        if found is None:
            raise FileNotFoundError(f"no checkpoint in {job_dir}/checkpoints")
        payload = load_payload(found[1])
        return cls(restore_state(payload, resolve_device(device)), payload.get("extra", {}))

    @property
    def c2w(self) -> np.ndarray:
        """Refined poses of the kept photos. Returns [N, 4, 4]."""
        return self.state.refined_c2w()

    @torch.inference_mode()
    def render_rays_np(self, rays_o: torch.Tensor, rays_d: torch.Tensor,
                       background: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        """Render rays in chunks, with early ray termination.

        Args:
            rays_o, rays_d: [R, 3].
        Returns:
            rgb [R, 3], alpha [R] (tensors).
        """
        st = self.state
        rcfg = st.config.render
        bg = torch.full((3,), background, device=st.device)

        def fn(p: torch.Tensor, d: torch.Tensor | None) -> FieldOutputs:
            return st.fields.query(p, d)

        gpu = st.device.type == "cuda"
        chunk = rcfg.chunk_rays or (GPU_CHUNK_RAYS if gpu else CPU_CHUNK_RAYS)
        rgbs, accs = [], []
        for i in range(0, rays_o.shape[0], chunk):
            rgb, acc = march_rays(fn, rays_o[i:i + chunk], rays_d[i:i + chunk],
                                  rcfg.samples_per_ray,
                                  rcfg.bound, self.render_grid(), bg,
                                  block=GPU_BLOCK if gpu else CPU_BLOCK)
            rgbs.append(rgb.float())
            accs.append(acc.float())
        return torch.cat(rgbs), torch.cat(accs)

    def render_image(self, c2w: np.ndarray, K: np.ndarray, width: int, height: int,
                     background: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Render one view.

        Args:
            c2w: [4, 4] OpenCV camera-to-world in the NeRF's (library model's) frame.
            K: [3, 3] intrinsics for a ``width`` x ``height`` image.
            background: grey level behind the object (1 = white, as trained).
        Returns:
            rgb [H, W, 3] float32 in [0, 1], alpha [H, W] float32.
        """
        dev = self.state.device
        rays_o, rays_d = image_rays(torch.as_tensor(c2w, dtype=torch.float32, device=dev),
                                    torch.as_tensor(K, dtype=torch.float32, device=dev),
                                    width, height)
        rgb, acc = self.render_rays_np(rays_o, rays_d, background)
        return (rgb.reshape(height, width, 3).clamp(0, 1).cpu().numpy().astype(np.float32),
                acc.reshape(height, width).clamp(0, 1).cpu().numpy().astype(np.float32))

    @torch.inference_mode()
    def occupancy(self, points: np.ndarray, chunk: int = 65536,
                  check: Callable[[], None] | None = None) -> np.ndarray:
        """Learned occupancy at points [P, 3]; ``check`` runs between chunks (it may raise to
        cancel). Returns [P] float32 in [0, 1]."""
        pts = torch.as_tensor(points, dtype=torch.float32, device=self.state.device)
        vals = []
        for i in range(0, pts.shape[0], chunk):
            if check is not None:
                check()
            vals.append(self.state.fields.query(pts[i:i + chunk], None).occupancy.float())
        return torch.cat(vals).cpu().numpy() if vals else np.zeros(0, np.float32)

    @torch.inference_mode()
    def colors(self, points: np.ndarray, dirs: np.ndarray, chunk: int = 65536,
               check: Callable[[], None] | None = None) -> np.ndarray:
        """Colour at points [P, 3] seen along unit directions [P, 3]; ``check`` runs between
        chunks. Returns [P, 3]."""
        pts = torch.as_tensor(points, dtype=torch.float32, device=self.state.device)
        d = torch.as_tensor(dirs, dtype=torch.float32, device=self.state.device)
        out = []
        for i in range(0, pts.shape[0], chunk):
            if check is not None:
                check()
            rgb = self.state.fields.query(pts[i:i + chunk], d[i:i + chunk]).rgb
            assert rgb is not None
            out.append(rgb.float())
        return torch.cat(out).cpu().numpy() if out else np.zeros((0, 3), np.float32)

"""Positional encoding, pose corrections, the skip grid and volume rendering, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from cadnerf_core.cameras.conventions import orbit_pose
from cadnerf_core.nerf.encoding import PositionalEncoding, frequency_weights
from cadnerf_core.nerf.fields import FieldOutputs
from cadnerf_core.nerf.grid import SkipGrid, dilate, grid_from_occupancy
from cadnerf_core.nerf.poses import PoseCorrection, in_window
from cadnerf_core.nerf.rays import image_rays
from cadnerf_core.nerf.volrend import composite, ray_sphere, render_rays, sample_distances


def test_annealing_masks_high_frequencies_early() -> None:
    assert torch.allclose(frequency_weights(4, 0.0), torch.zeros(4))
    assert torch.allclose(frequency_weights(4, 1.5), torch.tensor([1.0, 0.5, 0.0, 0.0]))
    assert torch.allclose(frequency_weights(4, 4.0), torch.ones(4))
    enc = PositionalEncoding(4)
    x = torch.rand(5, 3)
    enc.set_progress(0.0)
    out = enc(x)
    assert out.shape == (5, 3 * 9)
    assert torch.equal(out[:, :3], x) and torch.count_nonzero(out[:, 3:]) == 0
    enc.set_progress(0.5)  # alpha = 2: bands 0 and 1 on, 2 and 3 off
    bands = enc(x)[:, 3:].reshape(5, 4, 6)
    assert torch.count_nonzero(bands[:, 2:]) == 0
    assert torch.allclose(bands[:, 0, :3], torch.sin(math.pi * x))


def test_zero_pose_correction_leaves_poses_unchanged() -> None:
    c2w = torch.from_numpy(np.stack([orbit_pose(a, 20.0, 4.0) for a in (0, 90, 200)])).float()
    poses = PoseCorrection(c2w)
    assert torch.allclose(poses(), c2w, atol=1e-6)
    assert torch.allclose(poses(torch.tensor([2, 0])), c2w[[2, 0]], atol=1e-6)
    with torch.no_grad():
        poses.xi[1, 1] = 0.1  # rotate camera 1 about world +Y
    moved = poses()
    assert torch.allclose(moved[[0, 2]], c2w[[0, 2]], atol=1e-6)
    assert not torch.allclose(moved[1], c2w[1], atol=1e-3)
    assert in_window(75, 100, (0.75, 1.0)) and not in_window(74, 100, (0.75, 1.0))


def test_compositing_weights_by_hand() -> None:
    alpha = torch.tensor([[0.0, 0.2, 0.5, 0.0, 1.0], [0.5, 0.5, 0.5, 0.5, 0.5]])
    w = composite(alpha)
    # Row 0: T = 1, 1, 0.8, 0.4, 0.4 -> w = 0, 0.2, 0.4, 0, 0.4.
    assert torch.allclose(w[0], torch.tensor([0.0, 0.2, 0.4, 0.0, 0.4]), atol=1e-5)
    # Row 1: w_i = 0.5^(i+1); accumulated opacity 1 - 0.5^5.
    assert torch.allclose(w[1], 0.5 ** torch.arange(1, 6).float(), atol=1e-5)
    assert w[1].sum().item() == pytest.approx(1 - 0.5**5, abs=1e-5)


def test_ray_sphere_bounds() -> None:
    rays_o = torch.tensor([[0.0, 0.0, -4.0], [0.0, 3.0, -4.0]])
    rays_d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    near, far, hit = ray_sphere(rays_o, rays_d, 1.0)
    assert near[0].item() == pytest.approx(3.0) and far[0].item() == pytest.approx(5.0)
    assert hit.tolist() == [True, False]


def _sphere(radius: float):  # type: ignore[no-untyped-def]
    def fn(points: torch.Tensor, dirs: torch.Tensor) -> FieldOutputs:
        inside = (points.norm(dim=-1) < radius).float()
        rgb = torch.tensor([1.0, 0.0, 0.0]).expand(len(points), 3)
        return FieldOutputs(inside, rgb, None, None)
    return fn


def test_sphere_renders_opaque_centre_and_empty_corners() -> None:
    c2w = torch.from_numpy(orbit_pose(0.0, 0.0, 4.0)).float()
    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 16.0], [0.0, 0.0, 1.0]])
    rays_o, rays_d = image_rays(c2w, K, 32, 32)
    out = render_rays(_sphere(0.5), rays_o, rays_d, 64, 1.0, None, True, False)
    acc = out.acc.reshape(32, 32)
    rgb = out.rgb.reshape(32, 32, 3)  # type: ignore[union-attr]
    assert acc[16, 16].item() == pytest.approx(1.0, abs=1e-4)
    assert acc[0, 0].item() == 0.0 and acc[31, 31].item() == 0.0
    assert torch.allclose(rgb[16, 16], torch.tensor([1.0, 0.0, 0.0]), atol=1e-4)
    assert torch.allclose(rgb[0, 0], torch.ones(3))  # white background
    # The centre ray stops at the sphere's front, 3.5 from the camera (within a sample).
    assert out.depth.reshape(32, 32)[16, 16].item() == pytest.approx(3.5, abs=2.2 / 64)
    # Silhouette radius: 0.5 at distance 4 -> focal * tan(asin(0.5 / 4)) = 5.04 px.
    assert int((acc > 0.5).sum()) == pytest.approx(math.pi * 5.04**2, rel=0.2)


def test_skip_grid_keeps_the_image_and_skips_samples() -> None:
    grid = grid_from_occupancy(lambda p: np.linalg.norm(p, axis=-1) < 0.5, 16, 1.0, 1)
    assert 0.05 < grid.fraction() < 0.3
    assert grid.contains(torch.tensor([[0.0, 0.0, 0.0], [0.9, 0.9, 0.9], [2.0, 0, 0]])).tolist() \
        == [True, False, False]
    c2w = torch.from_numpy(orbit_pose(30.0, 20.0, 4.0)).float()
    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 16.0], [0.0, 0.0, 1.0]])
    rays_o, rays_d = image_rays(c2w, K, 32, 32)
    full = render_rays(_sphere(0.5), rays_o, rays_d, 64, 1.0, None, False, False)
    skip = render_rays(_sphere(0.5), rays_o, rays_d, 64, 1.0, grid, False, False)
    assert torch.allclose(full.acc, skip.acc)
    assert skip.n_evaluated < full.n_evaluated / 3


def test_grid_update_and_dilation() -> None:
    occ = torch.zeros(5, 5, 5)
    occ[2, 2, 2] = 1.0
    assert int(dilate(occ, 1).sum()) == 27
    grid = SkipGrid.full(8, 1.0)
    grid.update(lambda p: (p[:, 0] > 0.5).float(), 0.5, 0)
    assert grid.occupied[7].all() and not grid.occupied[:5].any()


def test_marching_with_early_termination_matches_full_rendering() -> None:
    from cadnerf_core.nerf.volrend import march_rays

    c2w = torch.from_numpy(orbit_pose(30.0, 20.0, 4.0)).float()
    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 16.0], [0.0, 0.0, 1.0]])
    rays_o, rays_d = image_rays(c2w, K, 32, 32)

    def soft(points: torch.Tensor, dirs: torch.Tensor) -> FieldOutputs:
        occ = torch.sigmoid(20 * (0.5 - points.norm(dim=-1)))
        return FieldOutputs(occ, (points + 1) / 2, None, None)

    full = render_rays(soft, rays_o, rays_d, 48, 1.0, None, True, False)
    for block in (8, 4):  # the GPU's and the CPU's checks for opaque rays (nerf.model)
        rgb, acc = march_rays(soft, rays_o, rays_d, 48, 1.0, None, torch.ones(3), block=block)
        assert torch.allclose(acc, full.acc, atol=2e-3)
        assert torch.allclose(rgb, full.rgb, atol=2e-3)  # type: ignore[arg-type]


def test_marching_through_a_grid_evaluates_only_the_rays_that_meet_it() -> None:
    """With a skip grid the display march matches the full render through the same grid,
    rays that meet no occupied cell see the background exactly, and the fields see only
    samples in occupied cells of rays still open."""
    from cadnerf_core.nerf.volrend import march_rays

    c2w = torch.from_numpy(orbit_pose(30.0, 20.0, 4.0)).float()
    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 16.0], [0.0, 0.0, 1.0]])
    rays_o, rays_d = image_rays(c2w, K, 32, 32)
    grid = SkipGrid.full(16, 1.0)
    grid.set_from_values((grid.cell_centres().norm(dim=-1) < 0.6).float(), 0.5, 0)
    seen = []

    def soft(points: torch.Tensor, dirs: torch.Tensor) -> FieldOutputs:
        seen.append(points.shape[0])
        assert grid.contains(points).all()  # only samples in occupied cells
        occ = torch.sigmoid(20 * (0.5 - points.norm(dim=-1)))
        return FieldOutputs(occ, (points + 1) / 2, None, None)

    full = render_rays(soft, rays_o, rays_d, 48, 1.0, grid, True, False)
    seen.clear()
    background = torch.tensor([0.2, 0.4, 0.6])
    rgb, acc = march_rays(soft, rays_o, rays_d, 48, 1.0, grid, background, block=4)
    assert torch.allclose(acc, full.acc, atol=2e-3)
    assert torch.allclose(rgb, full.rgb + (1 - full.acc)[:, None] * (background - 1),  # type: ignore[operator]
                          atol=2e-3)
    near, far, _ = ray_sphere(rays_o, rays_d, 1.0)
    t = sample_distances(near, far, 48, False)  # the march's own samples
    points = rays_o[:, None] + rays_d[:, None] * t[..., None]
    misses = ~grid.contains(points.reshape(-1, 3)).reshape(points.shape[:2]).any(1)
    assert misses.sum() > 100 and torch.equal(rgb[misses], background.expand(int(misses.sum()), 3))
    assert sum(seen) < full.n_evaluated  # opaque rays stop
    # A chunk of rays that all pass beside the sphere: the background, nothing evaluated.
    seen.clear()
    beside = rays_o + torch.tensor([5.0, 0.0, 0.0])
    rgb, acc = march_rays(soft, beside, rays_d, 48, 1.0, grid, background, block=4)
    assert not seen and torch.equal(acc, torch.zeros_like(acc))
    assert torch.equal(rgb, background.expand_as(rgb))


def test_missed_rays_give_finite_pose_gradients() -> None:
    rays_o = torch.tensor([[0.0, 3.0, -4.0], [0.0, 0.0, -4.0]], requires_grad=True)
    rays_d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    near, far, _ = ray_sphere(rays_o, rays_d, 1.0)
    (near.sum() + far.sum()).backward()
    assert rays_o.grad is not None and torch.isfinite(rays_o.grad).all()


def test_deformation_reads_the_points_bands_and_starts_as_the_identity() -> None:
    """G encodes its input with D's ``pos_freqs`` bands and starts as the identity."""
    from cadnerf_core.config import FieldConfig
    from cadnerf_core.nerf.fields import CadNerfFields

    fields = CadNerfFields(FieldConfig(pos_freqs=5), use_deformation=True, bound=1.1)
    assert fields.deformation is not None
    assert fields.deformation.encoding.n_freqs == 5
    assert fields.density.encoding.n_freqs == 5
    offset, correction = fields.deformation(torch.rand(7, 3) * 2 - 1)
    assert offset.shape == (7, 3) and correction.shape == (7,)
    assert torch.count_nonzero(offset) == 0 and torch.count_nonzero(correction) == 0


def test_culling_by_hand_drops_faint_and_hidden_samples() -> None:
    from cadnerf_core.nerf.volrend import Culling, cull_samples

    # One ray of five samples: alpha 0, 0.0005 (faint), 0.5, 1 (opaque), 0.7 (behind it);
    # transmittance before each: 1, 1, 0.9995, 0.49975, 0.
    alpha = torch.tensor([0.0, 0.0005, 0.5, 1.0, 0.7])

    def field(points: torch.Tensor, dirs: torch.Tensor | None) -> FieldOutputs:
        return FieldOutputs(alpha[points[:, 0].long()], None, None, None)

    points = torch.stack([torch.arange(5.0), torch.zeros(5), torch.zeros(5)], -1)[None]
    keep = torch.tensor([[True, True, True, True, True]])
    kept = cull_samples(field, points, keep, Culling(alpha=1e-3, transmittance=1e-3))
    assert kept.tolist() == [[False, False, True, True, False]]
    # Samples the grid skipped count as empty: nothing hides the last one then.
    grid_kept = torch.tensor([[True, True, False, False, True]])
    assert cull_samples(field, points, grid_kept, Culling()).tolist() \
        == [[False, False, False, False, True]]


def test_culled_rendering_matches_and_evaluates_fewer_samples() -> None:
    from cadnerf_core.nerf.volrend import Culling

    c2w = torch.from_numpy(orbit_pose(30.0, 20.0, 4.0)).float()
    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 16.0], [0.0, 0.0, 1.0]])
    rays_o, rays_d = image_rays(c2w, K, 32, 32)

    def soft(points: torch.Tensor, dirs: torch.Tensor | None) -> FieldOutputs:
        occ = torch.sigmoid(20 * (0.5 - points.norm(dim=-1)))
        return FieldOutputs(occ, None if dirs is None else (points + 1) / 2, None, None)

    full = render_rays(soft, rays_o, rays_d, 48, 1.0, None, True, False)
    culled = render_rays(soft, rays_o, rays_d, 48, 1.0, None, True, False, culling=Culling())
    assert torch.allclose(culled.acc, full.acc, atol=0.05)
    assert torch.allclose(culled.rgb, full.rgb, atol=0.05)  # type: ignore[arg-type]
    assert culled.n_evaluated < full.n_evaluated / 2


def test_display_grid_is_finer_and_within_the_training_grid() -> None:
    coarse = grid_from_occupancy(lambda p: np.linalg.norm(p, axis=-1) < 0.5, 8, 1.0, 2)
    fine = coarse.refined(lambda p: (p.norm(dim=-1) < 0.3).float(), 2, 0.5, dilation=1)
    assert fine.resolution == 16
    coarse_at_fine = coarse.contains(fine.cell_centres()).reshape((16,) * 3)
    assert not (fine.occupied & ~coarse_at_fine).any()  # nothing training never sampled
    assert fine.contains(torch.tensor([[0.0, 0.0, 0.0], [0.25, 0.0, 0.0]])).all()
    assert fine.fraction() < coarse.fraction() / 2

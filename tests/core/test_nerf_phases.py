"""The training phases on a tiny box scene: phase one fits the CAD occupancy, phase two pulls a
perturbed camera toward the truth, phase three fits colour, and a seed makes runs repeatable."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
import trimesh

from cadnerf_core.cameras.conventions import (
    intrinsics_from_fov,
    orbit_pose,
    project,
    rotation_angle_deg,
    se3_exp,
)
from cadnerf_core.cameras.matches import PairMatch
from cadnerf_core.config import PipelineConfig
from cadnerf_core.errors import JobCancelled
from cadnerf_core.intake.crop import CropBox
from cadnerf_core.mesh.renderer import MeshRenderer
from cadnerf_core.nerf import blur, phases
from cadnerf_core.nerf.epipolar import match_terms
from cadnerf_core.nerf.grid import SkipGrid, grid_from_occupancy
from cadnerf_core.nerf.model import TrainedModel
from cadnerf_core.nerf.passes import ray_passes
from cadnerf_core.nerf.state import TrainData, TrainState
from cadnerf_core.progress import Progress
from tests.configs import tiny_config

SIZE = 32
DEVICE = torch.device("cpu")


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _box() -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=(1.0, 0.5, 0.7))
    mesh.visual.face_colors = np.tile([200, 60, 40, 255], (len(mesh.faces), 1))
    return mesh


def _scene(mesh: trimesh.Trimesh, size: int = SIZE) -> tuple[TrainData, np.ndarray]:
    renderer = MeshRenderer(mesh)
    K = intrinsics_from_fov(40.0, size)
    c2w = np.stack([orbit_pose(a, e, 4.0) for a, e in ((10, 15), (80, 30), (150, 20),
                                                         (230, 40), (300, 25))])
    views = [renderer.render(K, pose, size, size) for pose in c2w]
    data = TrainData.from_numpy(np.stack([v.rgb for v in views]),
                                np.stack([v.mask for v in views]),
                                np.broadcast_to(K, (len(c2w), 3, 3)), DEVICE)
    return data, c2w


def _sampler(mesh: trimesh.Trimesh, seed: int = 0) -> phases.OccupancySampler:
    rng = np.random.default_rng(seed)

    def sample(n: int) -> tuple[np.ndarray, np.ndarray]:
        points = rng.uniform(-1.0, 1.0, (min(n, 4096), 3)).astype(np.float32)
        return points, mesh.contains(points).astype(np.float32)
    return sample


def _config(**overrides: object) -> PipelineConfig:
    return tiny_config(**{"field.hidden": 32, "field.pos_freqs": 4, **overrides})


def test_phase_one_reduces_bce() -> None:
    mesh = _box()
    state = TrainState.create(_config(**{"phase1.steps": 60, "phase1.lr": 3e-3}),
                              np.eye(4)[None], DEVICE)
    phases.run_phase1(state, _sampler(mesh))
    points, occ = _sampler(mesh, seed=1)(2000)

    bce = state.history["phase1/bce"]
    assert np.mean(bce[-5:]) < 0.6 * np.mean(bce[:5])
    with torch.no_grad():
        logit, _ = state.fields.density(torch.from_numpy(points))
    accuracy = ((logit > 0).float().numpy() == occ).mean()
    assert accuracy > 0.85


def test_phase_two_moves_a_perturbed_pose_toward_the_truth() -> None:
    mesh = _box()
    data, c2w = _scene(mesh)
    # ~6.7 degrees about the camera's own centre: the box moves by ~2.5 pixels in the photo.
    # (The same turn about the object's centre moves the corners by a quarter of a pixel at
    # this size, too little for a silhouette to tell; the score was then a matter of CPU
    # rounding.) Silhouettes fix where the object appears, which a rotation and a translation
    # can trade between them, so the measure is the corners' reprojection error.
    xi = torch.zeros(len(c2w), 6, dtype=torch.float64)
    xi[2, :3] = torch.tensor([0.0, 1.0, 0.5]) * math.radians(6.0)
    c2w_init = (torch.from_numpy(c2w) @ se3_exp(xi)).numpy()
    K = intrinsics_from_fov(40.0, SIZE)

    def corner_error(pose: np.ndarray) -> float:
        return float(np.abs(project(mesh.vertices, K, pose)
                            - project(mesh.vertices, K, c2w[2])).mean())
    # D fitted to the true shape and held still: only the pose can explain the silhouette.
    cfg = _config(**{"phase1.steps": 200, "phase1.lr": 3e-3, "phase1.batch_points": 2048,
                     "use_deformation": False, "phase2.train_density": False,
                     "phase2.steps": 120, "phase2.rays": 512,
                     "phase2.pose_lr": 4e-3, "phase2.pose_window": (0.0, 1.0),
                     "phase2.anneal": (0.0, 0.0), "render.samples_per_ray": 32})
    grid = grid_from_occupancy(mesh.contains, 16, cfg.render.bound, 2)
    state = TrainState.create(cfg, c2w_init, DEVICE, grid)
    phases.run_phase1(state, _sampler(mesh))
    before = corner_error(c2w_init[2])
    d_before = [p.detach().clone() for p in state.fields.density.parameters()]
    phases.run_phase2(state, data)
    after = corner_error(state.refined_c2w()[2])
    assert before > 2.0
    assert after < 0.4 * before
    assert all(torch.equal(a, b) for a, b in
               zip(d_before, state.fields.density.parameters(), strict=True))


@pytest.mark.parametrize("optimise_poses", [True, False])
def test_phase_two_with_the_shape_held_runs_only_the_pose_window(optimise_poses: bool) -> None:
    """No G and ``phase2.train_density`` off: the shape stays the CAD model's, so only the
    steps inside the pose window run (none when the poses are not optimised); D is untouched
    and trainable again afterwards."""
    data, c2w = _scene(_box())
    cfg = _config(**{"use_deformation": False, "phase2.train_density": False,
                     "phase2.steps": 8, "phase2.rays": 64, "phase2.pose_window": (0.5, 1.0),
                     "optimise_poses": optimise_poses})
    state = TrainState.create(cfg, c2w, DEVICE)
    d_before = [p.detach().clone() for p in state.fields.density.parameters()]
    phases.run_phase2(state, data)
    assert len(state.history.get("phase2/loss", [])) == (4 if optimise_poses else 0)
    assert bool(state.poses.xi.detach().abs().sum() > 0) == optimise_poses
    assert all(torch.equal(a, b) for a, b in
               zip(d_before, state.fields.density.parameters(), strict=True))
    assert all(p.requires_grad for p in state.fields.density.parameters())


def test_phase_three_fits_colour_and_a_seed_repeats_a_run() -> None:
    mesh = _box()
    data, c2w = _scene(mesh)
    cfg = _config(**{"phase1.steps": 40, "phase3.steps": 60, "phase3.rays": 256,
                     "phase3.lr": 3e-3})

    def run() -> tuple[TrainState, float]:
        state = TrainState.create(cfg, c2w, DEVICE,
                                  grid_from_occupancy(mesh.contains, 8, cfg.render.bound, 1))
        phases.run_phase1(state, _sampler(mesh))
        phases.run_phase2(state, data)
        phases.run_phase3(state, data)
        rgb, alpha = TrainedModel(state).render_image(c2w[0], data.K[0].numpy(), SIZE, SIZE)
        assert rgb.shape == (SIZE, SIZE, 3) and alpha.shape == (SIZE, SIZE)
        return state, float(np.mean((rgb - data.images[0].numpy()) ** 2))

    first, mse_first = run()
    loss = first.history["phase3/loss"]
    assert np.mean(loss[-10:]) < np.mean(loss[:10])
    second, mse_second = run()
    assert first.history == second.history
    assert mse_second == pytest.approx(mse_first, rel=1e-6)
    # The display chunk is a memory setting: 64-ray chunks render the same image as the
    # automatic size (one chunk for this small image).
    whole = TrainedModel(first).render_image(c2w[0], data.K[0].numpy(), SIZE, SIZE)
    render = first.config.render.model_copy(update={"chunk_rays": 64})
    first.config = first.config.model_copy(update={"render": render})
    chunked = TrainedModel(first).render_image(c2w[0], data.K[0].numpy(), SIZE, SIZE)
    assert SIZE * SIZE > 64
    for a, b in zip(whole, chunked, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-5)


def test_scene_mode_learns_the_background() -> None:
    mesh = _box()
    data, c2w = _scene(mesh)
    blue = torch.tensor([0.1, 0.2, 0.9])
    data.scene_images = torch.where(data.masks[..., None] > 0, data.images, blue)
    cfg = _config(**{"scene_mode": True, "phase1.steps": 20, "phase3.steps": 5,
                     "phase3.scene_steps": 80, "phase3.rays": 256, "phase3.lr": 3e-3})
    state = TrainState.create(cfg, c2w, DEVICE,
                              grid_from_occupancy(mesh.contains, 8, cfg.render.bound, 1))
    assert state.fields.background is not None
    phases.run_phase1(state, _sampler(mesh))
    phases.run_phase3(state, data)
    loss = state.history["phase3/scene_loss"]
    assert len(loss) == 80 and np.mean(loss[-10:]) < 0.5 * np.mean(loss[:10])
    with torch.no_grad():
        colour = state.fields.background(torch.tensor([[0.0, 0.0, -1.0]]))[0]
    assert colour[2] > colour[0] + 0.3


def test_cancel_is_checked_on_every_step_between_reports() -> None:
    calls = []

    def cancel() -> bool:
        calls.append(1)
        return len(calls) >= 3

    progress = Progress(cancel=cancel)
    # Steps 0 and 1 of a 1000-step phase are not report steps; the third check cancels.
    phases._report(progress, "phase1", 0, 1000)
    phases._report(progress, "phase1", 1, 1000)
    with pytest.raises(JobCancelled):
        phases._report(progress, "phase1", 2, 1000)


def test_a_grid_update_that_finds_nothing_keeps_the_previous_grid() -> None:
    occupied = torch.zeros((4, 4, 4), dtype=torch.bool)
    occupied[1:3, 1:3, 1:3] = True
    grid = SkipGrid(occupied.clone(), 1.0)
    grid.set_from_values(torch.zeros(64), threshold=0.5, dilation=1)
    assert torch.equal(grid.occupied, occupied)
    values = torch.zeros(64)
    values[0] = 1.0
    grid.set_from_values(values, threshold=0.5, dilation=0)
    assert int(grid.occupied.sum()) == 1


@pytest.mark.parametrize("train_density", [True, False])
def test_phase_two_trains_d_only_when_asked(train_density: bool) -> None:
    """``phase2.train_density``: D learns beside G (ours), or G deforms a frozen D (the
    paper's phase two); G learns either way, and D is trainable again for phase three."""
    mesh = _box()
    data, c2w = _scene(mesh)
    cfg = _config(**{"phase2.steps": 5, "phase2.rays": 128,
                     "phase2.train_density": train_density})
    state = TrainState.create(cfg, c2w, DEVICE)
    assert state.fields.deformation is not None
    d_before = [p.detach().clone() for p in state.fields.density.parameters()]
    g_before = [p.detach().clone() for p in state.fields.deformation.parameters()]
    phases.run_phase2(state, data)
    d_moved = any(not torch.equal(a, b) for a, b in
                  zip(d_before, state.fields.density.parameters(), strict=True))
    g_moved = any(not torch.equal(a, b) for a, b in
                  zip(g_before, state.fields.deformation.parameters(), strict=True))
    assert g_moved
    assert d_moved == train_density
    assert all(p.requires_grad for p in state.fields.density.parameters())


def test_target_blur_halves_at_each_third_of_the_pose_window() -> None:
    window = (0.0, 0.75)
    blurs = [blur.target_blur(step, 120, window, 0.0625) for step in (0, 29, 30, 60, 89, 90)]
    assert blurs == [0.0625, 0.0625, 0.03125, 0.015625, 0.015625, 0.0]
    assert blur.target_blur(0, 120, (0.0, 0.0), 0.0625) == 0.0  # frozen poses: sharp
    assert blur.target_blur(0, 120, window, 0.0) == 0.0


def test_blur_images_is_a_normalised_gaussian_of_the_given_width() -> None:
    images = torch.zeros(1, 41, 41, 3)
    images[0, 20, 20] = 1.0
    blurred = blur.blur_images(images, 2.0)
    assert blurred.shape == images.shape
    assert float(blurred.sum()) == pytest.approx(3.0, rel=1e-5)  # mass kept, per channel
    profile = blurred[0, 20, :, 0] / blurred[0, 20, :, 0].sum()
    offsets = torch.arange(41.0) - 20
    assert math.sqrt(float((profile * offsets**2).sum())) == pytest.approx(2.0, rel=0.02)
    flat = torch.full((2, 8, 8, 3), 0.7)
    assert torch.allclose(blur.blur_images(flat, 20.0), flat)  # radius clipped to the image
    assert blur.blur_images(images, 0.0) is images


def test_ray_passes_split_a_step_into_shares_that_sum_to_one() -> None:
    state = TrainState.create(_config(**{"render.train_pass_rays": 300}), np.eye(4)[None],
                              DEVICE)
    passes = ray_passes(state, 1000)
    assert [(p.start, p.stop) for p, _ in passes] == [(0, 300), (300, 600), (600, 900),
                                                      (900, 1000)]
    assert sum(share for _, share in passes) == pytest.approx(1.0)
    assert ray_passes(state, 200) == [(slice(0, 200), 1.0)]
    auto = TrainState.create(_config(), np.eye(4)[None], DEVICE)
    assert [p.stop for p, _ in ray_passes(auto, 5000)] == [2048, 4096, 5000]


@pytest.mark.parametrize("phase", [2, 3])
def test_a_step_in_passes_learns_what_one_pass_learns(phase: int) -> None:
    """The same rays in one pass or in four: the same loss and the same update of every
    network and pose (up to float rounding), with the poses optimised and G on."""
    mesh = _box()
    data, c2w = _scene(mesh)
    results = []
    for pass_rays in (512, 128):
        cfg = _config(**{"render.train_pass_rays": pass_rays, "render.samples_per_ray": 16,
                         "phase2.rays": 512, "phase3.rays": 512})
        state = TrainState.create(cfg, c2w, DEVICE,
                                  grid_from_occupancy(mesh.contains, 8, cfg.render.bound, 1))
        params = list(state.fields.parameters())
        optimizer = torch.optim.SGD(params, lr=1.0)
        pose_optimizer = torch.optim.SGD(state.poses.parameters(), lr=1.0)
        torch.manual_seed(5)
        if phase == 2:
            loss = phases.phase2_step(state, data, optimizer, pose_optimizer, 0)
        else:
            loss = phases.phase3_step(state, data, optimizer, pose_optimizer)
        results.append((loss, [p.detach().clone() for p in params],
                        state.poses.xi.detach().clone()))
    (loss_one, params_one, pose_one), (loss_four, params_four, pose_four) = results
    assert loss_four == pytest.approx(loss_one, rel=1e-5)
    for a, b in zip(params_one, params_four, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
    assert pose_one.abs().max() > 0
    torch.testing.assert_close(pose_one, pose_four, rtol=1e-4, atol=1e-7)


def test_phase_two_learns_a_shared_focal_length_within_its_bound() -> None:
    mesh = _box()
    data, c2w = _scene(mesh)
    too_long = 1.25  # the photos' focal length, as retrieval estimated it, 25 % too long
    data = TrainData(data.images, data.masks, data.K * torch.tensor(
        [[too_long, 1.0, too_long], [1.0, too_long, too_long], [1.0, 1.0, 1.0]]) /
        torch.tensor([[1.0, 1.0, too_long], [1.0, 1.0, too_long], [1.0, 1.0, 1.0]]))
    assert torch.allclose(data.K[0, :2, 2], torch.tensor([SIZE / 2, SIZE / 2]))
    cfg = _config(**{"phase1.steps": 200, "phase1.lr": 3e-3, "phase1.batch_points": 2048,
                     "use_deformation": False, "phase2.train_density": False,
                     "phase2.steps": 160, "phase2.rays": 512, "phase2.pose_lr": 1e-9,
                     "phase2.pose_window": (0.0, 1.0), "phase2.anneal": (0.0, 0.0),
                     "phase2.focal_bound": 1.6, "phase2.focal_lr": 5e-2,
                     "render.samples_per_ray": 32})
    grid = grid_from_occupancy(mesh.contains, 16, cfg.render.bound, 2)
    fixed = TrainState.create(cfg, c2w, DEVICE, grid)  # focal known: never moves
    state = TrainState.create(cfg, c2w, DEVICE, grid, learn_focal=True)
    for s in (fixed, state):
        phases.run_phase1(s, _sampler(mesh))
        phases.run_phase2(s, data)
    assert fixed.focal_scale() == 1.0
    assert abs(state.focal_scale() * too_long - 1.0) < 0.5 * (too_long - 1.0)
    with torch.no_grad():
        state.poses.focal_logit.fill_(50.0)
        K = state.poses.intrinsics(data.K[:1])[0]
    assert state.focal_scale() == pytest.approx(1.6)
    assert K[0, 0] == pytest.approx(1.6 * float(data.K[0, 0, 0]))
    assert torch.equal(K[:, 2], data.K[0, :, 2]) and K[0, 1] == 0.0


def _surface_matches(mesh: trimesh.Trimesh, c2w: np.ndarray, K: np.ndarray,
                     n: int = 400) -> list[PairMatch]:
    """Matches between every pair of views: surface points both cameras see (the box is
    convex: a face seen from a camera is visible), in pixels with centres at integers."""
    points, faces = trimesh.sample.sample_surface(mesh, n, seed=0)
    normals = mesh.face_normals[faces]
    seen = [np.einsum("ij,ij->i", normals, pose[:3, 3] - points) > 0 for pose in c2w]
    pairs = []
    for i in range(len(c2w)):
        for j in range(i + 1, len(c2w)):
            both = seen[i] & seen[j]
            x_i, x_j = (project(points[both], K, c2w[k]) - 0.5 for k in (i, j))
            pairs.append(PairMatch(i, j, int(both.sum()), int(both.sum()), 0.1, None, None,
                                   np.stack([x_i, x_j], axis=1)))
    return pairs


def test_phase_two_with_matches_turns_back_a_camera_the_silhouettes_cannot() -> None:
    """A camera turned 10 degrees about the object (its silhouette changes little): phase two
    brings most of the turn back with the views' matches (the epipolar loss), not without."""
    mesh = _box()
    size = 64
    data, c2w = _scene(mesh, size)
    K = intrinsics_from_fov(40.0, size)
    turn = np.eye(4)
    turn[:3, :3] = trimesh.transformations.rotation_matrix(math.radians(10.0), [0, 1, 0])[:3, :3]
    c2w_init = c2w.copy()
    c2w_init[2] = turn @ c2w[2]
    box = CropBox(0.0, 0.0, float(size), size)
    terms = match_terms(_surface_matches(mesh, c2w, K), range(len(c2w)), [box] * len(c2w),
                        20, DEVICE)
    cfg = _config(**{"phase1.steps": 200, "phase1.lr": 3e-3, "phase1.batch_points": 2048,
                     "use_deformation": False, "phase2.train_density": False,
                     "phase2.steps": 100, "phase2.rays": 256, "phase2.pose_lr": 4e-3,
                     "phase2.pose_window": (0.0, 1.0), "phase2.anneal": (0.0, 0.0),
                     "render.samples_per_ray": 32, "phase2.lambda_matches": 0.05})
    grid = grid_from_occupancy(mesh.contains, 16, cfg.render.bound, 2)

    def error(matched: bool) -> float:
        state = TrainState.create(cfg, c2w_init, DEVICE, grid)
        phases.run_phase1(state, _sampler(mesh))
        phases.run_phase2(state, dataclasses.replace(data, matches=terms if matched else None))
        refined = state.refined_c2w()
        # Relative to camera 0, as the matches see it (the silhouettes hold the frame).
        relative = refined[2, :3, :3].T @ refined[0, :3, :3]
        truth = c2w[2, :3, :3].T @ c2w[0, :3, :3]
        return float(rotation_angle_deg(relative @ truth.T))

    without, with_matches = error(False), error(True)
    assert without > 3.0
    assert with_matches < 0.5 * without

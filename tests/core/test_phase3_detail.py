"""Phase three's detail levers: the colour planes (``nerf.fields.ColorPlanes``) read
bilinearly at a point's three projections, learn at their own rate, let phase three fit a
texture finer than the colour network alone fits, and phase three's larger crops keep the
cameras they were cut for; a share of the rays falls on the objects."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import trimesh

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose, project
from cadnerf_core.config import FieldConfig
from cadnerf_core.mesh.renderer import MeshRenderer
from cadnerf_core.nerf import phases
from cadnerf_core.nerf.fields import ColorPlanes, plane_sides
from cadnerf_core.nerf.grid import grid_from_occupancy
from cadnerf_core.nerf.model import TrainedModel
from cadnerf_core.nerf.state import TrainData, TrainState
from tests.configs import tiny_config

pytestmark = pytest.mark.usefixtures("one_torch_thread")
DEVICE = torch.device("cpu")


def test_plane_sides_run_geometrically_from_32_to_the_finest() -> None:
    assert plane_sides(FieldConfig(color_planes=0)) == []
    assert plane_sides(FieldConfig(color_planes=1, color_plane_size=256)) == [256]
    assert plane_sides(FieldConfig(color_planes=2, color_plane_size=512)) == [32, 512]
    assert plane_sides(FieldConfig(color_planes=3, color_plane_size=128)) == [32, 64, 128]
    assert plane_sides(FieldConfig(color_planes=2, color_plane_size=16)) == [16, 16]


def test_a_point_reads_the_sum_of_its_three_projections_bilinearly() -> None:
    planes = ColorPlanes(FieldConfig(color_planes=1, color_plane_size=17,
                                     color_plane_channels=1), bound=2.0)
    texels = torch.zeros(3, 1, 17, 17)  # a texel every 0.25 over [-2, 2]
    texels[0, 0, 12, 4] = 1.0  # xy plane: column x = -1, row y = +1
    texels[1, 0, 0, 8] = 10.0  # xz plane: column x = 0, row z = -2
    texels[2, 0, 16, 16] = 100.0  # yz plane: column y = +2, row z = +2
    with torch.no_grad():
        planes.planes[0].copy_(texels)
    points = torch.tensor([[-1.0, 1.0, 0.5],  # on the xy texel only
                           [0.0, 0.5, -2.0],  # on the xz texel only
                           [0.5, 2.0, 2.0],  # on the yz texel only
                           [-0.875, 1.0, 0.5],  # half a texel off the xy one
                           [-1.0, 1.0, 9.0]])  # outside: clamped to the border
    assert planes.out_dim == 1
    np.testing.assert_allclose(planes(points)[:, 0].detach().numpy(), [1.0, 10.0, 100.0, 0.5, 1.0],
                               atol=1e-6)


def test_smoothness_is_zero_on_constant_planes_and_grows_with_texel_noise() -> None:
    planes = ColorPlanes(FieldConfig(color_planes=2, color_plane_size=64), bound=1.0)
    with torch.no_grad():
        for p in planes.planes:
            p.fill_(0.3)
    assert float(planes.smoothness().detach()) == pytest.approx(0.0, abs=1e-12)
    with torch.no_grad():
        planes.planes[1].add_(torch.randn_like(planes.planes[1]))
    assert float(planes.smoothness().detach()) > 1.0


def _striped_box() -> trimesh.Trimesh:
    """A box whose faces carry narrow stripes of two colours: detail a 16-wide colour
    network with D's feature alone blurs."""
    mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).subdivide().subdivide().subdivide()
    centres = mesh.triangles_center
    stripe = (np.floor((centres[:, 0] + centres[:, 1] + centres[:, 2]) * 8) % 2).astype(bool)
    colours = np.where(stripe[:, None], [230, 40, 30, 255], [30, 60, 220, 255])
    mesh.visual.face_colors = colours.astype(np.uint8)
    return mesh


def _fit(mesh: trimesh.Trimesh, planes: int) -> tuple[TrainState, float]:
    size = 48
    K = intrinsics_from_fov(40.0, size)
    c2w = np.stack([orbit_pose(a, e, 3.5) for a, e in ((20, 25), (110, 30), (200, 20),
                                                         (290, 35))])
    renderer = MeshRenderer(mesh)
    views = [renderer.render(K, pose, size, size) for pose in c2w]
    data = TrainData.from_numpy(np.stack([v.rgb for v in views]),
                                np.stack([v.mask for v in views]),
                                np.broadcast_to(K, (len(c2w), 3, 3)), DEVICE)
    cfg = tiny_config(**{"field.color_planes": planes, "field.color_plane_size": 128,
                         "field.hidden": 32, "field.color_hidden": 32,
                         "render.samples_per_ray": 32,
                         "optimise_poses": False, "phase1.steps": 100, "phase3.steps": 150,
                         "phase3.rays": 512,
                         "phase3.lr": 3e-3, "phase3.mask_weight": 0.0})
    state = TrainState.create(cfg, c2w, DEVICE,
                              grid_from_occupancy(mesh.contains, 8, cfg.render.bound, 1))
    phases.run_phase1(state, _occupancy(mesh))  # D as the box: the test is about colour
    phases.run_phase3(state, data)
    rgb, _ = TrainedModel(state).render_image(c2w[1], K, size, size)
    inside = views[1].mask
    return state, float(np.mean((rgb[inside] - views[1].rgb[inside]) ** 2))


def _occupancy(mesh: trimesh.Trimesh) -> phases.OccupancySampler:
    rng = np.random.default_rng(0)

    def sample(n: int) -> tuple[np.ndarray, np.ndarray]:
        points = rng.uniform(-1.0, 1.0, (min(n, 4096), 3)).astype(np.float32)
        return points, mesh.contains(points).astype(np.float32)
    return sample


def test_the_planes_let_phase_three_fit_stripes_the_colour_network_alone_blurs() -> None:
    mesh = _striped_box()
    plain, plain_mse = _fit(mesh, 0)
    with_planes, planes_mse = _fit(mesh, 2)
    assert plain.fields.color.planes is None
    assert with_planes.fields.color.planes is not None
    assert planes_mse < 0.6 * plain_mse, (planes_mse, plain_mse)


def test_phase_three_trains_the_planes_at_their_own_rate() -> None:
    cfg = tiny_config(**{"field.color_planes": 2, "phase3.lr": 1e-3, "phase3.plane_lr": 0.05})
    state = TrainState.create(cfg, np.stack([orbit_pose(0, 20, 4.0)]), DEVICE)
    groups = phases._phase3_groups(state, cfg.phase3)
    planes = state.fields.color.planes
    assert planes is not None
    assert [g["lr"] for g in groups] == [1e-3, 0.05]
    assert {id(p) for p in groups[1]["params"]} == {id(p) for p in planes.parameters()}
    others = {id(p) for p in groups[0]["params"]}
    assert not others & {id(p) for p in planes.parameters()}
    assert others == {id(p) for name, p in state.fields.named_parameters()
                      if not name.startswith(("background.", "color.planes."))}


def test_phase_three_crops_at_a_larger_size_keep_the_cameras(tmp_path: Path,
                                                             tiny_library: Any) -> None:
    from cadnerf_core.pipeline import phase3_data, run_intake, training_data
    from cadnerf_core.progress import Progress
    from tests.core.test_pipeline import write_job

    write_job(tmp_path, tiny_library)
    config = tiny_config(**{"phase3.image_size": 96})
    intake = run_intake(tmp_path, tiny_library, config, Progress())
    margin = tiny_library.spec.margin
    small = training_data(intake, config, margin, DEVICE)
    large = phase3_data(intake, config, margin, DEVICE, small)
    assert (small.width, large.width) == (32, 96)
    # At the job's own size the crops are retrieval's: their intrinsics are its K_canon.
    np.testing.assert_array_equal(small.K.numpy(), np.stack(
        [m.K_canon for m in intake.retrieval.kept]).astype(np.float32))
    same = phase3_data(intake, tiny_config(), margin, DEVICE, small)
    assert same is small
    # A point on the object lands at the same place in both crops, in units of their side.
    c2w = np.stack([m.c2w for m in intake.retrieval.kept])
    point = np.array([[0.1, -0.2, 0.15]])
    for i in range(len(c2w)):
        uv_small = project(point, small.K[i].numpy(), c2w[i])[0]
        uv_large = project(point, large.K[i].numpy(), c2w[i])[0]
        np.testing.assert_allclose(uv_large / 96, uv_small / 32, atol=2e-3)
    # And the crops show the same photo: the large one shrunk is the small one.
    shrunk = torch.nn.functional.avg_pool2d(large.images.permute(0, 3, 1, 2), 3)
    assert float((shrunk.permute(0, 2, 3, 1) - small.images).abs().mean()) < 0.03


def test_a_share_of_the_rays_falls_on_the_objects_and_their_edge() -> None:
    from cadnerf_core.nerf.batch import object_pixels, sample_pixels

    masks = np.zeros((2, 20, 20), bool)
    masks[1, 8:10, 8:10] = True  # one photo's object: 2 x 2 pixels
    data = TrainData.from_numpy(np.ones((2, 20, 20, 3), np.float32), masks,
                                np.broadcast_to(np.eye(3), (2, 3, 3)), DEVICE)
    on_object = object_pixels(data)
    assert len(on_object) == 36  # the 2 x 2 pixels and their 2-pixel edge
    torch.manual_seed(0)
    img, x, y = sample_pixels(data, 1000, 0.75, on_object)
    near = (img == 1) & (x >= 6) & (x < 12) & (y >= 6) & (y < 12)
    assert bool(near[:750].all())
    # The rest anywhere: about as often on the object as its 36 of 800 pixels.
    assert float(near[750:].float().mean()) < 0.15
    torch.manual_seed(0)
    img, x, y = sample_pixels(data, 1000)  # uniform
    uniform = (img == 1) & (x >= 6) & (x < 12) & (y >= 6) & (y < 12)
    assert float(uniform.float().mean()) < 0.1


def test_smoothness_in_a_window_reads_only_that_window() -> None:
    planes = ColorPlanes(FieldConfig(color_planes=1, color_plane_size=64), bound=1.0)
    with torch.no_grad():
        planes.planes[0].zero_()
        planes.planes[0][:, :, 40, 40] = 1.0  # one bright texel
    whole = float(planes.smoothness().detach())
    assert whole > 0
    seen = set()
    for seed in range(20):
        torch.manual_seed(seed)
        part = float(planes.smoothness(window=32).detach())
        seen.add(part > 0)
        assert part == pytest.approx(0.0) or part > whole  # a window's mean, larger if hit
    assert seen == {False, True}  # some windows hold the texel, some do not
    torch.manual_seed(0)
    assert float(planes.smoothness(window=64).detach()) == pytest.approx(whole)


def test_a_job_with_the_detail_levers_runs_and_reloads_its_planes(tmp_path: Path,
                                                                  tiny_library: Any) -> None:
    from cadnerf_core.pipeline import run_job
    from tests.core.test_pipeline import write_job

    write_job(tmp_path, tiny_library, overrides={
        "field.color_planes": 2, "field.color_plane_size": 64, "phase3.image_size": 48,
        "phase3.object_rays": 0.5})
    result = run_job(tmp_path, tiny_library, device="cpu")
    assert "views/000.png" in result.artifacts and "mesh.glb" in result.artifacts
    model = TrainedModel.load(tmp_path, "cpu")
    planes = model.state.fields.color.planes
    assert planes is not None and [int(p.shape[-1]) for p in planes.planes] == [32, 64]
    # What phase three learned is in the planes: no longer their small random start.
    assert float(planes.planes[1].detach().abs().max()) > 0.011

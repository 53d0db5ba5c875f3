"""Evaluation harness: alignment math on synthetic poses, and a whole tiny evaluation."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cadnerf_core.cameras.conventions import orbit_pose
from cadnerf_core.evaluation.frame import Similarity, centre_similarity
from cadnerf_core.jobfolder import JobFolder
from tests.configs import TINY_OVERRIDES, TINY_PRESET, tiny_request

# ---------------------------------------------------------------- alignment on synthetic poses


def _gt_poses(n: int = 6, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([orbit_pose(az, el, 2.5) for az, el in
                     zip(np.sort(rng.uniform(0, 360, n)), rng.uniform(0, 60, n), strict=True)])


def _random_similarity(seed: int = 1) -> Similarity:
    R = Rotation.random(random_state=seed).as_matrix()
    return Similarity(scale=1.7, R=R, t=np.array([0.3, -1.2, 2.0]))


def test_similarity_copy_maps_back_exactly() -> None:
    gt = _gt_poses()
    sim = _random_similarity()
    moved = sim.apply_to_poses(gt)
    # Rotations stay rotations; the moved centres are the similarity of the old ones.
    assert np.allclose(moved[:, :3, :3] @ np.swapaxes(moved[:, :3, :3], 1, 2), np.eye(3),
                       atol=1e-9)
    assert np.allclose(moved[:, :3, 3], 1.7 * gt[:, :3, 3] @ sim.R.T + sim.t)
    found = centre_similarity(gt, moved)
    assert found.scale == pytest.approx(1.7)
    assert np.allclose(found.R, sim.R, atol=1e-9)
    assert np.allclose(found.t, sim.t, atol=1e-9)
    # Held-out cameras follow the training cameras' similarity exactly.
    held_out = _gt_poses(4, seed=5)
    assert np.allclose(found.apply_to_poses(held_out), sim.apply_to_poses(held_out), atol=1e-9)
    back = centre_similarity(moved, gt).apply_to_poses(moved)
    assert np.allclose(back, gt, atol=1e-9)


def test_similarity_with_noise_is_close_not_exact() -> None:
    gt = _gt_poses(8)
    sim = _random_similarity(3)
    moved = sim.apply_to_poses(gt)
    moved[:, :3, 3] += np.random.default_rng(4).normal(0, 0.01, (8, 3))
    found = centre_similarity(gt, moved)
    assert found.scale == pytest.approx(1.7, rel=0.02)
    assert not np.allclose(found.t, sim.t, atol=1e-9)
    assert np.allclose(found.t, sim.t, atol=0.1)


def test_similarity_then_composes() -> None:
    gt = _gt_poses()
    first = _random_similarity(2)
    R = Rotation.from_rotvec([0.02, -0.05, 0.01]).as_matrix()
    t = np.array([0.1, 0.0, -0.2])
    both = first.then(0.9, R, t).apply_to_poses(gt)
    step = first.apply_to_poses(gt)
    assert np.allclose(both[:, :3, :3], R @ step[:, :3, :3], atol=1e-12)
    assert np.allclose(both[:, :3, 3], (0.9 * step[:, :3, 3]) @ R.T + t, atol=1e-12)


class _Ball:
    """A stand-in trained model: an opaque ball off the origin whose colour changes across it
    (so its position and turn show in a picture), with the interface ``fit_frame`` uses."""

    def __init__(self, centre: tuple[float, float, float] = (0.15, -0.1, 0.05)) -> None:
        from types import SimpleNamespace

        import torch

        from cadnerf_core.nerf.fields import FieldOutputs

        at = torch.tensor(centre)

        class Fields(torch.nn.Module):
            def __init__(self) -> None:
                super().__init__()
                self.dummy = torch.nn.Parameter(torch.zeros(1))  # fit_frame freezes parameters

            def query(self, p: torch.Tensor, d: torch.Tensor) -> FieldOutputs:
                rel = p - at
                occupancy = torch.sigmoid((0.5 - rel.norm(dim=-1)) * 30.0)
                rgb = torch.stack([0.5 + 0.5 * torch.sin(6 * rel[:, 0]),
                                   0.5 + 0.5 * torch.sin(6 * rel[:, 1]),
                                   0.5 + 0.5 * torch.cos(6 * rel[:, 2])], dim=-1)
                return FieldOutputs(occupancy, rgb + 0 * self.dummy, None, None)

        render = SimpleNamespace(samples_per_ray=48, bound=1.2)
        self.state = SimpleNamespace(device="cpu", fields=Fields(), grid=None,
                                     config=SimpleNamespace(render=render))

    def render(self, c2w: np.ndarray, K: np.ndarray, size: int) -> np.ndarray:
        """The ball seen from c2w [4, 4] with K [3, 3]: [size, size, 3] on white."""
        import torch

        from cadnerf_core.nerf.rays import image_rays
        from cadnerf_core.nerf.volrend import render_rays

        rays_o, rays_d = image_rays(torch.as_tensor(c2w, dtype=torch.float32),
                                    torch.as_tensor(K, dtype=torch.float32), size, size)
        with torch.no_grad():
            out = render_rays(lambda p, d: self.state.fields.query(p, d), rays_o, rays_d, 48,
                              1.2, None, True, False)
        assert out.rgb is not None
        return out.rgb.reshape(size, size, 3).numpy()


def test_fit_frame_recovers_a_shared_offset() -> None:
    from cadnerf_core.cameras.conventions import intrinsics_from_fov
    from cadnerf_core.evaluation.frame import fit_frame

    ball = _Ball()
    gt = _gt_poses(5, seed=2)
    K = np.stack([intrinsics_from_fov(40.0, 32)] * len(gt))
    # The photos were taken from cameras that the starting mapping misses by one small turn
    # and shift shared by all of them (what six noisy camera centres leave).
    start = Similarity(1.0, np.eye(3), np.zeros(3))
    turn = Rotation.from_rotvec([0.0, 0.06, 0.03]).as_matrix()
    truth = start.then(1.0, turn, np.array([0.08, -0.05, 0.04]))
    images = np.stack([ball.render(c2w, K[0], 32) for c2w in truth.apply_to_poses(gt)])
    fitted = fit_frame(ball, start, gt, K, images, steps=150, rays=1024)  # type: ignore[arg-type]

    def miss(sim: Similarity) -> float:
        return float(np.abs(sim.apply_to_poses(gt)[:, :3, 3]
                            - truth.apply_to_poses(gt)[:, :3, 3]).max())

    assert miss(fitted) < 0.05 * miss(start)  # measured: 0.0002 against 0.15
    assert fit_frame(ball, start, gt, K, images, steps=0) is start  # type: ignore[arg-type]
    assert ball.state.fields.dummy.requires_grad  # the fields' flags are restored


# ---------------------------------------------------------------- end to end on a tiny box


def test_evaluate_tiny_box_has_all_fields(tmp_path: Path, tiny_library: Any) -> None:
    import trimesh

    from cadnerf_core.evaluation.dataset import render_dataset
    from cadnerf_core.evaluation.evaluate import evaluate_dataset

    mesh_path = tmp_path / "box.ply"
    trimesh.creation.box(extents=(1.2, 0.8, 0.6)).export(mesh_path)
    dataset = render_dataset(mesh_path, tmp_path / "ds", n_views=4, size=64, seed=0,
                             test_views=2)
    library = tiny_library
    report = evaluate_dataset(dataset, 3, library, preset=TINY_PRESET,
                              overrides=tiny_request(seed=3)["overrides"],
                              job_dir=tmp_path / "job")
    data = report.to_json()
    json.dumps(data)  # serialisable
    assert report.n_views == 3 and len(report.per_view) == 2
    assert len(report.kept) + len(report.discarded) == 3
    for value in (report.image.psnr, report.image.ssim, report.pose_refined.rotation_deg,
                  report.pose_refined.translation_x100, report.pose_retrieved.rotation_deg,
                  report.pose_retrieved.translation_x100, report.seconds, report.focal_used):
        assert math.isfinite(value)
    assert 0.0 < report.image.psnr < 100.0
    assert report.lpips_note is not None and report.image.lpips is None
    assert report.model_id in {m.id for m in library.models}
    assert set(report.cameras) == {"gt", "retrieved", "refined"}
    assert all(Path(p).is_file() for p in report.renders)
    assert report.phases, "metrics.json phases missing"
    assert report.eval_size == 64 and report.align == "photometric"
    assert report.seed == 3 and JobFolder(report.job_dir).read_config().seed == 3
    with pytest.raises(ValueError, match="not empty"):
        evaluate_dataset(dataset, 3, library, **tiny_request(), job_dir=tmp_path / "job")


# ---------------------------------------------------------------- benchmark tables, fake inputs


def test_tables_mean_row_and_layout(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    from benchmarks.eval_tables import markdown_table, mean_row, with_mean, worst

    rows = [{"object": "a", "psnr": 20.0, "lpips": None, "ok": True},
            {"object": "b", "psnr": 24.0, "lpips": 0.2, "ok": False},
            {"object": "c", "psnr": math.inf, "lpips": 0.4}]
    mean = mean_row(rows, "object")
    assert mean["psnr"] == pytest.approx(22.0)  # the infinite value is left out
    assert mean["lpips"] == pytest.approx(0.3)
    assert "ok" not in mean  # booleans are not averaged
    table = markdown_table([("object", "object", 0), ("PSNR", "psnr", 2),
                            ("LPIPS", "lpips", 3)], with_mean(rows, "object"))
    lines = table.splitlines()
    assert lines[0] == "| object | PSNR | LPIPS |"
    assert lines[1] == "| --- | ---: | ---: |"
    assert lines[2] == "| a | 20.00 | - |"
    assert lines[4] == "| c | inf | 0.400 |"
    assert lines[5] == "| **mean** | 22.00 | 0.300 |"
    bad = worst(rows, "psnr")
    assert bad is not None and bad["object"] == "a"


# ---------------------------------------------------------------- job read-back helpers


def test_phase_costs_reads_both_layouts() -> None:
    from cadnerf_core.evaluation.jobio import phase_costs

    extra = {"timings": {"phase1_s": 1.0, "phase2_s": 2.0},
             "memory": {"phase1": {"rss_peak_mb": 100.0}}}
    metrics = {"timings_s": {"phase2_s": 2.5, "export_s": 0.5},
               "peak_memory_mb": {"phase2": {"rss_peak_mb": 120.0, "note": "x"}}}
    costs = phase_costs(extra, metrics)
    assert costs["phase1"] == {"seconds": 1.0, "rss_peak_mb": 100.0}
    assert costs["phase2"] == {"seconds": 2.5, "rss_peak_mb": 120.0}  # later source wins
    assert costs["export"] == {"seconds": 0.5}


def test_read_job_cameras_and_intrinsics(tmp_path: Path) -> None:
    from cadnerf_core.evaluation.jobio import eval_intrinsics, read_job_cameras

    poses = _gt_poses(4)
    K_photo = np.array([[150.0, 0, 64], [0, 150.0, 64], [0, 0, 1]])
    matches = [{"index": i, "name": f"p{i}", "discarded": i == 2, "c2w": poses[i].tolist(),
                "K_photo": (K_photo * [[1 + 0.1 * i], [1 + 0.1 * i], [1]]).tolist()}
               for i in range(4)]
    JobFolder(tmp_path).write_retrieval(
        {"model_id": "chair_a", "category": "chair", "matches": matches[::-1]})

    class FakeModel:
        c2w = poses[[0, 1, 3]] + 0.01

    cams = read_job_cameras(tmp_path, FakeModel())  # type: ignore[arg-type]
    assert cams.kept == [0, 1, 3] and cams.discarded == [2]
    assert np.allclose(cams.retrieved, poses[[0, 1, 3]])
    assert np.allclose(cams.refined, poses[[0, 1, 3]] + 0.01)
    gt_K = np.array([[170.0, 0, 64], [0, 170.0, 64], [0, 0, 1]])
    K = eval_intrinsics(gt_K, cams, "estimated")
    assert K[0, 0] == pytest.approx(165.0) and K[0, 2] == 64  # median of 150, 165, 195
    assert np.array_equal(eval_intrinsics(gt_K, cams, "gt"), gt_K)

    class WrongModel:
        c2w = poses

    with pytest.raises(ValueError, match="4 poses for 3 kept"):
        read_job_cameras(tmp_path, WrongModel())  # type: ignore[arg-type]

    class DivergedModel:
        c2w = np.where(np.arange(3)[:, None, None] == 1, np.nan, poses[[0, 1, 3]])

    with pytest.raises(ValueError, match=r"not finite .*\['p1'\]"):
        read_job_cameras(tmp_path, DivergedModel())  # type: ignore[arg-type]


def test_resize_view_scales_intrinsics() -> None:
    from cadnerf_core.cameras.conventions import intrinsics_from_fov
    from cadnerf_core.evaluation.evaluate import resize_view

    image = np.zeros((8, 8, 3), np.float32)
    image[:4] = 1.0
    K = intrinsics_from_fov(40.0, 8)
    small, K_small = resize_view(image, K, 4)
    assert small.shape == (4, 4, 3)
    assert np.allclose(small[:2], 1.0) and np.allclose(small[2:], 0.0)
    assert np.allclose(K_small, intrinsics_from_fov(40.0, 4))
    same, K_same = resize_view(image, K, None)
    assert np.array_equal(same, image)
    assert K_same is K


def test_centred_similarity_keeps_origin_and_distance() -> None:
    gt = _gt_poses()
    sim = Similarity(scale=1.6, R=_random_similarity(7).R, t=np.zeros(3))
    moved = sim.apply_to_poses(gt)
    found = centre_similarity(gt, moved, fix_origin=True)
    assert found.scale == pytest.approx(1.6) and np.allclose(found.R, sim.R, atol=1e-9)
    assert np.array_equal(found.t, np.zeros(3))
    # A mirrored camera set has no good rotation; the cameras still keep their distance.
    mirrored = moved.copy()
    mirrored[:, 0, 3] *= -1.0
    bad = centre_similarity(gt, mirrored, fix_origin=True)
    mapped = bad.apply_to_poses(gt)[:, :3, 3]
    assert np.allclose(np.linalg.norm(mapped, axis=1), 1.6 * np.linalg.norm(gt[:, :3, 3], axis=1))


# ---------------------------------------------------------------- benchmark runner


def test_runner_records_missing_and_failing_areas(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys
    import types

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    from benchmarks import run as runner

    def broken(quick: bool) -> str:
        raise RuntimeError(f"boom quick={quick}")

    def fine(quick: bool) -> str:
        return f"## fine\n\nquick={quick}\n"

    for name, fn in (("broken", broken), ("fine", fine)):
        module = types.ModuleType(f"benchmarks.bench_{name}")
        module.run = fn  # type: ignore[attr-defined]
        monkeypatch.setitem(sys.modules, f"benchmarks.bench_{name}", module)
    text, _ = runner.run_area("broken", True)
    assert "**FAILED**" in text and "boom quick=True" in text
    text, _ = runner.run_area("nonexistent_area", True)
    assert "does not exist yet" in text
    sections = [runner.Section("fine", runner.run_area("fine", False)[0], 1.5, "full",
                               "abc1234", "2026-01-01 00:00 UTC", "python -m benchmarks.run",
                               runner.cpu_summary()),
                runner.Section("old", "## old\n", 2.0, "full", "abc1234",
                               "2026-01-01 00:00 UTC", "python -m benchmarks.run")]
    doc = runner.build_document(sections)
    assert "quick=False" in doc and "| fine | 1.5 | full | abc1234 |" in doc
    assert f"| {runner.cpu_summary()} |" in doc and "cores" in runner.cpu_summary()
    assert "| not recorded |" in doc  # a section measured before rows named their CPU
    assert "- CPU: " in doc and "torch " in doc
    assert runner.read_sections(doc) == {"fine": sections[0], "old": sections[1]}


def test_runner_only_replaces_the_areas_it_runs(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """``--only`` re-measures its areas and keeps every other section of the document."""
    import sys
    import types

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    from benchmarks import run as runner

    calls = {"renderer": 0, "library": 0}
    for area in calls:
        def run(quick: bool, area: str = area) -> str:
            calls[area] += 1
            return f"## {area}\n\nrun {calls[area]}\n"
        module = types.ModuleType(f"benchmarks.bench_{area}")
        module.run = run  # type: ignore[attr-defined]
        monkeypatch.setitem(sys.modules, f"benchmarks.bench_{area}", module)
    out = tmp_path / "benchmarks.md"
    assert runner.main(["--quick", "--only", "library", "renderer", "--out", str(out)]) == 0
    assert runner.main(["--quick", "--only", "library", "--out", str(out)]) == 0
    sections = runner.read_sections(out.read_text())
    assert list(sections) == ["renderer", "library"]  # the areas' own order
    assert "run 1" in sections["renderer"].text and "run 2" in sections["library"].text
    assert sections["library"].command.endswith("--only library --out " + str(out))



def test_runner_keeps_what_a_run_beside_it_wrote(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """Two ``--only`` runs at once on one document: the section the other run wrote while this
    one measured is still there when this one writes its own."""
    import sys
    import types

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    from benchmarks import run as runner

    out = tmp_path / "benchmarks.md"

    def renderer(quick: bool) -> str:
        return "## renderer\n\nfirst run\n"

    def library(quick: bool) -> str:
        # Meanwhile, another run writes the renderer's section anew.
        text = out.read_text().replace("first run", "the other run")
        out.write_text(text)
        return "## library\n\nthis run\n"

    for area, run in (("renderer", renderer), ("library", library)):
        module = types.ModuleType(f"benchmarks.bench_{area}")
        module.run = run  # type: ignore[attr-defined]
        monkeypatch.setitem(sys.modules, f"benchmarks.bench_{area}", module)
    assert runner.main(["--quick", "--only", "renderer", "--out", str(out)]) == 0
    assert runner.main(["--quick", "--only", "library", "--out", str(out)]) == 0
    sections = runner.read_sections(out.read_text())
    assert "the other run" in sections["renderer"].text
    assert "this run" in sections["library"].text


def test_true_cameras_oracle_gives_the_job_the_ground_truth(tmp_path: Path,
                                                            tiny_library: Any) -> None:
    """The training benchmark's oracle: inside ``true_cameras`` a job's kept photos carry the
    dataset's own cameras (rotation error 0, true focal length), outside it the retrieved
    ones; the pipeline is restored afterwards."""
    import trimesh

    import cadnerf_core.pipeline as pipeline
    from benchmarks.bench_training import true_cameras
    from cadnerf_core.evaluation.dataset import render_dataset
    from cadnerf_core.evaluation.evaluate import evaluate_dataset

    mesh_path = tmp_path / "box.ply"
    trimesh.creation.box(extents=(1.2, 0.8, 0.6)).export(mesh_path)
    dataset = render_dataset(mesh_path, tmp_path / "ds", n_views=4, size=64, seed=0,
                             test_views=1)
    original = pipeline.run_intake
    with true_cameras(dataset):
        oracle = evaluate_dataset(dataset, 4, tiny_library, **tiny_request(optimise_poses=False),
                                  job_dir=tmp_path / "o")
    assert pipeline.run_intake is original
    plain = evaluate_dataset(dataset, 4, tiny_library, **tiny_request(optimise_poses=False),
                             job_dir=tmp_path / "p")
    assert max(oracle.pose_retrieved.rotation_deg_per_view) < 1e-3
    assert max(oracle.pose_refined.rotation_deg_per_view) < 0.05  # float32 in the model
    assert oracle.focal_used == pytest.approx(oracle.focal_gt)
    # A 3-model library's poses on a 10-degree grid are not the truth.
    assert max(plain.pose_retrieved.rotation_deg_per_view) > 1.0
    assert plain.focal_used != pytest.approx(plain.focal_gt, rel=1e-3)


def test_training_benchmark_rejects_an_unknown_run_name() -> None:
    """``bench_training --runs`` names runs; a misspelt one fails before any work, naming the
    choices, instead of silently running nothing."""
    from benchmarks.bench_training import run

    with pytest.raises(ValueError, match="no deformation"):
        run(quick=True, only=["full", "no deformations"])


def test_a_job_written_with_exif_focal_gives_its_photos_the_true_focal(tmp_path: Path) -> None:
    import trimesh

    from cadnerf_core.evaluation.dataset import load_dataset, render_dataset
    from cadnerf_core.evaluation.jobio import write_job
    from cadnerf_core.intake.photos import load_photos

    mesh_path = tmp_path / "box.ply"
    trimesh.creation.box(extents=(1.2, 0.8, 0.6)).export(mesh_path)
    data = load_dataset(render_dataset(mesh_path, tmp_path / "ds", n_views=3, size=64, seed=0,
                                       fov_deg=55.0))
    write_job(tmp_path / "with", data, TINY_PRESET, TINY_OVERRIDES, exif_focal=True)
    write_job(tmp_path / "without", data, TINY_PRESET, TINY_OVERRIDES)
    told = load_photos([p.path for p in JobFolder(tmp_path / "with").photos()])
    plain = load_photos([p.path for p in JobFolder(tmp_path / "without").photos()])
    for photo, K in zip(told, data.K, strict=True):
        # The tag holds whole millimetres: within half a mm of 35 mm-equivalent.
        assert photo.focal_pixels == pytest.approx(K[0, 0], rel=0.5 / photo.focal_35mm)
    assert all(p.focal_35mm is None for p in plain)


def test_cli_eval_leaves_the_excluded_models_out(tmp_path: Path, tiny_library_dir: Path) -> None:
    import trimesh
    from typer.testing import CliRunner

    from cadnerf_cli.main import app
    from cadnerf_core.evaluation.dataset import render_dataset
    from tests.configs import tiny_cli_options

    mesh_path = tmp_path / "box.ply"
    trimesh.creation.box(extents=(1.2, 0.8, 0.6)).export(mesh_path)
    dataset = render_dataset(mesh_path, tmp_path / "ds", n_views=4, size=64, seed=0,
                             test_views=2)
    common = ["eval", str(dataset), "--views", "3", "--library", str(tiny_library_dir),
              "--device", "cpu", *tiny_cli_options()]
    result = CliRunner().invoke(app, [*common, "--json", "--exclude-models", "cuboid_slab"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)[0]
    assert report["model_id"] != "cuboid_slab"
    assert report["overrides"]["retrieval.exclude_models"] == ["cuboid_slab"]
    unknown = CliRunner().invoke(app, [*common, "--exclude-models", "nope"])
    assert unknown.exit_code == 2 and "no model 'nope' in the library" in unknown.output

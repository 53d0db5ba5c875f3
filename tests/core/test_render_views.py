"""``cadnerf render JOB --cameras FILE --out DIR``: a finished tiny job rendered at the cameras
of its own transforms.json and COLMAP model (the two agree), from the field and the mesh."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from tests.core.test_pipeline import write_job

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def job(tmp_path_factory: pytest.TempPathFactory, tiny_library: Any) -> Path:
    from cadnerf_core.pipeline import run_job

    job_dir = tmp_path_factory.mktemp("job")
    write_job(job_dir, tiny_library)
    run_job(job_dir, tiny_library, None, "cpu")
    return job_dir


def _render(*args: str) -> Any:
    from cadnerf_cli.main import app

    return CliRunner().invoke(app, ["render", *args, "--device", "cpu"])


def _read(folder: Path) -> dict[str, np.ndarray]:
    return {p.stem: np.asarray(Image.open(p), dtype=np.float32) / 255.0
            for p in sorted(folder.glob("*.png"))}


def test_render_at_the_jobs_own_cameras_from_both_files(job: Path, tmp_path: Path) -> None:
    transforms = json.loads((job / "transforms.json").read_text())
    frames = transforms["frames"]
    result = _render(str(job), "--cameras", str(job / "transforms.json"), "--out",
                     str(tmp_path / "t"), "--size", "40")
    assert result.exit_code == 0, result.output
    by_transforms = _read(tmp_path / "t")
    assert sorted(by_transforms) == sorted(Path(f["file_path"]).stem for f in frames)
    for frame in frames:
        image = by_transforms[Path(frame["file_path"]).stem]
        long_side = max(frame["w"], frame["h"])
        assert image.shape[:2] == (round(frame["h"] * 40 / long_side),
                                   round(frame["w"] * 40 / long_side))
        assert (image.min(axis=-1) < 0.95).mean() > 0.01  # the object is in view
    result = _render(str(job), "--cameras", str(job / "sparse" / "0" / "images.txt"), "--out",
                     str(tmp_path / "c"), "--size", "40")
    assert result.exit_code == 0, result.output
    by_colmap = _read(tmp_path / "c")
    assert sorted(by_colmap) == sorted(by_transforms)
    for name, image in by_colmap.items():
        assert np.abs(image - by_transforms[name]).mean() < 0.01
    result = _render(str(job), "--cameras", str(job), "--out", str(tmp_path / "j"), "--size",
                     "40")  # the job folder itself: its transforms.json
    assert result.exit_code == 0, result.output
    assert sorted(_read(tmp_path / "j")) == sorted(by_transforms)


def test_render_from_the_mesh_shows_it_in_the_jobs_frame(job: Path, tmp_path: Path) -> None:
    """The job's mesh.glb (here a red ball of radius 0.5 at the origin, in place of the tiny
    job's speck) seen from a camera of the job's transforms.json: the ball's disc, its colour
    as it is (unlit), white around it."""
    import shutil

    import trimesh

    from cadnerf_core.cameras import project
    from cadnerf_core.evaluation.views import job_renderer, read_views

    copy = tmp_path / "job"
    shutil.copytree(job, copy)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    ball.visual.face_colors = (200, 60, 30, 255)
    (copy / "mesh.glb").write_bytes(ball.export(file_type="glb"))
    view = read_views(copy / "transforms.json", size=48)[0]
    rgb, coverage = job_renderer(copy, "mesh")(view)
    mask = coverage > 0.5
    centre = project(np.zeros((1, 3)), view.K, view.c2w)[0]
    distance = float(np.linalg.norm(view.c2w[:3, 3]))
    radius = view.K[0, 0] * 0.5 / np.sqrt(distance**2 - 0.25)  # the sphere's outline
    xs, ys = np.meshgrid(np.arange(view.width) + 0.5, np.arange(view.height) + 0.5)
    disc = (xs - centre[0]) ** 2 + (ys - centre[1]) ** 2 < radius**2
    assert mask.any() and (mask & disc).sum() / (mask | disc).sum() > 0.9
    np.testing.assert_allclose(rgb[mask], np.broadcast_to([200 / 255, 60 / 255, 30 / 255],
                                                          (int(mask.sum()), 3)), atol=0.01)
    assert np.allclose(rgb[~mask], 1.0)
    result = _render(str(copy), "--cameras", str(copy / "transforms.json"), "--out",
                     str(tmp_path / "m"), "--size", "32", "--source", "mesh")
    assert result.exit_code == 0, result.output
    assert len(_read(tmp_path / "m")) == len(json.loads((copy / "transforms.json")
                                                        .read_text())["frames"])


def test_a_nerf_synthetic_file_needs_a_size_or_its_images(job: Path, tmp_path: Path) -> None:
    """The Blender layout: ``camera_angle_x`` and poses only, no image beside it."""
    transforms = json.loads((job / "transforms.json").read_text())
    bare = {"camera_angle_x": transforms["camera_angle_x"],
            "frames": [{"file_path": "./test/r_0",
                        "transform_matrix": transforms["frames"][0]["transform_matrix"]}]}
    path = tmp_path / "transforms_test.json"
    path.write_text(json.dumps(bare))
    unsized = _render(str(job), "--cameras", str(path), "--out", str(tmp_path / "n"))
    assert unsized.exit_code == 2 and "--size" in unsized.output
    sized = _render(str(job), "--cameras", str(path), "--out", str(tmp_path / "n"), "--size",
                    "24")
    assert sized.exit_code == 0, sized.output
    assert _read(tmp_path / "n")["r_0"].shape == (24, 24, 3)


def test_render_reports_bad_inputs_without_a_traceback(job: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken.json"
    broken.write_text('{"frames": [{"transform_matrix": 3}]}')
    for cameras, folder, expected in ((broken, job, "not a cameras file"),
                                      (tmp_path, job, "no transforms.json"),
                                      (job / "transforms.json", tmp_path, "not trained")):
        result = _render(str(folder), "--cameras", str(cameras), "--out", str(tmp_path / "x"),
                         "--size", "16")
        assert result.exit_code == 2 and expected in result.output, result.output
        assert result.exception is None or isinstance(result.exception, SystemExit)

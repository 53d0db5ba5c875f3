"""The whole job on the tiny library with the suite's tiny config: every artifact, the masks and
config it used, resume, CLI errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
from PIL import Image

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
from cadnerf_core.errors import JobCancelled
from cadnerf_core.jobfolder import JobFolder
from cadnerf_core.progress import Progress
from tests.configs import tiny_cli_options, tiny_config

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def write_job(job_dir: Path, library: Any, model_id: str = "mug", n: int = 4,
              overrides: dict[str, Any] | None = None) -> None:
    """Render ``n`` RGBA photos of a library model walking around it into a job folder, with
    the tiny config (plus ``overrides``)."""
    from cadnerf_core.mesh.renderer import MeshRenderer

    renderer = MeshRenderer(library.mesh(model_id))
    K = intrinsics_from_fov(40.0, 64)
    folder = JobFolder(job_dir)
    for i in range(n):
        result = renderer.render(K, orbit_pose(20.0 + 50.0 * i, 20.0, 4.0), 64, 64)
        rgb = (result.rgb * 255).astype(np.uint8)
        alpha = result.mask.astype(np.uint8) * 255
        Image.fromarray(np.dstack([rgb, alpha]), "RGBA").save(folder.new_photo_path(i, "p", "png"))
    folder.write_config(tiny_config(**(overrides or {})))


def test_run_job_writes_every_artifact(tmp_path: Path, tiny_library: Any) -> None:
    from cadnerf_core.pipeline import run_job

    write_job(tmp_path, tiny_library)
    written = (tmp_path / "config.json").read_bytes()
    stages: list[str] = []
    result = run_job(tmp_path, tiny_library, Progress(lambda s, d, t: stages.append(s)), "cpu")
    assert result.model.id in {m.id for m in tiny_library.models}
    assert [p.index for p in result.photos] == [0, 1, 2, 3]
    assert "result.json" in result.artifacts and "results.zip" in result.artifacts
    for name in result.artifacts:
        assert (tmp_path / name).is_file(), name
    assert JobFolder(tmp_path).read_result() == result  # what it returns is what it wrote
    for name in ("poses.json", "transforms.json", "metrics.json", "orbit.mp4", "orbit.gif",
                 "mesh.glb", "retrieval.json", "config.json", "masks.json", "views/000.png",
                 "masks/003.png", "masks/003_overlay.jpg", "log.txt", "checkpoints/phase1.pt",
                 "checkpoints/phase2.pt", "checkpoints/phase3.pt"):
        assert (tmp_path / name).is_file(), name
    folder = JobFolder(tmp_path)
    assert [m.source for m in folder.read_mask_sources()] == ["alpha"] * 4
    assert {"masks/000.png", "masks/003_overlay.jpg"} <= set(folder.artifacts())
    for photo in folder.photos():  # the used mask is the photo's alpha
        with Image.open(photo.path) as image:
            alpha = np.asarray(image)[..., 3] > 127
        assert np.array_equal(folder.read_mask(photo.index), alpha)
        with Image.open(folder.file(f"masks/{photo.index:03d}_overlay.jpg")) as overlay:
            assert overlay.size == alpha.shape[::-1] and overlay.mode == "RGB"
    assert {"masks", "retrieval", "phase1", "phase2", "phase3", "render", "export"} <= set(stages)
    mesh = trimesh.load(tmp_path / "mesh.glb", force="mesh")
    assert isinstance(mesh, trimesh.Trimesh)
    assert len(mesh.faces) > 0
    poses = json.loads((tmp_path / "poses.json").read_text())["photos"]
    assert len(poses) == 4 and all(len(p["K_photo"]) == 3 for p in poses)
    transforms = json.loads((tmp_path / "transforms.json").read_text())
    kept = [p for p in poses if not p["discarded"]]
    assert len(transforms["frames"]) == len(kept)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    stages = {"intake_s", "start_s", "phase1_s", "phase2_s", "phase3_s", "views_s", "orbit_s",
              "mesh_s", "bundle_s", "export_s"}
    assert stages <= set(metrics["timings_s"])
    assert all(metrics["timings_s"][k] >= 0 for k in stages)
    assert metrics["peak_memory_mb"]["phase3"]["rss_peak_mb"] > 0
    assert all(np.isfinite(p["psnr"]) and -1 <= p["ssim"] <= 1 for p in metrics["photos"])
    assert (tmp_path / "config.json").read_bytes() == written  # read, never rewritten
    assert folder.read_config() == tiny_config()

    from cadnerf_core.nerf.model import TrainedModel

    model = TrainedModel.load(tmp_path, "cpu")
    c2w = np.array(kept[0]["c2w"])
    assert np.allclose(model.c2w[0], c2w)
    rgb, alpha = model.render_image(c2w, np.array(kept[0]["K_canonical"]), 32, 32)
    assert rgb.shape == (32, 32, 3) and rgb.dtype == np.float32 and alpha.shape == (32, 32)
    assert alpha.min() >= 0.0 and alpha.max() <= 1.0


def test_orbit_video_is_h264(tmp_path: Path, tiny_library: Any) -> None:
    import imageio_ffmpeg

    from cadnerf_core.pipeline import run_job

    write_job(tmp_path, tiny_library, overrides={"export.novel_views": 0})
    run_job(tmp_path, tiny_library, None, "cpu")
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "orbit.mp4"))
    meta = next(reader)
    frames = list(reader)
    assert "h264" in meta["codec"]
    assert len(frames) == 4
    gif = Image.open(tmp_path / "orbit.gif")
    assert getattr(gif, "n_frames", 1) == 4


def test_resume_after_cancel_in_phase_three(tmp_path: Path, tiny_library: Any,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    from cadnerf_core.nerf import phases
    from cadnerf_core.pipeline import run_job

    write_job(tmp_path, tiny_library)
    seen: list[str] = []

    def cancel() -> bool:
        return bool(seen) and seen[-1] == "phase3"

    with pytest.raises(JobCancelled):
        run_job(tmp_path, tiny_library, Progress(lambda s, d, t: seen.append(s), cancel), "cpu")
    assert (tmp_path / "checkpoints/phase2.pt").is_file()
    assert not (tmp_path / "checkpoints/phase3.pt").exists()
    assert not (tmp_path / "mesh.glb").exists()

    def fail(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("phases one and two must not run again")

    monkeypatch.setattr(phases, "run_phase1", fail)
    monkeypatch.setattr(phases, "run_phase2", fail)
    stages: list[str] = []
    summary = run_job(tmp_path, tiny_library, Progress(lambda s, d, t: stages.append(s)), "cpu")
    assert "phase3" in stages and "phase2" not in stages and "phase1" not in stages
    assert (tmp_path / "mesh.glb").is_file()
    assert summary.metrics.resumed_after_phase == 2


def test_cli_reports_errors_in_one_line(tmp_path: Path, tiny_library_dir: Path) -> None:
    from typer.testing import CliRunner

    from cadnerf_cli.main import app

    photo = tmp_path / "a.png"
    Image.new("RGB", (80, 80), "white").save(photo)
    runner = CliRunner()
    result = runner.invoke(app, ["reconstruct", str(photo), "--out", str(tmp_path / "job"),
                                 "--preset", "nope", "--library", str(tiny_library_dir)])
    assert result.exit_code == 2
    assert "unknown preset" in result.output
    result = runner.invoke(app, ["reconstruct", str(tmp_path / "missing.png"), "--out",
                                 str(tmp_path / "job"), "--preset", "preview",
                                 "--library", str(tiny_library_dir)])
    assert result.exit_code == 2
    assert "no such file" in result.output
    result = runner.invoke(app, ["reconstruct", str(photo), "--out", str(tmp_path / "job"),
                                 "--mask-model", str(tmp_path / "missing.onnx")])
    assert result.exit_code == 2 and "missing.onnx" in result.output


def test_cli_reconstructs_into_the_output_folder(tmp_path: Path, tiny_library: Any,
                                                 tiny_library_dir: Path) -> None:
    from typer.testing import CliRunner

    from cadnerf_cli.main import app

    write_job(tmp_path / "src", tiny_library, n=3)
    photos = sorted(str(p.path) for p in JobFolder(tmp_path / "src").photos())
    masks = []  # named unlike their photos, shrunk so they differ from the photos' alpha
    for i, photo in enumerate(photos):
        with Image.open(photo) as image:
            alpha = np.asarray(image)[..., 3] > 127
        shrunk = alpha & np.roll(alpha, 2, axis=1) & np.roll(alpha, 2, axis=0)
        masks.append(tmp_path / f"mask_{i}.png")
        Image.fromarray(shrunk.astype(np.uint8) * 255).save(masks[-1])
    out = tmp_path / "job"
    result = CliRunner().invoke(app, ["reconstruct", *photos, "--out", str(out),
                                      *[arg for m in masks for arg in ("--masks", str(m))],
                                      *tiny_cli_options(), "--device", "cpu", "--library",
                                      str(tiny_library_dir), "--walk", "ccw", "--own-focal",
                                      "--perspective", "near", "--focal-35mm", "30",
                                      "--exclude-models", "chair_wood"])
    assert result.exit_code == 0, result.output
    assert "results in" in result.output
    # The walk write_job rendered is counter-clockwise (increasing azimuth), as told.
    resolved = JobFolder(out).read_config()
    assert resolved == tiny_config(retrieval={"walk": "ccw", "shared_focal": False,
                                              "perspective": "near", "focal_35mm": 30.0,
                                              "exclude_models": ("chair_wood",)})
    retrieval = JobFolder(out).read_retrieval()
    assert retrieval is not None
    assert retrieval["perspective"] == "near" and retrieval["model_id"] != "chair_wood"
    assert retrieval["direction"] == 1 and retrieval["direction_lead"] is None
    assert sorted(p.name for p in (out / "inputs").iterdir() if p.is_file()) == \
        ["000_000_p.png", "001_001_p.png", "002_002_p.png"]
    assert (out / "mesh.glb").is_file() and (out / "orbit.mp4").is_file()
    used = JobFolder(out)
    assert [m.source for m in used.read_mask_sources()] == ["uploaded"] * 3
    # `cadnerf retrieve` on the same photos and settings prints the cameras the job started from.
    retrieved = CliRunner().invoke(app, ["retrieve", *photos, "--json", *tiny_cli_options(),
                                         *[arg for m in masks for arg in ("--masks", str(m))],
                                         "--device", "cpu", "--library", str(tiny_library_dir),
                                         "--walk", "ccw", "--own-focal", "--perspective", "near",
                                         "--focal-35mm", "30", "--exclude-models", "chair_wood"])
    assert retrieved.exit_code == 0, retrieved.output
    started = {m["index"]: m["c2w"] for m in json.loads(retrieved.stdout)["matches"]}
    poses = json.loads((out / "poses.json").read_text())["photos"]
    assert len(poses) == 3
    for pose in poses:
        assert np.allclose(started[pose["index"]], pose["c2w_initial"], atol=1e-6)
    for i, mask in enumerate(masks):
        with Image.open(mask) as image:
            assert np.array_equal(used.read_mask(i), np.asarray(image) > 127)


def test_cli_retrieve_warns_of_a_guessed_direction_unless_given(tmp_path: Path,
                                                                tiny_library: Any,
                                                                tiny_library_dir: Path) -> None:
    from typer.testing import CliRunner

    from cadnerf_cli.main import app

    # A slab looks alike walked either way round: the direction is a guess unless given.
    write_job(tmp_path / "src", tiny_library, model_id="cuboid_slab", n=4)
    photos = sorted(str(p) for p in (tmp_path / "src" / "inputs").iterdir())
    common = ["retrieve", *photos, "--library", str(tiny_library_dir)]
    guessed = CliRunner().invoke(app, common)
    assert guessed.exit_code == 0, guessed.output
    assert "warning: The walking direction is a guess" in guessed.output
    told = CliRunner().invoke(app, [*common, "--walk", "cw", "--json"])
    assert told.exit_code == 0, told.output
    data = json.loads(told.output)
    assert data["direction"] == -1 and data["direction_ambiguous"] is False
    left_out = CliRunner().invoke(app, [*common, "--json", "--exclude-models", "cuboid_slab"])
    assert left_out.exit_code == 0, left_out.output
    data = json.loads(left_out.stdout)
    assert data["model_id"] != "cuboid_slab"
    assert "cuboid_slab" not in {t["model_id"] for t in data["top_models"]}
    # Photos in any order: the walking order found is reported, by index and by name.
    shuffled = [photos[i] for i in (2, 0, 3, 1)]
    anyhow = CliRunner().invoke(app, ["retrieve", *shuffled, "--library",
                                      str(tiny_library_dir), "--order", "any", "--json"])
    assert anyhow.exit_code == 0, anyhow.output
    data = json.loads(anyhow.stdout)
    assert data["order_mode"] == "any" and sorted(data["order"]) == [0, 1, 2, 3]
    assert [m["name"] for m in data["matches"]] == [Path(p).name for p in shuffled]
    assert data["order_ambiguous"] is False and data["order_lead"] > 0.003 * 4
    # Five photos of the mug: another order fits its silhouettes as well; said so.
    write_job(tmp_path / "mug", tiny_library, model_id="mug", n=5)
    mug = sorted(str(p) for p in (tmp_path / "mug" / "inputs").iterdir())
    mug_any = ["retrieve", *[mug[i] for i in (2, 0, 3, 1, 4)], "--library",
               str(tiny_library_dir), "--order", "any"]
    data = json.loads(CliRunner().invoke(app, [*mug_any, "--json"]).stdout)
    assert data["order_ambiguous"] is True and data["order_lead"] < 0.003 * 5
    assert "warning: The walking order is a guess" in CliRunner().invoke(app, mug_any).output
    bad = CliRunner().invoke(app, [*common, "--order", "sideways"])
    assert bad.exit_code == 2 and "--order" in bad.output
    unknown = CliRunner().invoke(app, [*common, "--exclude-models", "mug,no_such_model"])
    assert unknown.exit_code == 2
    assert "no model 'no_such_model' in the library" in unknown.output


def test_a_focal_length_given_for_photos_without_exif_sets_their_cameras(
        tmp_path: Path, tiny_library: Any) -> None:
    from cadnerf_core.pipeline import read_job_config, run_intake

    # 64 px renders at 40 degrees: their true focal length in 35 mm terms.
    true_focal_px = float(intrinsics_from_fov(40.0, 64)[0, 0])
    focal_35mm = true_focal_px * np.hypot(36.0, 24.0) / np.hypot(64.0, 64.0)
    write_job(tmp_path / "told", tiny_library, overrides={"retrieval": {
        "focal_35mm": focal_35mm}})
    write_job(tmp_path / "blind", tiny_library)
    told = run_intake(tmp_path / "told", tiny_library, read_job_config(tmp_path / "told"),
                      Progress())
    blind = run_intake(tmp_path / "blind", tiny_library, read_job_config(tmp_path / "blind"),
                       Progress())
    assert [m.K_photo[0, 0] for m in told.retrieval.matches] == \
        pytest.approx([true_focal_px] * 4)
    assert all(p.focal_35mm == pytest.approx(focal_35mm) for p in told.photos)
    assert all(p.focal_35mm is None for p in blind.photos)
    assert blind.retrieval.matches[0].K_photo[0, 0] != pytest.approx(true_focal_px, rel=1e-3)
    # Known, it lets retrieval choose the perspective: these photos are the far set's.
    assert told.retrieval.perspective == "far"
    # Unknown, the job records it (the result warns, saying what to send).
    assert JobFolder(tmp_path / "told").read_retrieval()["focal_known"] is True
    assert JobFolder(tmp_path / "blind").read_retrieval()["focal_known"] is False


def test_the_focal_length_is_learned_only_where_the_photos_do_not_give_it(
        tmp_path: Path, tiny_library: Any) -> None:
    from cadnerf_core.pipeline import run_job

    learn = {"phase2": {"focal_bound": 1.5, "focal_lr": 0.05}}
    write_job(tmp_path / "blind", tiny_library, overrides=learn)
    write_job(tmp_path / "told", tiny_library,
              overrides={**learn, "retrieval": {"focal_35mm": 50.0}})
    scales = {}
    for name in ("blind", "told"):
        run_job(tmp_path / name, tiny_library, Progress(), "cpu")
        folder = JobFolder(tmp_path / name)
        scales[name] = folder.read_metrics()["focal_scale"]  # type: ignore[index]
        retrieved = {m["index"]: np.asarray(m["K_photo"])
                     for m in folder.read_retrieval()["matches"]}  # type: ignore[index]
        for photo in folder.read_poses()["photos"]:  # type: ignore[index]
            K, before = np.asarray(photo["K_photo"]), retrieved[photo["index"]]
            assert K[0, 0] == pytest.approx(scales[name] * before[0, 0], rel=1e-5)
            assert K[1, 1] == pytest.approx(scales[name] * before[1, 1], rel=1e-5)
    assert scales["told"] == 1.0
    assert scales["blind"] != 1.0 and 1 / 1.5 <= scales["blind"] <= 1.5


def test_several_start_hypotheses_are_fitted_and_the_best_kept(tmp_path: Path,
                                                               tiny_library: Any) -> None:
    from cadnerf_core.pipeline import run_job

    write_job(tmp_path, tiny_library, overrides={"retrieval": {
        "hypotheses": 3, "hypothesis_steps": 4, "hypothesis_size": 16}})
    summary = run_job(tmp_path, tiny_library, Progress(), "cpu")
    retrieval = JobFolder(tmp_path).read_retrieval()
    assert retrieval is not None
    fits = retrieval["hypotheses"]
    assert len(fits) == 3 and sum(h["chosen"] for h in fits) == 1
    best = max(fits, key=lambda h: h["fit"])
    assert best["chosen"] and best["model_id"] == retrieval["model_id"] == summary.model.id
    assert len({(h["model_id"], h["direction"], h["perspective"]) for h in fits}) == 3
    assert fits[1]["perspective"] == "near"  # no focal length known: the near set's walk
    assert retrieval["focal_known"] is False  # kept by the start chosen, whichever it is
    assert all(-1.0 <= h["fit"] <= 1.0 for h in fits)


def test_photos_over_the_working_size_export_cameras_of_the_uploaded_photos(
        tmp_path: Path, tiny_library: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """Worked on at 40x40, the 64x64 photos' cameras in transforms.json and poses.json are
    still those of 64x64 photos (the object sits at their centre, 32 px, not 20)."""
    from cadnerf_core.pipeline import run_job

    monkeypatch.setattr("cadnerf_core.intake.limits.WORKING_PIXELS", 1600)
    write_job(tmp_path, tiny_library)
    run_job(tmp_path, tiny_library, None, "cpu")
    assert Image.open(tmp_path / "masks" / "000.png").size == (40, 40)
    frames = json.loads((tmp_path / "transforms.json").read_text())["frames"]
    assert frames and all((f["w"], f["h"]) == (64, 64) for f in frames)
    assert all(26 < f["cx"] < 38 and 26 < f["cy"] < 38 for f in frames), frames
    kept = [p for p in json.loads((tmp_path / "poses.json").read_text())["photos"]
            if not p["discarded"]]
    assert [p["K_photo"][0][2] for p in kept] == pytest.approx([f["cx"] for f in frames])


def test_a_job_folder_removed_mid_render_is_never_recreated(tmp_path: Path,
                                                            tiny_library: Any) -> None:
    """A worker that has not seen the deletion yet: its next write fails, nothing comes back."""
    from cadnerf_core.pipeline import run_job

    job = tmp_path / "job"
    job.mkdir()
    write_job(job, tiny_library)

    def remove_at_render(stage: str, done: int, total: int) -> None:
        if stage == "render" and job.exists():
            shutil.rmtree(job)

    with pytest.raises(OSError):
        run_job(job, tiny_library, Progress(remove_at_render), "cpu")
    assert not job.exists()

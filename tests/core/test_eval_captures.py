"""``cadnerf eval`` on a real capture's layout: photos on their background, masks, and
``cameras.json`` in a frame of its own (the object far from the origin, another scale)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
from PIL import Image

from cadnerf_core.evaluation.frame import Similarity

BACKGROUND = (40, 150, 70)  # the capture's table, which no target may keep
# The capture's world: the object sits at CENTRE, cameras at 3 times the synthetic distance.
CAPTURE_FRAME = Similarity(3.0, np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
                           np.array([30.0, -8.0, 50.0]))
CENTRE = CAPTURE_FRAME.t


def make_capture(tmp_path: Path, views: int = 4, size: int = 64, masks: bool = True) -> Path:
    """A capture folder as ``../shared/eval/captures`` holds them: ``images/NNN.jpg`` on a
    green background, ``masks/NNN.png`` (when ``masks``) and ``cameras.json`` (OpenCV c2w, K)
    in ``CAPTURE_FRAME``."""
    from cadnerf_core.cameras import from_transforms_json
    from cadnerf_core.evaluation.dataset import render_dataset

    mesh_path = tmp_path / "box.ply"
    box = trimesh.creation.box(extents=(1.2, 0.8, 0.6))
    box.visual.face_colors = (200, 60, 30, 255)
    box.export(mesh_path)
    synthetic = render_dataset(mesh_path, tmp_path / "synthetic", n_views=views, size=size,
                               seed=0)
    data = json.loads((synthetic / "transforms.json").read_text())
    c2w, K = from_transforms_json(data, size)
    capture = tmp_path / "capture"
    (capture / "images").mkdir(parents=True)
    (capture / "masks").mkdir()
    frames = []
    for i, (pose, k) in enumerate(zip(CAPTURE_FRAME.apply_to_poses(c2w), K, strict=True)):
        rgba = np.asarray(Image.open(synthetic / "images" / f"{i:03d}.png"))
        alpha = rgba[..., 3:] > 127
        photo = np.where(alpha, rgba[..., :3], np.array(BACKGROUND, np.uint8))
        Image.fromarray(photo.astype(np.uint8)).save(capture / "images" / f"{i:03d}.jpg",
                                                     quality=95)
        frame: dict[str, Any] = {"image": f"images/{i:03d}.jpg", "K": k.tolist(),
                                 "c2w": pose.tolist(), "width": size, "height": size}
        if masks:
            Image.fromarray(alpha[..., 0].astype(np.uint8) * 255).save(
                capture / "masks" / f"{i:03d}.png")
            frame["mask"] = f"masks/{i:03d}.png"
        frames.append(frame)
    (capture / "cameras.json").write_text(json.dumps({"convention": "OpenCV", "frames": frames}))
    return capture


def test_a_capture_folder_loads_with_held_out_frames_on_white(tmp_path: Path) -> None:
    from cadnerf_core.evaluation.dataset import load_dataset

    capture = make_capture(tmp_path)
    data = load_dataset(capture, hold_out=[2])
    assert data.names == ["000", "001", "003"] and data.masked
    assert data.test is not None and data.test.names == ["002"]
    frames = json.loads((capture / "cameras.json").read_text())["frames"]
    np.testing.assert_allclose(data.test.c2w[0], frames[2]["c2w"], atol=1e-12)
    np.testing.assert_allclose(data.K[2], frames[3]["K"], atol=1e-12)
    for split in (data, data.test):
        outside = split.images[~split.masks]
        assert outside.size and np.abs(outside - 1.0).max() < 0.02  # the table is gone
        assert split.images[split.masks].mean() < 0.8  # the red box is not
    with pytest.raises(ValueError, match="hold out"):
        load_dataset(capture, hold_out=[9])


def test_a_photo_with_a_mask_beside_it_is_composited_on_white(tmp_path: Path) -> None:
    """The NeRF-synthetic layout with JPEG photos and ``masks/``: the target is the object on
    white, as an RGBA photo's is."""
    from cadnerf_core.cameras import intrinsics_from_fov, orbit_pose, to_transforms_json
    from cadnerf_core.evaluation.dataset import load_dataset

    (tmp_path / "images").mkdir()
    (tmp_path / "masks").mkdir()
    photo = np.full((16, 16, 3), BACKGROUND, np.uint8)
    photo[4:12, 4:12] = (0, 0, 255)
    mask = np.zeros((16, 16), np.uint8)
    mask[4:12, 4:12] = 255
    Image.fromarray(photo).save(tmp_path / "images" / "000.png")
    Image.fromarray(mask).save(tmp_path / "masks" / "000.png")
    data = to_transforms_json(orbit_pose(0.0, 20.0, 3.0)[None], intrinsics_from_fov(50.0, 16),
                              16, 16, ["images/000"])
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    loaded = load_dataset(tmp_path)
    np.testing.assert_allclose(loaded.images[0, 0, 0], [1.0, 1.0, 1.0])
    np.testing.assert_allclose(loaded.images[0, 8, 8], [0.0, 0.0, 1.0])
    assert loaded.masks[0].sum() == 64


def test_the_centred_mapping_finds_an_object_off_the_origin() -> None:
    """Reference cameras in a world whose origin is not the object's centre (a calibration's,
    a COLMAP model's) are mapped so that they look at the NeRF's origin, where its object
    is; mapped about the reference origin they looked past it (held-out views were empty)."""
    from cadnerf_core.cameras import orbit_pose
    from cadnerf_core.evaluation.frame import centre_similarity, object_centre

    nerf = np.stack([orbit_pose(az, el, 2.5) for az, el in
                     ((0, 10), (60, 30), (130, 20), (200, 40), (290, 15))])
    reference = CAPTURE_FRAME.apply_to_poses(nerf)
    np.testing.assert_allclose(object_centre(reference), CENTRE, atol=1e-9)
    sim = centre_similarity(reference, nerf, fix_origin=True,
                            src_centre=object_centre(reference))
    held_out = orbit_pose(100.0, 25.0, 2.5)
    mapped = sim.apply_to_poses(CAPTURE_FRAME.apply_to_poses(held_out[None]))[0]
    np.testing.assert_allclose(mapped, held_out, atol=1e-9)
    # Parallel optical axes meet nowhere: the centre is then the cameras' own.
    parallel = np.stack([np.eye(4)] * 3)
    parallel[:, 0, 3] = [0.0, 1.0, 2.0]
    assert np.all(np.isfinite(object_centre(parallel)))


def test_fit_frame_survives_cameras_that_see_nothing() -> None:
    """Where no ray of a step meets the field the loss has no gradient: the fit skips such
    steps and, seeing nothing at all, keeps its start (it raised ``element 0 of tensors does
    not require grad``)."""
    from cadnerf_core.cameras import intrinsics_from_fov, look_at
    from cadnerf_core.evaluation.frame import fit_frame
    from tests.core.test_evaluation import _Ball

    ball = _Ball()
    away = np.stack([look_at(np.array([0.0, 0.0, 3.0 + i]), np.array([0.0, 0.0, 9.0]))
                     for i in range(3)])  # beside the field, looking away from it
    K = np.stack([intrinsics_from_fov(40.0, 16)] * 3)
    images = np.ones((3, 16, 16, 3), np.float32)
    start = Similarity(1.0, np.eye(3), np.zeros(3))
    assert fit_frame(ball, start, away, K, images, steps=5, rays=64) is start  # type: ignore[arg-type]


def test_resize_view_keeps_the_aspect_of_a_wide_photo() -> None:
    from cadnerf_core.cameras import intrinsics_from_fov
    from cadnerf_core.evaluation.evaluate import resize_view

    image = np.zeros((32, 48, 3), np.float32)
    image[:, :24] = 1.0
    K = intrinsics_from_fov(40.0, 48, 32)
    small, K_small = resize_view(image, K, 24)
    assert small.shape == (16, 24, 3)
    assert np.allclose(small[:, :12], 1.0) and np.allclose(small[:, 12:], 0.0)
    np.testing.assert_allclose(K_small, intrinsics_from_fov(40.0, 24, 16))


def test_cli_eval_takes_a_capture(tmp_path: Path, tiny_library_dir: Path) -> None:
    """``cadnerf eval CAPTURE --hold-out 2 --exif-focal --mesh``: a job on the other photos,
    the held-out one mapped (about the object's centre) to look at the object, rendered from
    the field and the mesh, and scored against it on white."""
    from typer.testing import CliRunner

    from cadnerf_cli.main import app
    from tests.configs import tiny_cli_options

    capture = make_capture(tmp_path, views=5)
    result = CliRunner().invoke(app, [
        "eval", str(capture), "--hold-out", "2", "--views", "4", "--exif-focal", "--mesh", "--json",
        "--align", "centred",
        "--library", str(tiny_library_dir), "--device", "cpu", "--work", str(tmp_path / "w"),
        *tiny_cli_options()])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)[0]
    assert report["test_names"] == ["002"] and report["n_views"] == 4
    assert report["test_masks"] == "dataset" and len(report["per_view_mesh"]) == 1
    assert 0.0 < report["image_masked"]["psnr"] < 100.0
    assert all(Path(p).is_file() for p in report["renders_mesh"])
    assert abs(report["focal_error_retrieved"]) < 0.05  # the EXIF focal length was given
    c2w = np.asarray(report["held_out"]["c2w"][0])
    along = c2w[:3, 3] @ c2w[:3, 2]
    miss = np.linalg.norm(c2w[:3, 3] - along * c2w[:3, 2])
    assert along < 0 and miss < 0.3 * np.linalg.norm(c2w[:3, 3])  # it looks at the object
    render = np.asarray(Image.open(report["renders"][0]), dtype=np.float32) / 255.0
    assert (render.min(axis=-1) < 0.9).mean() > 0.02  # not an empty white frame
    missing = CliRunner().invoke(app, ["eval", str(capture), "--views", "4",
                                       "--library", str(tiny_library_dir)])
    assert missing.exit_code == 2 and "--hold-out" in missing.output


def test_a_capture_without_masks_is_masked_as_a_job_masks_it(tmp_path: Path,
                                                              tiny_library: Any) -> None:
    """No masks: the job gets plain photos (it makes its own masks, not a whole-frame one), the
    held-out target is masked the same way and put on white, the frame fit sees the kept
    photos on white by the job's masks; the held-out camera is refined on that target."""
    from cadnerf_core.evaluation.dataset import load_dataset
    from cadnerf_core.evaluation.evaluate import evaluate_dataset
    from cadnerf_core.jobfolder import JobFolder
    from tests.configs import TINY_PRESET, tiny_request

    capture = make_capture(tmp_path, views=5, masks=False)
    assert not load_dataset(capture, hold_out=[2]).masked
    report = evaluate_dataset(capture, 4, tiny_library, preset=TINY_PRESET,
                              overrides=tiny_request(seed=1)["overrides"],
                              job_dir=tmp_path / "job", device="cpu", hold_out=[2],
                              align="per-view")
    assert report.test_masks == "found"
    # The held-out camera as the frame put it, then refined on its own photo: still a rigid
    # pose, moved by a small correction at most, and the scored target fits it no worse.
    from cadnerf_core.evaluation.capture import with_found_masks
    from cadnerf_core.evaluation.frame import photo_loss
    from cadnerf_core.nerf.model import TrainedModel

    frame, final = (np.asarray(report.held_out[k][0]) for k in ("c2w_frame", "c2w"))
    np.testing.assert_allclose(final[:3, :3] @ final[:3, :3].T, np.eye(3), atol=1e-5)
    assert np.linalg.norm(final[:3, 3] - frame[:3, 3]) < 0.5 * np.linalg.norm(frame[:3, 3])
    test = load_dataset(capture, hold_out=[2]).test
    assert test is not None
    target = with_found_masks(test).images[:1]
    K = np.asarray(report.held_out["K"])[:1]
    model = TrainedModel.load(Path(report.job_dir), "cpu")
    assert (photo_loss(model, final[None], K, target, seed=1)
            <= photo_loss(model, frame[None], K, target, seed=1))
    folder = JobFolder(report.job_dir)
    with Image.open(folder.photos()[0].path) as photo:
        assert photo.mode == "RGB"  # no alpha: the job found the object itself
    assert {r.source for r in folder.read_mask_sources()} <= {"learned", "grabcut"}
    assert folder.read_mask(0).mean() < 0.6  # the box, not the whole frame
    assert 0.0 < report.image_masked.psnr < 100.0


def test_a_frame_a_rig_took_upside_down_is_loaded_upright() -> None:
    """``upside_down_by_design``: the image turned half a turn, its camera rolled and its
    principal point moved to match, so a world point lands on the turned image's pixel."""
    from cadnerf_core.cameras import orbit_pose, project
    from cadnerf_core.evaluation.capture import upright

    rgb = np.random.default_rng(0).random((6, 8, 3)).astype(np.float32)
    mask = np.zeros((6, 8), bool)
    mask[1, 2] = True
    c2w = orbit_pose(30.0, 20.0, 4.0)
    K = np.array([[7.0, 0.0, 3.6], [0.0, 7.0, 2.9], [0.0, 0.0, 1.0]])
    turned_rgb, turned_mask, turned_c2w, turned_K = upright(rgb, mask, c2w, K)
    assert np.array_equal(turned_rgb, rgb[::-1, ::-1]) and turned_mask[4, 5]
    point = np.array([[0.1, -0.2, 0.3]])
    u, v = project(point, K, c2w)[0]
    np.testing.assert_allclose(project(point, turned_K, turned_c2w)[0], [8 - u, 6 - v],
                               atol=1e-9)

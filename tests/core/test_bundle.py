"""results.zip round trip: COLMAP reads the model back with the cameras of poses.json, every
transforms.json path resolves inside the bundle, the nerfstudio-data keys are there."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from cadnerf_core.export.usdz import usd_available
from cadnerf_core.jobfolder import BUNDLE, MESH, JobFolder
from tests.core.test_pipeline import write_job
from tests.gltf_validator import assert_no_errors_or_warnings, needs_validator

pytestmark = pytest.mark.usefixtures("one_torch_thread")

NERFSTUDIO_FRAME_KEYS = {"file_path", "transform_matrix", "fl_x", "fl_y", "cx", "cy", "w", "h",
                         "k1", "k2", "p1", "p2"}


@pytest.fixture(scope="module")
def job(tmp_path_factory: pytest.TempPathFactory, tiny_library: Any) -> Path:
    from cadnerf_core.pipeline import run_job

    job_dir = tmp_path_factory.mktemp("job")
    write_job(job_dir, tiny_library)
    run_job(job_dir, tiny_library, None, "cpu")
    return job_dir


@pytest.fixture(scope="module")
def unpacked(job: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bundle")
    with zipfile.ZipFile(job / BUNDLE) as bundle:
        assert bundle.testzip() is None
        bundle.extractall(out)
    return out


def test_transforms_paths_resolve_inside_the_bundle(job: Path, unpacked: Path) -> None:
    transforms = json.loads((unpacked / "transforms.json").read_text())
    poses = json.loads((unpacked / "poses.json").read_text())
    kept = [p for p in poses["photos"] if not p["discarded"]]
    assert transforms["camera_model"] == "OPENCV" and len(transforms["frames"]) == len(kept)
    for frame, pose in zip(transforms["frames"], kept, strict=True):
        assert set(frame) >= NERFSTUDIO_FRAME_KEYS
        image, mask = unpacked / frame["file_path"], unpacked / frame["mask_path"]
        assert image.is_file() and mask.is_file()
        with Image.open(image) as photo, Image.open(mask) as mask_image:
            assert photo.size == mask_image.size == (frame["w"], frame["h"])
            assert (frame["w"], frame["h"]) == (pose["width"], pose["height"])
        K = np.array(pose["K_photo"])
        assert [frame[k] for k in ("fl_x", "fl_y", "cx", "cy")] == pytest.approx(
            [K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
        gl_to_cv = np.diag([1.0, -1.0, -1.0, 1.0])
        assert np.allclose(np.array(frame["transform_matrix"]) @ gl_to_cv, pose["c2w"])
    # The photos are the uploads themselves (an upright PNG is kept byte for byte).
    for photo in JobFolder(job).photos():
        assert (unpacked / "images" / photo.name).read_bytes() == photo.path.read_bytes()


def test_colmap_reads_the_model_with_the_cameras_of_poses_json(unpacked: Path) -> None:
    import pycolmap

    model = pycolmap.Reconstruction(str(unpacked / "sparse" / "0"))
    poses = json.loads((unpacked / "poses.json").read_text())
    kept = {Path(p["name"]).name: p for p in poses["photos"] if not p["discarded"]}
    assert sorted(img.name for img in model.images.values()) == sorted(kept)
    for image in model.images.values():
        pose = kept[image.name]
        camera = model.cameras[image.camera_id]
        assert (camera.width, camera.height) == (pose["width"], pose["height"])
        assert np.allclose(camera.calibration_matrix(), pose["K_photo"], atol=1e-6)
        w2c = np.eye(4)
        w2c[:3] = image.cam_from_world().matrix()
        assert np.allclose(np.linalg.inv(w2c), pose["c2w"], atol=1e-6)
        assert (unpacked / "images" / image.name).is_file()
    assert len(model.points3D) > 100
    observed = [p for p in model.points3D.values() if p.track.length() > 0]
    assert observed, "no sampled point is seen by any camera"
    for point in observed[:50]:  # each observation is the point's projection
        for element in point.track.elements:
            image = model.images[element.image_id]
            xy = image.points2D[element.point2D_idx].xy
            projected = image.project_point(point.xyz)
            assert projected is not None and np.allclose(projected, xy, atol=0.01)


def test_poses_json_states_its_conventions_and_new_views(job: Path, unpacked: Path) -> None:
    poses = json.loads((unpacked / "poses.json").read_text())
    assert {"c2w", "world", "units", "K_photo"} <= set(poses["conventions"])
    assert "+Y up" in poses["conventions"]["world"]
    config = JobFolder(job).read_config()
    novel = poses["novel_views"]
    assert len(novel) == config.export.novel_views
    for view in novel:
        with Image.open(unpacked / view["view"]) as image:
            assert image.size == (view["width"], view["height"]) == (config.export.orbit_size,) * 2
        assert np.allclose(np.array(view["c2w"])[3], [0, 0, 0, 1])
    assert all(p["width"] > 0 and p["height"] > 0 for p in poses["photos"])


def test_every_bundle_part_is_an_artifact(job: Path) -> None:
    folder = JobFolder(job)
    artifacts = set(folder.artifacts())
    with zipfile.ZipFile(job / BUNDLE) as bundle:
        members = set(bundle.namelist())
    assert members <= artifacts
    assert {"sparse/0/cameras.txt", "sparse/0/images.txt", "sparse/0/points3D.txt",
            "transforms.json", "poses.json", "mesh.glb", "mesh.obj", "mesh.mtl",
            "mesh_texture.png"} <= members
    assert ("mesh.usdz" in members) == usd_available()
    assert BUNDLE in artifacts
    for name in artifacts:
        assert folder.artifact_path(name) is not None, name


@needs_validator
def test_the_jobs_glb_passes_the_khronos_validator(job: Path) -> None:
    assert_no_errors_or_warnings(job / MESH)


def test_a_rotated_jpeg_becomes_an_upright_png(tmp_path: Path) -> None:
    from cadnerf_core.export.bundle import write_images

    folder = JobFolder(tmp_path)
    image = Image.new("RGB", (40, 20), (200, 10, 10))
    exif = image.getexif()
    exif[0x0112] = 6  # rotate 90 degrees clockwise to display
    image.save(folder.new_photo_path(0, "turned", "jpg"), exif=exif)
    Image.new("RGB", (40, 20)).save(folder.new_photo_path(1, "plain", "jpg"))
    names = write_images(folder)
    assert names == {0: "images/000_turned.png", 1: "images/001_plain.jpg"}
    with Image.open(folder.file(names[0])) as upright:
        assert upright.size == (20, 40)

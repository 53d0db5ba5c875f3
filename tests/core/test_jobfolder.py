"""The job folder's owner: name rules, masks found by construction, one config shape, readers and
writers round-tripping, and the download allow-list."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cadnerf_core.config import DEFAULT_PRESET, resolve_config
from cadnerf_core.jobfolder import (
    MASK_UPLOADS,
    JobFolder,
    MaskSource,
    atomic_path,
    ensure_folder,
    is_artifact_name,
    media_type,
    photo_file_name,
    photo_index,
    safe_stem,
)


def _png(path: Path, size: tuple[int, int] = (8, 6), mode: str = "RGB") -> Path:
    Image.new(mode, size, 200).save(path)
    return path


@pytest.mark.parametrize(("name", "stem"), [
    ("IMG_01.jpg", "IMG_01"), ("../../etc/passwd", "passwd"), ("C:\\x\\my photo.png", "my_photo"),
    (".hidden", "hidden"), ("é.png", "photo"), ("a" * 60 + ".png", "a" * 40), ("a.b.c", "a_b"),
])
def test_safe_stems_never_become_paths(name: str, stem: str) -> None:
    assert safe_stem(name) == stem


def test_stored_photo_names_keep_the_order() -> None:
    assert photo_file_name(3, "IMG_01.JPG", "JPG") == "003_IMG_01.jpg"
    assert photo_index("003_IMG_01.jpg") == 3
    assert photo_index("/jobs/x/inputs/011_b.png") == 11
    assert photo_index("photo.png") is None and photo_index("masks/001.png") is None
    names = [photo_file_name(i, "p", "png") for i in (10, 2, 0)]
    assert sorted(names) == ["000_p.png", "002_p.png", "010_p.png"]


def test_a_mask_is_found_by_its_photo_whatever_its_own_name(tmp_path: Path) -> None:
    folder = JobFolder(tmp_path / "job")
    sources = tmp_path / "upload"
    sources.mkdir()
    photos = [folder.add_photo(i, _png(sources / f"IMG_0{i}.png"), f"IMG_0{i}.jpg", "jpg")
              for i in range(3)]
    folder.add_mask(photos[0], _png(sources / "IMG_00_mask.png", mode="L"))
    jpeg_mask = sources / "whatever.jpg"
    Image.new("L", (8, 6), 255).save(jpeg_mask, format="JPEG")
    folder.add_mask(photos[2], jpeg_mask, move=True)
    (folder.file("inputs") / "notes.txt").write_text("not a photo")
    found = folder.photos()
    assert [p.name for p in found] == ["000_IMG_00.jpg", "001_IMG_01.jpg", "002_IMG_02.jpg"]
    assert [p.index for p in found] == [0, 1, 2]
    assert found[1].mask is None
    assert found[0].mask is not None and found[2].mask is not None
    assert found[0].mask.read_bytes()[:4] == found[2].mask.read_bytes()[:4] == b"\x89PNG"
    assert not jpeg_mask.exists()  # moved
    with Image.open(found[2].mask) as stored:
        assert stored.size == (8, 6)
    assert not folder.file("masks").exists()  # uploads stay with the inputs, never downloadable
    assert all(folder.artifact_path(f"inputs/masks/{p.stem}.png") is None for p in photos)
    folder.clear_inputs()
    assert folder.photos() == [] and found[0].mask is not None and not found[0].mask.exists()


def test_a_mask_that_cannot_be_decoded_is_refused(tmp_path: Path) -> None:
    folder = JobFolder(tmp_path)
    photo = folder.add_photo(0, _png(tmp_path / "a.png"))
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"\xff\xd8\xff" + bytes(20))
    with pytest.raises((OSError, ValueError)):
        folder.add_mask(photo, bad)
    assert not folder.mask_path(photo).exists()


def test_the_config_has_one_shape(tmp_path: Path) -> None:
    folder = JobFolder(tmp_path)
    assert not folder.has_config()
    assert folder.read_config() == resolve_config(None, None)
    assert folder.read_config().preset == DEFAULT_PRESET
    config = resolve_config("preview", {"phase2.steps": 7, "seed": 4})
    folder.write_config(config)
    assert folder.read_config() == config
    assert json.loads(folder.file("config.json").read_text())["phase2"]["steps"] == 7
    folder.file("config.json").write_text(json.dumps({"preset": "preview", "overrides": {}}))
    with pytest.raises(ValueError):  # the request's shape is not a job's config
        folder.read_config()


def test_json_files_round_trip_and_missing_ones_read_as_none(tmp_path: Path) -> None:
    folder = JobFolder(tmp_path)
    assert folder.read_retrieval() is None and folder.read_poses() is None
    assert folder.read_metrics() is None and folder.read_mask_sources() == []
    folder.write_retrieval({"model_id": "mug", "matches": []})
    folder.write_poses("mug", [{"index": 0, "c2w": None}])
    folder.write_metrics({"mean_psnr": 20.5})
    assert folder.read_retrieval() == {"model_id": "mug", "matches": []}
    assert folder.read_poses() == {"model_id": "mug", "photos": [{"index": 0, "c2w": None}]}
    assert folder.read_metrics() == {"mean_psnr": 20.5}
    folder.file("metrics.json").write_text("[1, 2]")
    with pytest.raises(ValueError):
        folder.read_metrics()
    assert not list(tmp_path.glob(".*"))  # atomic writes leave no temporary files


@dataclass
class _Found:
    mask: np.ndarray
    source: MaskSource
    warnings: list[str] = field(default_factory=list)


def test_used_masks_overlays_sources_and_warnings_round_trip(tmp_path: Path) -> None:
    folder = JobFolder(tmp_path)
    for i in range(3):
        folder.add_photo(i, _png(tmp_path / f"p{i}.png"))
    photos = folder.photos()
    rng = np.random.default_rng(0)
    found = [_Found(rng.random((6, 8)) > 0.5, source)
             for source in ("uploaded", "alpha", "learned")]
    found[2].warnings.append("002_p2.png: the mask touches three borders; crop or retake")
    big = np.zeros((1500, 2000, 3), np.uint8)  # a large overlay is stored smaller
    records = folder.write_masks(photos, found, iter([np.zeros((6, 8, 3), np.uint8)] * 2
                                                     + [big]))
    assert [r.mask for r in records] == ["masks/000.png", "masks/001.png", "masks/002.png"]
    assert [r.overlay for r in records] == [f"masks/00{i}_overlay.jpg" for i in range(3)]
    assert folder.read_mask_sources() == records
    assert [r.source for r in records] == ["uploaded", "alpha", "learned"]
    assert [r.warnings for r in records] == [[], [], found[2].warnings]
    assert [r.name for r in records] == [p.name for p in photos]
    for i, entry in enumerate(found):
        assert np.array_equal(folder.read_mask(i), entry.mask)
        with Image.open(folder.file(f"masks/00{i}.png")) as stored:
            assert stored.mode == "L" and set(np.unique(np.asarray(stored))) <= {0, 255}
    with Image.open(folder.file("masks/002_overlay.jpg")) as overlay:
        assert overlay.format == "JPEG" and overlay.size == (1024, 768)


def test_only_listed_artifacts_inside_the_folder_are_served(tmp_path: Path) -> None:
    folder = JobFolder(tmp_path / "job")
    folder.root.mkdir()
    folder.write_metrics({})
    folder.write_config(resolve_config("preview"))
    folder.file("views").mkdir()
    _png(folder.view_path(1))
    _png(folder.view_path(0))
    folder.write_masks([], [], [])
    folder.file("masks").mkdir()
    _png(folder.file("masks/001.png"))
    _png(folder.file("masks/001_overlay.jpg"))
    _png(folder.file("masks/001_photo.png"))
    (folder.file("views") / "notes.png").write_bytes(b"x")
    folder.file("state.json").write_text("{}")
    outside = _png(tmp_path / "secret.png")
    (folder.file("views") / "002.png").symlink_to(outside)
    assert folder.artifacts() == ["metrics.json", "config.json", "masks.json", "views/000.png",
                                  "views/001.png", "views/002.png", "masks/001.png",
                                  "masks/001_overlay.jpg"]
    assert folder.artifact_path("views/001.png") == folder.view_path(1).resolve()
    for name in ("views/002.png", "state.json", "views/notes.png", "../secret.png",
                 "views/../config.json", "inputs/000_a.png", "mesh.glb", "checkpoints/phase1.pt",
                 "masks/001_photo.png", "inputs/masks/000_a.png", "masks/../inputs/000_a.png"):
        assert folder.artifact_path(name) is None, name
    assert is_artifact_name("masks/004.png") and not is_artifact_name("masks/4.png")
    assert is_artifact_name("masks/004_overlay.jpg") and not is_artifact_name("used_masks/004.png")
    assert media_type("masks/004_overlay.jpg") == "image/jpeg"
    assert media_type("orbit.mp4") == "video/mp4" and media_type("views/003.png") == "image/png"
    assert media_type("mesh.glb") == "model/gltf-binary"
    assert folder.checkpoint_path(2) == tmp_path / "job" / "checkpoints" / "phase2.pt"


def test_writers_never_recreate_a_missing_job_folder(tmp_path: Path) -> None:
    """A deleted job's folder stays gone: its subfolders are created only inside it."""
    folder = JobFolder(tmp_path / "job")
    folder.root.mkdir()
    with atomic_path(folder.view_path(0)) as tmp:  # views/ is created inside the job folder
        Image.new("RGB", (8, 6)).save(tmp, format="PNG")
    assert folder.artifacts() == ["views/000.png"]
    folder.write_metrics({"a": 1})
    shutil.rmtree(folder.root)
    with pytest.raises(FileNotFoundError):
        folder.write_metrics({"a": 2})
    with pytest.raises(FileNotFoundError), atomic_path(folder.view_path(1)):
        pass
    with pytest.raises(FileNotFoundError):
        ensure_folder(folder.file(MASK_UPLOADS))
    assert not folder.root.exists()

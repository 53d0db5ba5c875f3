"""The job folder: its layout, its name rules, and typed readers and writers of every file in it.

One job is one folder, written by the app at upload (or the CLI), then by the pipeline::

    inputs/NNN_<stem>.<ext>   the photos; NNN (000, 001, ...) is the photo order
    inputs/masks/NNN_<stem>.png   uploaded masks, each named after ITS PHOTO (not its own name)
    config.json               the resolved PipelineConfig, written once at the door
    masks/NNN.png             the mask photo NNN used (8-bit, 255 = object, the photo's
                              working size after EXIF orientation)
    masks/NNN_overlay.jpg     a picture of that mask over the photo, to look at
    masks.json                per photo: name, mask source (uploaded, alpha, learned, grabcut),
                              warnings, and the mask and overlay file names
    matches/pairs.npz         the photos' verified matches (read back when the job runs again)
    matches/NNN_MMM.jpg       a picture of neighbouring photos NNN and MMM's matches
    retrieval.json            model, matches and discarded photos (the retrieval stage)
    poses.json, transforms.json, metrics.json
    result.json               the job's result (``jobresult.JobResult``), written last
    views/NNN.png, orbit.mp4, orbit.gif, mesh.glb, mesh.obj, mesh.mtl, mesh_texture.png,
    mesh.usdz                 the mesh for AR Quick Look (where usd-core is installed)
    images/NNN_<stem>.<ext>   the photos for other tools: the upload itself (linked) when it is
                              an upright JPEG or PNG, else its upright pixels as PNG
    sparse/0/cameras.txt, sparse/0/images.txt, sparse/0/points3D.txt   a COLMAP text model
    results.zip               images/, masks/, transforms.json, sparse/0/, poses.json, meshes
    checkpoints/phaseN.pt, log.txt, eval/ (held-out renders of an evaluation)

Inputs (photos and uploaded masks) are never downloadable; the masks the job used are.
``state.json`` belongs to the service's job state, not to this module. Where the folder's bytes
live (this machine, or S3-compatible object storage of which folders are scratch copies) is
``jobstorage``'s, re-exported here. Everything here is light (stdlib, pydantic, numpy, Pillow;
boto3 only once object storage is used): the API imports it.
"""

# ruff: noqa: F405 - the names come from jobnames, part of this owner
from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Protocol

import numpy as np
from PIL import Image
from pydantic import BaseModel, ConfigDict

from cadnerf_core.config import PipelineConfig, resolve_config
from cadnerf_core.jobnames import *  # noqa: F403 - the names are part of this owner
from cadnerf_core.jobnames import _NUMBERED
from cadnerf_core.jobresult import JobResult
from cadnerf_core.jobstorage import (  # noqa: F401 - where the bytes live, part of this owner
    JobStorage,
    LocalStorage,
    S3Storage,
    StorageError,
    Transfer,
    folder_bytes,
    open_storage,
)

SUBFOLDERS = (MASK_UPLOADS, SPARSE, INPUTS, MASKS, VIEWS, IMAGES, CHECKPOINTS, EVAL, MATCHES)
"""The folders inside a job folder (nested ones first), created on demand; the job folder
itself never is."""


def ensure_folder(folder: Path) -> None:
    """Create a job folder's subfolder (``SUBFOLDERS``) if missing; never a job folder.

    A deleted job's folder is gone: writing into it must fail, not bring it back.

    Raises:
        FileNotFoundError: ``folder`` is missing and is not a subfolder of an existing job
            folder.
    """
    if folder.is_dir():
        return
    for name in SUBFOLDERS:
        parts = PurePosixPath(name).parts
        if folder.parts[-len(parts):] != parts:
            continue
        current = folder.parents[len(parts) - 1]  # the job folder
        if not current.is_dir():
            break
        for part in parts:
            current = current / part
            current.mkdir(exist_ok=True)
        return
    raise FileNotFoundError(2, "the job folder is gone (deleted?)", str(folder))


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix), renamed onto it on success, so a
    reader never sees half a file and a killed job leaves no truncated one. Only a subfolder
    of an existing job folder is created (``ensure_folder``)."""
    ensure_folder(path.parent)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically (indented, UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2), encoding="utf-8")


@dataclass(frozen=True)
class InputPhoto:
    """A photo in ``inputs/`` and the uploaded mask stored for it, if any."""

    index: int
    path: Path
    mask: Path | None

    @property
    def name(self) -> str:
        """The stored file name (``NNN_<stem>.<ext>``)."""
        return self.path.name


class FoundMask(Protocol):
    """What ``write_masks`` keeps of one photo's mask (``intake.masks.MaskResult`` is one)."""

    mask: np.ndarray  # [H, W] bool, the photo's size
    source: MaskSource
    warnings: list[str]  # what looks wrong with it (empty when fine)


class MaskRecord(BaseModel):
    """One photo's entry in ``masks.json``."""

    model_config = ConfigDict(frozen=True, extra="ignore")

    index: int
    """Photo index (order in ``inputs/``)."""
    name: str
    """The photo's stored name."""
    source: MaskSource
    """Where the mask came from."""
    warnings: list[str] = []
    """What looks wrong with the mask, each naming the photo and what to do."""
    mask: str
    """The used mask, relative to the job folder (``masks/NNN.png``)."""
    overlay: str | None = None
    """Its overlay, relative to the job folder (``masks/NNN_overlay.jpg``)."""


class JobFolder:
    """One job's folder: every path in it, and the readers and writers of its files."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)

    def file(self, name: str) -> Path:
        """The path of a file named by one of this module's constants (``METRICS``...)."""
        return self.root / name

    # Inputs: photos and uploaded masks.

    def new_photo_path(self, index: int, filename: str, ext: str) -> Path:
        """Where photo ``index`` (uploaded as ``filename``, of type ``ext``) is stored."""
        self.root.mkdir(parents=True, exist_ok=True)  # a new job (the app, the CLI)
        ensure_folder(self.root / INPUTS)
        return self.root / INPUTS / photo_file_name(index, filename, ext)

    def add_photo(self, index: int, source: Path, filename: str | None = None,
                  ext: str | None = None, move: bool = False) -> Path:
        """Store a photo file as photo ``index`` (moved or copied). Returns its stored path."""
        suffix = ext or source.suffix.lstrip(".") or "png"
        target = self.new_photo_path(index, filename or source.name, suffix)
        if move:
            source.rename(target)
        else:
            shutil.copyfile(source, target)
        return target

    def mask_path(self, photo: Path | str) -> Path:
        """Where the uploaded mask of a stored photo lives: ``inputs/masks/<photo's stem>.png``."""
        return self.root / MASK_UPLOADS / f"{PurePosixPath(Path(photo).name).stem}.png"

    def clear_inputs(self) -> None:
        """Remove every photo and uploaded mask (before staging a new set into the folder)."""
        shutil.rmtree(self.root / INPUTS, ignore_errors=True)

    def add_mask(self, photo: Path | str, source: Path, move: bool = False) -> Path:
        """Store ``source`` as the uploaded mask of a stored photo, as PNG.

        A PNG is moved or copied as it is; another format is decoded and saved as PNG.

        Raises:
            OSError, ValueError: a mask that cannot be decoded (nothing is stored then).
        """
        target = self.mask_path(photo)
        ensure_folder(target.parent)
        with source.open("rb") as handle:
            is_png = handle.read(8) == b"\x89PNG\r\n\x1a\n"
        if is_png and move:
            source.rename(target)
        elif is_png:
            shutil.copyfile(source, target)
        if is_png:
            return target
        with Image.open(source) as image, atomic_path(target) as tmp:
            keep = image.mode in ("1", "L", "LA", "P", "RGB", "RGBA")
            (image if keep else image.convert("RGB")).save(tmp, format="PNG")
        if move:
            source.unlink()
        return target

    def photos(self) -> list[InputPhoto]:
        """The photos in ``inputs/`` in order (sorted names) with their uploaded masks."""
        folder = self.root / INPUTS
        paths = sorted(p for p in folder.iterdir() if p.is_file()
                       and p.suffix.lower() in PHOTO_SUFFIXES) if folder.is_dir() else []
        return [InputPhoto(i, p, m if (m := self.mask_path(p)).is_file() else None)
                for i, p in enumerate(paths)]

    @staticmethod
    def photo_ref(photo: Path | str) -> str:
        """A photo's path relative to the job folder (``inputs/<name>``), for JSON files."""
        return f"{INPUTS}/{Path(photo).name}"

    # Config: written once, in one shape.

    def write_config(self, config: PipelineConfig) -> None:
        """Write the resolved configuration (the job runs with exactly this)."""
        write_json(self.root / CONFIG, config.model_dump(mode="json"))

    def has_config(self) -> bool:
        """Whether ``config.json`` exists."""
        return (self.root / CONFIG).is_file()

    def read_config(self) -> PipelineConfig:
        """The job's resolved configuration; the default preset when ``config.json`` is missing.

        Raises:
            ValueError: unreadable JSON or not a valid PipelineConfig.
        """
        if not self.has_config():
            return resolve_config(None, None)
        return PipelineConfig.model_validate_json((self.root / CONFIG).read_bytes())

    # JSON results.

    def _read(self, name: str) -> Any:
        path = self.root / name
        return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None

    def _read_object(self, name: str) -> dict[str, Any] | None:
        data = self._read(name)
        if data is not None and not isinstance(data, dict):
            raise ValueError(f"{name} does not hold a JSON object")
        return data

    def write_retrieval(self, data: dict[str, Any]) -> None:
        """Write ``retrieval.json`` (``RetrievalResult.to_json()``)."""
        write_json(self.root / RETRIEVAL, data)

    def read_retrieval(self) -> dict[str, Any] | None:
        """``retrieval.json``, None before retrieval ran. Raises ValueError on a broken file."""
        return self._read_object(RETRIEVAL)

    def write_warnings(self, warnings: list[str]) -> None:
        """Write ``warnings.json``: what the job tells its user (``job_warnings``)."""
        write_json(self.root / WARNINGS, warnings)

    def read_warnings(self) -> list[str] | None:
        """``warnings.json``, None before the job's intake wrote it. Raises ValueError on a
        broken file."""
        data = self._read(WARNINGS)
        if data is not None and not (isinstance(data, list)
                                     and all(isinstance(w, str) for w in data)):
            raise ValueError(f"{WARNINGS} does not hold a list of strings")
        return data

    def write_poses(self, model_id: str, photos: list[dict[str, Any]],
                    extra: dict[str, Any] | None = None) -> None:
        """Write ``poses.json``: the model id, one entry per photo, and ``extra`` keys (its
        ``conventions``, the ``novel_views``)."""
        write_json(self.root / POSES, {"model_id": model_id, "photos": photos, **(extra or {})})

    def read_poses(self) -> dict[str, Any] | None:
        """``poses.json`` (``{"model_id", "photos"}``), None before export."""
        return self._read_object(POSES)

    def write_transforms(self, data: dict[str, Any]) -> None:
        """Write ``transforms.json`` (nerfstudio-data layout, NeRF-synthetic compatible)."""
        write_json(self.root / TRANSFORMS, data)

    def write_metrics(self, data: dict[str, Any]) -> None:
        """Write ``metrics.json``."""
        write_json(self.root / METRICS, data)

    def read_metrics(self) -> dict[str, Any] | None:
        """``metrics.json``, None before export."""
        return self._read_object(METRICS)

    def write_result(self, result: JobResult) -> None:
        """Write ``result.json``: what the job gives its user (the last file a job writes)."""
        with atomic_path(self.root / RESULT) as tmp:
            tmp.write_text(result.model_dump_json(indent=2), encoding="utf-8")

    def read_result(self) -> JobResult | None:
        """``result.json``, None before the job finished.

        Raises:
            ValueError: a broken file, or one not in ``JobResult``'s shape.
        """
        path = self.root / RESULT
        return JobResult.model_validate_json(path.read_bytes()) if path.is_file() else None

    # Masks used, their overlays, where each came from and what looks wrong.

    def write_masks(self, photos: Sequence[InputPhoto], found: Sequence[FoundMask],
                    overlays: Iterable[np.ndarray]) -> list[MaskRecord]:
        """Keep each photo's mask (``masks/NNN.png``, 0/255), its overlay
        (``masks/NNN_overlay.jpg``, at most ``OVERLAY_SIDE`` px) and ``masks.json``.

        Args:
            photos: the job's photos; found: their masks [H_i, W_i] bool, sources, warnings.
            overlays: one [H_i, W_i, 3] uint8 picture each (a generator keeps one in memory).
        """
        records = []
        for photo, result, overlay in zip(photos, found, overlays, strict=True):
            name, picture = numbered_name(MASKS, photo.index), overlay_name(photo.index)
            with atomic_path(self.root / name) as tmp:
                Image.fromarray(np.asarray(result.mask, bool).astype(np.uint8) * 255, "L").save(
                    tmp, format="PNG")
            image = Image.fromarray(np.asarray(overlay, np.uint8), "RGB")
            image.thumbnail((OVERLAY_SIDE, OVERLAY_SIDE), Image.Resampling.LANCZOS)
            with atomic_path(self.root / picture) as tmp:
                image.save(tmp, format="JPEG", quality=85)
            records.append(MaskRecord(index=photo.index, name=photo.name, source=result.source,
                                      warnings=list(result.warnings), mask=name,
                                      overlay=picture))
        write_json(self.root / MASK_SOURCES, {"photos": [r.model_dump() for r in records]})
        return records

    def read_mask_sources(self) -> list[MaskRecord]:
        """The entries of ``masks.json`` (empty before the masks stage ran).

        Raises:
            ValueError: a broken file.
        """
        data = self._read_object(MASK_SOURCES) or {}
        return [MaskRecord.model_validate(entry) for entry in data.get("photos", [])]

    def read_mask(self, index: int) -> np.ndarray:
        """The mask photo ``index`` used, [H, W] bool. Raises FileNotFoundError before masks."""
        with Image.open(self.root / numbered_name(MASKS, index)) as image:
            return np.asarray(image.convert("L")) > 127

    # Rendered outputs, checkpoints, log.

    # The photos' matches: a cache of the verified pairs, and a picture of each neighbouring pair.

    def write_match_cache(self, arrays: dict[str, np.ndarray]) -> None:
        """Store the verified pairs' arrays (``retrieval.pairs_io.to_arrays``)."""
        with atomic_path(self.root / MATCH_CACHE) as tmp, tmp.open("wb") as stream:
            np.savez(stream, **arrays)  # type: ignore[arg-type]

    def read_match_cache(self) -> dict[str, np.ndarray] | None:
        """The stored pairs' arrays, None when absent or unreadable."""
        try:
            with np.load(self.root / MATCH_CACHE, allow_pickle=False) as data:
                return {name: data[name] for name in data.files}
        except (OSError, ValueError):
            return None

    def write_match_picture(self, i: int, j: int, rgb: np.ndarray) -> None:
        """Store the picture of photos ``i`` and ``j``'s matches (JPEG)."""
        with atomic_path(self.root / match_picture_name(i, j)) as tmp:
            Image.fromarray(rgb).save(tmp, format="JPEG", quality=85)

    def view_path(self, index: int) -> Path:
        """``views/NNN.png``: the photos' views at their refined poses, then new views."""
        return self.root / numbered_name(VIEWS, index)

    def checkpoint_path(self, phase: int) -> Path:
        """``checkpoints/phase{phase}.pt``."""
        return self.root / CHECKPOINTS / f"phase{phase}.pt"

    @property
    def log_path(self) -> Path:
        """``log.txt``: the core's log of this job."""
        return self.root / LOG

    @property
    def eval_dir(self) -> Path:
        """``eval/``: held-out renders written by an evaluation."""
        return self.root / EVAL

    # Files for other tools: photos, COLMAP model, bundle.

    def write_text(self, name: str, text: str) -> None:
        """Write a text file named by one of this module's constants (``COLMAP_CAMERAS``...)."""
        with atomic_path(self.root / name) as tmp:
            tmp.write_text(text, encoding="utf-8")

    def bundle_members(self) -> list[str]:
        """What ``results.zip`` holds, of the files present: photos, used masks (no overlays),
        ``transforms.json``, the COLMAP model, ``poses.json``, metrics, meshes and renders."""
        names = [n for n in self.artifacts()
                 if n not in (BUNDLE, LOG, CONFIG, MASK_SOURCES, RESULT)
                 and not n.endswith(OVERLAY_SUFFIX)]
        return sorted(names, key=lambda n: (not n.startswith(f"{IMAGES}/"), n))

    # Downloads.

    def artifacts(self) -> list[str]:
        """Names of the downloadable files present: fixed files, then views, then used masks
        and their overlays."""
        names = [n for n in MEDIA_TYPES if (self.root / n).is_file()]
        for folder in (VIEWS, MASKS, MATCHES, IMAGES):
            if (self.root / folder).is_dir():
                names += sorted(n for p in (self.root / folder).iterdir()
                                if _NUMBERED.match(n := f"{folder}/{p.name}") and p.is_file())
        return names

    def artifact_path(self, name: str) -> Path | None:
        """The file behind an artifact name; None for a name off the list, a missing file, or a
        path that leaves the folder (a symbolic link pointing out)."""
        if not is_artifact_name(name):
            return None
        root = self.root.resolve()
        path = (root / name).resolve()
        return path if path.is_relative_to(root) and path.is_file() else None

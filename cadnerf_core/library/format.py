"""The CAD mini library on disk: its format, and loading it for retrieval and training.

Layout of a library folder::

    manifest.json            format version, LibrarySpec, models (with sha256 of every file)
    <model id>/mesh.ply      normalised watertight mesh (+Y up, front +Z, max |v| = 1)
    <model id>/silhouettes.npz   bits: np.packbits of [V, S, S] canonical crops (last axis),
                             boxes: [V, 3] (x0, y0, side) of each crop in render pixels
    <model id>/occupancy.npz     bits, shape: the OccupancyGrid, bit-packed

The library's poses are shared by all models (``library_poses``, azimuth-major). Files are
written byte-for-byte deterministically (fixed zip timestamps) so checksums only change when
the content does.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from cadnerf_core.errors import LibraryError
from cadnerf_core.intake.crop import CropBox, crop_intrinsics
from cadnerf_core.library.occupancy import OccupancyGrid

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
MESH_FILE = "mesh.ply"
SILHOUETTES_FILE = "silhouettes.npz"
OCCUPANCY_FILE = "occupancy.npz"
MODEL_FILES = (MESH_FILE, SILHOUETTES_FILE, OCCUPANCY_FILE)
REBUILD_HINT = "run `cadnerf library build`"
_ZIP_DATE = (2020, 1, 1, 0, 0, 0)


@dataclass(frozen=True)
class LibrarySpec:
    """How the library's silhouettes and occupancy grids are made."""

    n_azimuths: int = 36
    """Azimuths of the pose set, evenly spaced from 0 (the front). 36 (10-degree steps), not
    DESIGN.md's 20: on the 52 synthetic walks of ``benchmarks/bench_retrieval.py``, with the
    DP's spread prior at 20, the median rotation error of retrieval is 15.2 degrees with 20
    azimuths and 13.0 with 36 (72 gain nothing more); the IoU table stays a few ms."""
    elevations: tuple[float, ...] = (0.0, 7.5, 15.0, 22.5, 30.0, 37.5, 45.0, 52.5, 60.0)
    """Elevations of the pose set in degrees: 7.5-degree steps (324 views a model), not 15
    (180): on the 52 synthetic walks of ``benchmarks/bench_retrieval.py`` the median rotation
    error falls from 13.6 to 12.9 degrees and the sets where our solver is worse than
    Algorithm 1 from 9 to 5 (docs/bench_retrieval_full.md); retrieval of 9 photos stays
    ~55 ms."""
    distance: float = 4.0
    """Camera distance from the origin (the model is inside the unit sphere)."""
    fov_deg: float = 40.0
    """Horizontal field of view of the render camera in degrees."""
    near_distance: float | None = 2.2
    """Distance of a second set of silhouettes, the same poses seen from nearer (None: none).
    A phone's wide lens (about 65 degrees across) frames an object from about half the
    distance a 40-degree camera does, and the nearer view changes the silhouette's
    perspective; retrieval picks the set whose perspective matches the photos' when their
    focal length is known (``RetrievalConfig.perspective``). On the 52 synthetic walks of
    ``benchmarks/bench_retrieval.py`` rendered at 65 degrees, the median rotation error of
    retrieval is 14.7 degrees from the 40-degree set and 13.9 from this one (at 40 degrees:
    13.6 against 15.2), and the 40-degree set mirrors three of the four armchair walks;
    training (``docs/bench_training_focal.md``) gains 0.9 dB on such photos."""
    near_fov_deg: float = 65.0
    """Horizontal field of view of the near set's render camera (the unit sphere's outline
    spans about 80% of it at ``near_distance`` 2.2, against 71% of the far set's)."""
    render_size: int = 128
    """Side of the square silhouette renders in pixels."""
    silhouette_size: int = 64
    """Side of the stored canonical crops in pixels."""
    margin: float = 0.1
    """Canonical crop margin (free fraction of the crop on each side)."""
    grid_size: int = 128
    """Occupancy grid cells per side over [-1, 1]^3."""

    @property
    def n_views(self) -> int:
        """Number of library poses, V."""
        return self.n_azimuths * len(self.elevations)

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """The pose set. Returns c2w [V, 4, 4] and az_el [V, 2] in degrees."""
        # Imported here: cameras imports torch, which library building and listing never need.
        from cadnerf_core.cameras.conventions import library_poses

        return library_poses(self.n_azimuths, self.elevations, self.distance)

    def K_render(self) -> np.ndarray:  # noqa: N802 (the camera matrix is K everywhere)
        """Intrinsics of the render camera. Returns [3, 3]."""
        from cadnerf_core.cameras.conventions import intrinsics_from_fov

        return intrinsics_from_fov(self.fov_deg, self.render_size)

    def near_spec(self) -> LibrarySpec | None:
        """The near set's settings as a spec of its own (no near set of its own), or None."""
        if self.near_distance is None:
            return None
        return replace(self, distance=self.near_distance, fov_deg=self.near_fov_deg,
                       near_distance=None)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        data = asdict(self)
        data["elevations"] = list(self.elevations)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LibrarySpec:
        """Inverse of ``to_dict`` (a manifest written before the near set has none)."""
        values = dict(data)
        values["elevations"] = tuple(float(e) for e in values["elevations"])
        values.setdefault("near_distance", None)
        return cls(**values)


@dataclass(frozen=True)
class ModelEntry:
    """One library model as listed in the manifest."""

    id: str
    """Unique id, also the model's folder name."""
    category: str
    """Object category (chair, car, ...) or basic shape name."""
    kind: str
    """"object" or "basic"."""
    source: str
    """Where it came from: "parametric:cadnerf" or "import:<file name>"."""
    licence: str
    """Licence of the geometry."""
    n_triangles: int
    """Triangles of the stored mesh."""
    checksums: dict[str, str] = field(default_factory=dict)
    """sha256 of each of the model's files, by file name."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return asdict(self)


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays as a compressed .npz whose bytes depend only on the arrays."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name in sorted(arrays):
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.ascontiguousarray(arrays[name]),
                                      allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, buffer.getvalue())


def load_npz(path: Path) -> dict[str, np.ndarray]:
    """Read every array of an .npz file (no pickles).

    Raises:
        LibraryError: naming the file when it is missing or unreadable.
    """
    try:
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise LibraryError(f"{path} is unreadable ({exc}); {REBUILD_HINT}") from exc


NEAR_SUFFIX = "_near"
"""Suffix of the near set's arrays in a silhouettes file (``bits_near``, ``boxes_near``)."""


def pack_silhouettes(masks: np.ndarray, boxes: np.ndarray,
                     near: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Arrays of a silhouettes file. masks [V, S, S] bool, boxes [V, 3] -> {bits, boxes}, and
    with ``near`` (its masks and boxes) also {bits_near, boxes_near}."""
    arrays: dict[str, np.ndarray] = {"bits": np.packbits(masks, axis=-1),
                                     "boxes": np.asarray(boxes, dtype=np.float64)}
    if near is not None:
        arrays["bits" + NEAR_SUFFIX] = np.packbits(near[0], axis=-1)
        arrays["boxes" + NEAR_SUFFIX] = np.asarray(near[1], dtype=np.float64)
    return arrays


def write_manifest(root: Path, spec: LibrarySpec, models: list[ModelEntry],
                   build_info: dict[str, Any]) -> None:
    """Write ``manifest.json`` atomically (sorted keys: same content, same bytes)."""
    data = {"format_version": FORMAT_VERSION, "spec": spec.to_dict(), "build": build_info,
            "models": [m.to_dict() for m in models]}
    temporary = root / f".{MANIFEST}.tmp"
    temporary.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    os.replace(temporary, root / MANIFEST)  # atomic: readers see the old or the new manifest


def read_manifest(root: Path) -> dict[str, Any]:
    """The parsed manifest of a library folder, with its format version checked.

    Raises:
        LibraryError: when it is missing, unreadable or of another format version.
    """
    path = Path(root) / MANIFEST
    if not path.is_file():
        raise LibraryError(f"no library at {root} ({path} is missing); {REBUILD_HINT}")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise LibraryError(f"{path} is damaged ({exc}); {REBUILD_HINT}") from exc
    version = data.get("format_version") if isinstance(data, dict) else None
    if version != FORMAT_VERSION:
        raise LibraryError(f"{path} has format version {version}, this code reads "
                           f"{FORMAT_VERSION}; {REBUILD_HINT}")
    return data


def verify_model(root: Path, entry: ModelEntry) -> None:
    """Check that every file of a model exists and matches its checksum.

    Raises:
        LibraryError: naming the first missing, stale or damaged file.
    """
    for name in MODEL_FILES:
        path = Path(root) / entry.id / name
        expected = entry.checksums.get(name)
        if expected is None:
            raise LibraryError(f"{MANIFEST} lists no checksum for {path}; {REBUILD_HINT}")
        if not path.is_file():
            raise LibraryError(f"{path} is missing; {REBUILD_HINT}")
        if sha256_file(path) != expected:
            raise LibraryError(f"{path} is stale or damaged (checksum mismatch); {REBUILD_HINT}")


class Library:
    """A loaded library: its models, the shared pose set, silhouettes and crop boxes."""

    def __init__(self, root: Path, spec: LibrarySpec, models: list[ModelEntry],
                 packed_silhouettes: np.ndarray, boxes: np.ndarray,
                 near: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Args: packed_silhouettes [M, V, S, S/8] uint8 (packbits), boxes [M, V, 3]; near: the
        same two for the near set (``LibrarySpec.near_distance``), when the spec has one."""
        self.root = Path(root)
        self._near_arrays = near
        self._far: Library | None = None  # set on a near set: the library it belongs to
        self.spec = spec
        self.models = models
        self.poses, self.az_el = spec.poses()
        self.K_render = spec.K_render()
        self.boxes = boxes
        self._packed = packed_silhouettes
        self._index = {m.id: i for i, m in enumerate(models)}
        self._occupancy: dict[str, OccupancyGrid] = {}

    @cached_property
    def near(self) -> Library | None:
        """The same models and poses seen from ``spec.near_distance`` (a Library of its own
        whose poses, camera, silhouettes and boxes are the near set's; occupancy shared), or
        None when the library has no near set."""
        near_spec = self.spec.near_spec()
        if near_spec is None or self._near_arrays is None:
            return None
        near = Library(self.root, near_spec, self.models, *self._near_arrays)
        near._occupancy = self._occupancy
        near._far = self
        return near

    def view_set(self, perspective: str) -> Library:
        """The Library of a silhouette set by name: "far" (this one) or "near".

        Raises:
            LibraryError: for "near" when the library has no near set.
        """
        far = self._far or self
        if perspective == "far":
            return far
        if perspective == "near" and far.near is not None:
            return far.near
        raise LibraryError(f"the library at {self.root} has no '{perspective}' silhouette set; "
                           f"{REBUILD_HINT}")

    @cached_property
    def silhouettes(self) -> np.ndarray:
        """[M, V, S, S] bool canonical crops of every model and view (unpacked once)."""
        size = self.spec.silhouette_size
        return np.unpackbits(self._packed, axis=-1, count=size).astype(bool)

    def index(self, model_id: str) -> int:
        """Position of a model in ``models``.

        Raises:
            KeyError: naming the id when the library has no such model.
        """
        try:
            return self._index[model_id]
        except KeyError:
            raise KeyError(f"no model '{model_id}' in the library at {self.root}") from None

    def crop_box(self, m: int, v: int, size: int) -> CropBox:
        """Canonical crop window of model m's view v, resized to ``size`` px."""
        x0, y0, side = (float(x) for x in self.boxes[m, v])
        return CropBox(x0, y0, side, size)

    def canonical_K(self, m: int, v: int, size: int) -> np.ndarray:  # noqa: N802
        """Intrinsics of model m's view v in its canonical crop at ``size`` px. Returns [3, 3]."""
        return crop_intrinsics(self.K_render, self.crop_box(m, v, size))

    def occupancy(self, model_id: str) -> OccupancyGrid:
        """The model's occupancy grid (loaded once, then cached)."""
        if model_id not in self._occupancy:
            path = self.root / self.models[self.index(model_id)].id / OCCUPANCY_FILE
            self._occupancy[model_id] = OccupancyGrid.unpack(load_npz(path))
        return self._occupancy[model_id]

    def mesh(self, model_id: str) -> trimesh.Trimesh:
        """The model's normalised watertight mesh."""
        path = self.root / self.models[self.index(model_id)].id / MESH_FILE
        try:
            loaded = trimesh.load(str(path), process=False, force="mesh")
        except (OSError, ValueError) as exc:
            raise LibraryError(f"{path} is unreadable ({exc}); {REBUILD_HINT}") from exc
        assert isinstance(loaded, trimesh.Trimesh)
        return loaded


def _load_silhouettes(path: Path, spec: LibrarySpec) -> list[tuple[np.ndarray, np.ndarray]]:
    """Packed silhouettes [V, S, S/8] and boxes [V, 3] of one model, shapes checked: the main
    set's, then the near set's where the spec has one."""
    arrays = load_npz(path)
    size, views = spec.silhouette_size, spec.n_views
    suffixes = ["", NEAR_SUFFIX] if spec.near_distance is not None else [""]
    out = []
    for suffix in suffixes:
        bits, boxes = arrays.get("bits" + suffix), arrays.get("boxes" + suffix)
        if (bits is None or boxes is None or bits.shape != (views, size, (size + 7) // 8)
                or boxes.shape != (views, 3)):
            raise LibraryError(f"{path} does not match the library spec ({views} views of "
                               f"{size} px{', and a near set' if suffix else ''}); "
                               f"{REBUILD_HINT}")
        out.append((bits, boxes))
    return out


def load_library(root: Path | str, verify: bool = True) -> Library:
    """Load a library folder.

    Args:
        root: folder with ``manifest.json``.
        verify: check every file's sha256 against the manifest.
    Returns:
        The Library, silhouettes ready (packed, unpacked on first use).
    Raises:
        LibraryError: naming the missing, stale or damaged file, and saying how to rebuild.
    """
    root = Path(root)
    data = read_manifest(root)
    try:
        spec = LibrarySpec.from_dict(data["spec"])
        models = [ModelEntry(**m) for m in data["models"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise LibraryError(f"{root / MANIFEST} is damaged ({exc}); {REBUILD_HINT}") from exc
    if not models:
        raise LibraryError(f"the library at {root} has no models; {REBUILD_HINT}")
    sets: list[list[tuple[np.ndarray, np.ndarray]]] = []
    for entry in models:
        if verify:
            verify_model(root, entry)
        sets.append(_load_silhouettes(root / entry.id / SILHOUETTES_FILE, spec))
    stacked = [(np.stack([s[k][0] for s in sets]), np.stack([s[k][1] for s in sets]))
               for k in range(len(sets[0]))]
    return Library(root, spec, models, *stacked[0],
                   near=stacked[1] if len(stacked) > 1 else None)

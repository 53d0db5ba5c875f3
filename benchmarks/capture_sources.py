"""Reading a capture's source: its files (a bare git directory at a commit, or a folder) and
its reference cameras (a COLMAP sparse model, an instant-ngp / nerfstudio ``transforms.json``,
an LLFF ``poses_bounds.npy`` or a Middlebury ``*_par.txt``), every camera as OpenCV
camera-to-world with its pinhole intrinsics in the source image's pixels
(``benchmarks.capture_import`` writes them out).
"""

from __future__ import annotations

import io
import json
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".JPG", ".JPEG", ".PNG")
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Camera axes: OpenGL (x right, y up, z back) to OpenCV (x right, y down, z forward)."""


class SourceTree:
    """The files of a source: a bare git directory at ``commit``, or a plain folder."""

    def __init__(self, root: Path, commit: str | None = None) -> None:
        self.root = Path(root)
        self.is_git = (self.root / "HEAD").is_file() and (self.root / "objects").is_dir()
        self.commit = self._resolve(commit or "HEAD") if self.is_git else commit

    def _git(self, *args: str) -> bytes:
        return subprocess.run(["git", f"--git-dir={self.root}", *args], check=True,
                              capture_output=True).stdout

    def _resolve(self, commit: str) -> str:
        return self._git("rev-parse", f"{commit}^{{commit}}").decode().strip()

    def files(self) -> list[str]:
        """Every file's path (posix, relative to the root), sorted."""
        if self.is_git:
            names = self._git("ls-tree", "-r", "--name-only", str(self.commit)).decode()
            return sorted(n for n in names.splitlines() if n)
        return sorted(p.relative_to(self.root).as_posix() for p in self.root.rglob("*")
                      if p.is_file() and ".git" not in p.parts)

    def read(self, path: str) -> bytes:
        """A file's bytes.

        Raises:
            FileNotFoundError: absent (a git snapshot may lack its largest files).
        """
        if self.is_git:
            try:
                return self._git("show", f"{self.commit}:{path}")
            except subprocess.CalledProcessError as exc:
                raise FileNotFoundError(f"{path} is not in {self.root}@{self.commit}") from exc
        return (self.root / path).read_bytes()

    def exists(self, path: str) -> bool:
        """Whether the file is there and readable."""
        try:
            self.read(path)
        except FileNotFoundError:
            return False
        return True


@dataclass(frozen=True)
class Frame:
    """One reference camera: ``image`` (path in the source), ``c2w [4, 4]`` OpenCV,
    ``K [3, 3]`` in the pixels of a ``width`` x ``height`` image, ``distortion``: the model's
    other parameters (not in K), ``seen [P, 5]``: the model's points this camera saw (x, y, z
    in the world, then u, v where it saw them, in pixels; None where the source has none)."""

    image: str
    c2w: np.ndarray
    K: np.ndarray
    width: int
    height: int
    distortion: dict[str, float] = field(default_factory=dict)
    seen: np.ndarray | None = None


def find_model(tree: SourceTree) -> str:
    """The source's reference cameras: the COLMAP model folder with the most images.bin /
    images.txt bytes, else a transforms.json, else a poses_bounds.npy (shortest path first).

    Raises:
        FileNotFoundError: none.
    """
    files = tree.files()
    models = sorted({str(PurePosixPath(f).parent) for f in files
                     if PurePosixPath(f).name in ("images.bin", "images.txt")
                     and tree.exists(f)}, key=lambda m: (m.count("/"), m))
    if models:
        return models[0]
    for name in ("transforms.json", "poses_bounds.npy", "_par.txt"):
        found = sorted((f for f in files if PurePosixPath(f).name == name
                        or (name == "_par.txt" and f.endswith(name))),
                       key=lambda f: (f.count("/"), f))
        if found:
            return found[0]
    raise FileNotFoundError(f"no reference cameras in {tree.root}")


def read_frames(tree: SourceTree, model: str, images: str | None = None) -> list[Frame]:
    """The reference cameras of ``model`` (``find_model``), images as source paths.

    Args:
        tree: the source.
        model: a COLMAP model folder, a transforms.json, a poses_bounds.npy or a Middlebury
            ``*_par.txt``.
        images: the folder of the images (default: ``images`` beside the model's top folder,
            for transforms.json the paths it names).
    """
    name = PurePosixPath(model).name
    if name == "transforms.json":
        return read_transforms(tree, model)
    if name.endswith("_par.txt"):
        return read_middlebury(tree, model)
    if name == "poses_bounds.npy":
        folder = images or str(PurePosixPath(model).parent / "images")
        return read_llff(tree, model, folder.removeprefix("./"))
    return read_colmap(tree, model, images or _images_beside(tree, model))


def _images_beside(tree: SourceTree, model: str) -> str:
    """The ``images`` folder nearest a COLMAP model (``x/sparse/0`` -> ``x/images``)."""
    parts = PurePosixPath(model).parts
    files = set(tree.files())
    for cut in range(len(parts), -1, -1):
        folder = PurePosixPath(*parts[:cut], "images") if cut else PurePosixPath("images")
        if any(f.startswith(f"{folder}/") for f in files):
            return str(folder)
    raise FileNotFoundError(f"no images folder near {model}")


def read_colmap(tree: SourceTree, model: str, images: str) -> list[Frame]:
    """The registered images of a COLMAP model (any camera model: its focal lengths and
    principal point in K, the rest in ``distortion``)."""
    import pycolmap

    with tempfile.TemporaryDirectory(prefix="capture_model_") as work:
        for part in ("cameras", "images", "points3D", "frames", "rigs"):
            for suffix in (".bin", ".txt"):
                path = f"{model}/{part}{suffix}"
                if tree.exists(path):
                    (Path(work) / f"{part}{suffix}").write_bytes(tree.read(path))
        reconstruction = pycolmap.Reconstruction(work)
    frames = []
    for image in sorted(reconstruction.images.values(), key=lambda im: im.name):
        if not image.has_pose:
            continue
        camera = reconstruction.cameras[image.camera_id]
        w2c = np.eye(4)
        pose = image.cam_from_world
        w2c[:3, :4] = (pose() if callable(pose) else pose).matrix()
        K = np.asarray(camera.calibration_matrix(), dtype=np.float64)
        names = camera.params_info.split(", ")
        extra = {n: float(v) for n, v in zip(names, camera.params, strict=True)
                 if n not in ("f", "fx", "fy", "cx", "cy")}
        # COLMAP puts pixel centres at half-integers, OpenCV (and this project) at integers.
        K[0, 2] -= 0.5
        K[1, 2] -= 0.5
        seen = np.array([[*reconstruction.points3D[p.point3D_id].xyz, *(p.xy - 0.5)]
                         for p in image.points2D if p.has_point3D()]).reshape(-1, 5)
        frames.append(Frame(f"{images}/{image.name}", np.linalg.inv(w2c), K,
                            int(camera.width), int(camera.height), extra, seen))
    return frames


def read_transforms(tree: SourceTree, path: str) -> list[Frame]:
    """The frames of an instant-ngp / nerfstudio ``transforms.json`` (OpenGL camera axes;
    intrinsics per frame or shared: ``fl_x``/``fl_y``/``cx``/``cy``/``w``/``h``, else
    ``camera_angle_x`` with the image's own size)."""
    data = json.loads(tree.read(path))
    base = PurePosixPath(path).parent
    frames = []
    for entry in data["frames"]:
        spec = {**data, **entry}
        image = str(PurePosixPath(base, entry["file_path"].removeprefix("./")))
        if not PurePosixPath(image).suffix:
            image = next(f for f in tree.files() if f.startswith(image + "."))
        width, height = _size(tree, image) if "w" not in spec else (spec["w"], spec["h"])
        fx = spec.get("fl_x", 0.5 * width / np.tan(0.5 * spec.get("camera_angle_x", 1.0)))
        fy = spec.get("fl_y", fx)
        K = np.array([[fx, 0.0, spec.get("cx", width / 2.0)],
                      [0.0, fy, spec.get("cy", height / 2.0)], [0.0, 0.0, 1.0]])
        extra = {k: float(spec[k]) for k in ("k1", "k2", "k3", "k4", "p1", "p2")
                 if float(spec.get(k, 0.0)) != 0.0}
        c2w = np.asarray(entry["transform_matrix"], dtype=np.float64) @ OPENGL_TO_OPENCV
        frames.append(Frame(image, c2w, K, int(width), int(height), extra))
    return frames


def read_llff(tree: SourceTree, path: str, images: str) -> list[Frame]:
    """The frames of an LLFF ``poses_bounds.npy``: rows [R | t | (h, w, f)] with columns
    (down, right, back), one per image of ``images`` in sorted name order (as LLFF's
    ``imgs2poses`` writes them); principal point at the centre.

    Raises:
        ValueError: the file has not one row per image (unregistered images: the order is
            then unknown).
    """
    rows = np.load(io.BytesIO(tree.read(path)), allow_pickle=False)
    names = sorted(f for f in tree.files() if f.startswith(f"{images}/")
                   and "/" not in f[len(images) + 1:] and f.endswith(IMAGE_SUFFIXES))
    if len(rows) != len(names):
        raise ValueError(f"{path}: {len(rows)} poses for {len(names)} images in {images}/")
    frames = []
    for row, name in zip(rows, names, strict=True):
        pose = row[:15].reshape(3, 5)
        height, width, focal = pose[:, 4]
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([pose[:, 1], pose[:, 0], -pose[:, 2]], axis=1)
        c2w[:3, 3] = pose[:, 3]
        K = np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0, 0, 1.0]])
        frames.append(Frame(name, c2w, K, round(width), round(height)))
    return frames


def read_middlebury(tree: SourceTree, path: str) -> list[Frame]:
    """The frames of a Middlebury multi-view ``*_par.txt`` (a count, then per image: its name,
    K row-major, R row-major, t; ``x = K (R X + t)``), images beside it."""
    lines = tree.read(path).decode().split("\n")[1:]
    base = PurePosixPath(path).parent
    frames = []
    for line in (line.split() for line in lines if line.strip()):
        values = np.array([float(v) for v in line[1:]])
        w2c = np.eye(4)
        w2c[:3, :3] = values[9:18].reshape(3, 3)
        w2c[:3, 3] = values[18:21]
        image = str(base / line[0])
        width, height = _size(tree, image)
        frames.append(Frame(image, np.linalg.inv(w2c), values[:9].reshape(3, 3), width, height))
    return frames


def _size(tree: SourceTree, image: str) -> tuple[int, int]:
    from PIL import Image

    with Image.open(io.BytesIO(tree.read(image))) as opened:
        return opened.size


def describe(tree: SourceTree) -> dict[str, Any]:
    """Where the source is: its root and commit (None for a folder)."""
    return {"root": str(tree.root), "commit": tree.commit}

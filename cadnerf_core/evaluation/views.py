"""A finished job rendered at any cameras, as nerfstudio's ``ns-render`` renders its models.

The cameras come from a file other tools write: a ``transforms.json`` (nerfstudio's or the
NeRF-synthetic layout: OpenGL camera axes, per-frame or shared ``fl_x``/``fl_y``/``cx``/``cy``/
``w``/``h``, else ``camera_angle_x`` and the frame's image size) or a COLMAP text model
(``cameras.txt`` and ``images.txt``, any distortion left out). They must be in the job's own
frame, the one its ``transforms.json`` and ``sparse/0/`` are written in (the object centred at
the origin inside the unit sphere, +Y up). Each view is rendered from the trained field or
from the exported textured mesh (``mesh.glb``).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cadnerf_core.cameras import CV_TO_GL
from cadnerf_core.errors import InputError

if TYPE_CHECKING:
    from cadnerf_core.progress import Progress

log = logging.getLogger(__name__)

Source = Literal["field", "mesh"]


@dataclass(frozen=True)
class View:
    """One camera to render: a name for its file, pose and intrinsics."""

    name: str  # file stem of its render
    c2w: np.ndarray  # [4, 4] OpenCV camera-to-world, in the job's frame
    K: np.ndarray  # [3, 3] in pixels of a width x height image
    width: int
    height: int

    def at_size(self, size: int | None) -> View:
        """The same camera rendering ``size`` pixels on its longer side (None: unchanged)."""
        if size is None or size == max(self.width, self.height):
            return self
        width = max(1, round(self.width * size / max(self.width, self.height)))
        height = max(1, round(self.height * size / max(self.width, self.height)))
        K = np.array(self.K, dtype=np.float64, copy=True)
        K[0] *= width / self.width  # pixel edges at integers: K's rows scale as the sides
        K[1] *= height / self.height
        return replace(self, K=K, width=width, height=height)


def _image_size(folder: Path, frame: dict[str, Any]) -> tuple[int, int] | None:
    """(width, height) of a frame's image beside the cameras file, None without one."""
    from PIL import Image

    if "file_path" not in frame:
        return None
    path = folder / str(frame["file_path"])
    path = path if path.is_file() else path.with_name(path.name + ".png")
    if not path.is_file():
        return None
    with Image.open(path) as image:
        return image.size


def _transforms_view(folder: Path, shared: dict[str, Any], frame: dict[str, Any], index: int,
                     size: int | None) -> View:
    """One frame of a transforms file (``shared``: the file's top-level keys)."""
    merged = {**shared, **frame}
    found = (int(merged["w"]), int(merged["h"])) if "w" in merged and "h" in merged \
        else _image_size(folder, frame)
    if found is None:
        if size is None:
            raise InputError(f"frame {index} has no image size (w, h) nor an image beside the "
                             "file", hint="give the size to render at (--size)")
        found = (size, size)
    width, height = found
    if "fl_x" in merged:
        fx = float(merged["fl_x"])
        fy = float(merged.get("fl_y", fx))
    else:
        fx = fy = 0.5 * width / math.tan(0.5 * float(merged["camera_angle_x"]))
    K = np.array([[fx, 0.0, float(merged.get("cx", width / 2))],
                  [0.0, fy, float(merged.get("cy", height / 2))], [0.0, 0.0, 1.0]])
    c2w = np.asarray(frame["transform_matrix"], dtype=np.float64) @ CV_TO_GL
    stem = Path(str(frame.get("file_path", ""))).stem or f"{index:03d}"
    return View(stem, c2w, K, width, height)


def _read_transforms(path: Path, size: int | None) -> list[View]:
    data = json.loads(path.read_text())
    shared = {k: v for k, v in data.items() if k != "frames"}
    return [_transforms_view(path.parent, shared, frame, i, size)
            for i, frame in enumerate(data["frames"])]


def _read_colmap(folder: Path) -> list[View]:
    from cadnerf_core.export.colmap import read_colmap_text

    cameras = read_colmap_text((folder / "cameras.txt").read_text(),
                               (folder / "images.txt").read_text())
    return [View(Path(c.name).stem, c.c2w, c.K, c.width, c.height) for c in cameras]


def read_views(path: Path, size: int | None = None) -> list[View]:
    """The cameras of a ``transforms.json`` or of a COLMAP text model.

    Args:
        path: a transforms file; a folder holding ``cameras.txt`` and ``images.txt`` (a
            ``sparse/0`` folder) or one of those two files; or a folder holding a
            ``transforms.json`` or a ``sparse/0`` (a job's, nerfstudio's data).
        size: longer side to render at (None: each camera's own size).
    Returns:
        The views, in the file's order (names made unique).
    Raises:
        InputError: no cameras there, or a file that does not parse.
    """
    path = Path(path)
    if path.is_file() and path.name in ("cameras.txt", "images.txt"):
        path = path.parent
    if path.is_dir() and not (path / "images.txt").is_file():
        # A folder others write (a job's, nerfstudio's data): its transforms.json, else its
        # COLMAP model.
        if (path / "transforms.json").is_file():
            path = path / "transforms.json"
        elif (path / "sparse" / "0" / "images.txt").is_file():
            path = path / "sparse" / "0"
    try:
        if path.is_dir() and (path / "images.txt").is_file():
            views = _read_colmap(path)
        elif path.is_file():
            views = _read_transforms(path, size)
        else:
            raise InputError("no transforms.json or COLMAP cameras.txt and images.txt there",
                             item=str(path))
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise InputError(f"not a cameras file ({type(exc).__name__}: {exc})",
                         item=str(path)) from None
    if not views:
        raise InputError("the file holds no cameras", item=str(path))
    seen: set[str] = set()
    unique = []
    for i, view in enumerate(views):
        name = view.name if view.name not in seen else f"{view.name}_{i:03d}"
        seen.add(name)
        unique.append(replace(view, name=name).at_size(size))
    return unique


def job_renderer(job_dir: Path, source: Source = "field", device: str = "auto",
                 ) -> Callable[[View], tuple[np.ndarray, np.ndarray]]:
    """A function rendering a finished job at one view, on white.

    Args:
        job_dir: the job folder (its last checkpoint for "field", ``mesh.glb`` for "mesh").
        source: "field" (the trained NeRF) or "mesh" (the exported textured mesh, its baked
            colours shown as they are, unlit).
        device: for the field ("auto", "cpu", "cuda").
    Returns:
        view -> (rgb [H, W, 3] float32 in [0, 1], coverage [H, W] float32 in [0, 1]).
    Raises:
        InputError: the job has no checkpoint, or no mesh.
    """
    from cadnerf_core.jobfolder import MESH, JobFolder

    if source == "mesh":
        from cadnerf_core.mesh.meshio import load_mesh
        from cadnerf_core.mesh.renderer import MeshRenderer

        path = JobFolder(job_dir).file(MESH)
        if not path.is_file():
            raise InputError("the job has no mesh (it has not finished)", item=str(path))
        renderer = MeshRenderer(load_mesh(path), lit=False)

        def mesh_view(view: View) -> tuple[np.ndarray, np.ndarray]:
            out = renderer.render(view.K, view.c2w, view.width, view.height, background=1.0)
            return out.rgb, out.mask.astype(np.float32)

        return mesh_view
    if source != "field":
        raise ValueError(f"source must be 'field' or 'mesh', not {source!r}")
    from cadnerf_core.nerf.model import TrainedModel

    try:
        model = TrainedModel.load(job_dir, device)
    except FileNotFoundError as exc:
        raise InputError(f"{exc} (the job has not trained)", item=str(job_dir)) from None

    def field_view(view: View) -> tuple[np.ndarray, np.ndarray]:
        return model.render_image(view.c2w, view.K, view.width, view.height, background=1.0)

    return field_view


def render_views(job_dir: Path, views: list[View], out_dir: Path, source: Source = "field",
                 device: str = "auto", progress: Progress | None = None) -> list[Path]:
    """Render a finished job at each view into ``out_dir/<name>.png``.

    Args:
        job_dir: the job folder; views: from ``read_views``; out_dir: created.
        source, device: see ``job_renderer``.
        progress: reports stage "render" after each view.
    Returns:
        The PNG files written, in the views' order.
    Raises:
        InputError: see ``job_renderer``.
    """
    from cadnerf_core.export.media import write_png

    render = job_renderer(job_dir, source, device)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for i, view in enumerate(views):
        rgb, _ = render(view)
        path = out_dir / f"{view.name}.png"
        write_png(path, rgb)
        written.append(path)
        if progress is not None:
            progress.step("render", i + 1, len(views))
    log.info("rendered %d views of %s from its %s into %s", len(views), job_dir, source,
             out_dir)
    return written

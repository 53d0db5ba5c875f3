"""The capture benchmark's captures: where they are, how they load, and the users' spacing.

Two roots hold captures in one layout (``images/NNN.jpg`` in walking order, ``masks/`` where
shipped, ``cameras.json``: per frame OpenCV ``c2w`` and ``K`` in the image's pixels):
``../shared/eval/captures`` (dense captures kept with the evaluation set) and
``<repo>/data/captures`` (git-ignored; made by ``benchmarks.capture_import`` from the sources
``benchmarks/captures_sources.md`` lists). Either may be absent.

Two sets are benchmarked. **Users'**: photos 30 to 60 degrees apart, as users take them: every
capture of ``data/captures`` (imported at that spacing) and each dense capture's frames
subsampled to it where they allow (``users_capture``: ``capture_spacing.choose_walk`` on its
reference cameras). **Dense**: the captures of ``../shared/eval/captures`` as they are, and the
espresso phone photos.
"""

from __future__ import annotations

import json
import logging
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.capture_spacing import (
    USERS,
    WalkSpec,
    choose_walk,
    object_centre,
    rays_from,
    ring_angles,
    spacing_deg,
    up_axis,
)
from benchmarks.harness import CAPTURES, PHOTOS, ROOT

log = logging.getLogger("benchmarks.captures")

LOCAL_CAPTURES = ROOT / "data" / "captures"
"""Captures imported by ``benchmarks.capture_import`` (git-ignored)."""
SETS = ("users", "dense", "textured")
"""The benchmark's sets: the users' spacing (the headline), the dense captures, the textured
synthetic walks."""


@dataclass(frozen=True)
class Capture:
    """One capture: photos in walking order, their masks (None: the job makes them), the
    reference cameras [N, 4, 4] (OpenCV c2w) and focal lengths [N] in photo pixels (None
    where unknown)."""

    name: str
    photos: list[Path]
    masks: list[Path] | None
    c2w: np.ndarray
    focal: np.ndarray | None
    overrides: dict[str, Any] = field(default_factory=dict)
    """Configuration values the job gets besides the preset's and the variant's."""
    exif_35mm: float | None = None
    """The 35 mm-equivalent focal length the photos' EXIF would give (``cameras.json``
    ``focal_35mm``), passed to the job as ``retrieval.focal_35mm``; None: no EXIF."""
    frames: tuple[int, ...] = ()
    """Where the photos are a subsample of a dense capture: its frames taken, else empty."""

    @property
    def spacing(self) -> float:
        """Median angle between neighbouring photos seen from the object (degrees)."""
        return spacing_deg(self.c2w) if len(self.c2w) > 1 else float("nan")


def capture_folder(name: str) -> Path:
    """The folder of capture ``name``: ``data/captures`` first, then the shared one."""
    local = LOCAL_CAPTURES / name
    return local if (local / "cameras.json").is_file() else CAPTURES / name


def load_capture(name: str, folder: Path | None = None) -> Capture:
    """A capture's folder (``cameras.json``: frames with image, K, c2w; default
    ``capture_folder(name)``) or the espresso photos (``../shared/eval/photos``, metadata
    azimuth and elevation)."""
    if name == "ners_espresso":
        from benchmarks.retrieval_real import real_set_photos

        photos, masks, truth = real_set_photos(name)
        assert truth is not None
        return Capture(name, photos, masks, truth, None)
    folder = folder or capture_folder(name)
    data = json.loads((folder / "cameras.json").read_text())
    frames = data["frames"]
    photos = [folder / f["image"] for f in frames]
    masks = [folder / "masks" / f"{Path(f['image']).stem}.png" for f in frames]
    c2w = np.array([f["c2w"] for f in frames], dtype=np.float64)
    flipped = [k for k, f in enumerate(frames) if f.get("upside_down_by_design")]
    has_masks = all(m.is_file() for m in masks)
    if flipped:
        photos, masks, c2w = upright(name, photos, masks if has_masks else None, c2w, flipped)
    exif = data.get("focal_35mm")
    return Capture(name, photos, masks if has_masks else None, c2w,
                   np.array([f["K"][0][0] for f in frames], dtype=np.float64),
                   {} if exif is None else {"retrieval.focal_35mm": float(exif)},
                   None if exif is None else float(exif))


def upright(name: str, photos: list[Path], masks: list[Path] | None, c2w: np.ndarray,
            flipped: list[int]) -> tuple[list[Path], list[Path], np.ndarray]:
    """The capture as a phone saves it: frames a camera rig took upside down (a gantry's
    ``upside_down_by_design``) turned upright, as a phone's orientation tag turns its photos
    (``intake.photos`` applies it), their reference cameras rolled half a turn about the
    optical axis to match. The turned copies go to a temporary folder."""
    import cv2

    work = Path(tempfile.gettempdir()) / "cadnerf_bench_upright" / name
    work.mkdir(parents=True, exist_ok=True)
    photos, masks = list(photos), list(masks or [])
    c2w = c2w.copy()
    roll = np.diag([-1.0, -1.0, 1.0, 1.0])  # half a turn about the camera's z axis
    for k in flipped:
        for files, suffix in ((photos, "photo"), (masks, "mask")):
            if not files:
                continue
            image = cv2.imread(str(files[k]), cv2.IMREAD_UNCHANGED)
            assert image is not None, f"cannot read {files[k]}"
            turned = work / f"{k:03d}_{suffix}{files[k].suffix}"
            cv2.imwrite(str(turned), cv2.rotate(image, cv2.ROTATE_180))
            files[k] = turned
        c2w[k] = c2w[k] @ roll
    return photos, masks, c2w


def textured_capture(name: str, work: Path) -> Capture:
    """A textured synthetic walk of mesh ``name`` (``textured_walks``), rendered into ``work``,
    its focal length given as a phone's EXIF gives it."""
    from benchmarks.textured_walks import phone_focal_35mm, render_walk

    photos, masks, c2w = render_walk(name, work / name)
    exif = round(phone_focal_35mm(), 2)
    return Capture(name, photos, masks, c2w, None, {"retrieval.focal_35mm": exif}, exif)


def walk_of(c2w: np.ndarray, spec: WalkSpec = USERS) -> list[int]:
    """The frames of reference cameras ``c2w`` [N, 4, 4] (in walking order) a walk at
    ``spec``'s spacing takes (``choose_walk``), in walking order."""
    centre = object_centre(c2w)
    azimuth, elevation = ring_angles(c2w, centre, up_axis(c2w))
    return choose_walk(azimuth, elevation, spec, rays_from(c2w, centre))


def users_capture(capture: Capture, spec: WalkSpec = USERS) -> Capture | None:
    """The capture at the users' spacing: its frames a walk takes (``walk_of``; all of them
    where they already stand so), None where its frames allow no walk."""
    frames = walk_of(capture.c2w, spec)
    if not frames:
        return None
    if sorted(frames) == list(range(len(capture.photos))):
        frames = list(range(len(capture.photos)))  # already a walk: keep the given order
    return replace(capture, photos=[capture.photos[k] for k in frames],
                   masks=None if capture.masks is None else [capture.masks[k] for k in frames],
                   c2w=capture.c2w[frames],
                   focal=None if capture.focal is None else capture.focal[frames],
                   frames=tuple(frames))


def _names(root: Path) -> list[str]:
    return sorted(p.name for p in root.iterdir() if (p / "cameras.json").is_file()) \
        if root.is_dir() else []


def dense_names() -> list[str]:
    """The dense captures (``../shared/eval/captures``), then the espresso photos."""
    names = _names(CAPTURES)
    if (PHOTOS / "ners_espresso").is_dir():
        names.append("ners_espresso")
    return names


def capture_names() -> list[str]:
    """Every capture of either root, then the espresso photos (``bench_pairs``' captures)."""
    local = _names(LOCAL_CAPTURES)
    return [*local, *(n for n in dense_names() if n not in local)]


def users_captures(names: list[str] | None = None) -> list[Capture]:
    """The users' set: the imported captures, then each dense capture subsampled where its
    frames allow (``users_capture``; the espresso photos' coarse metadata is no reference for
    this set); ``names`` restricts it."""
    found = []
    local = _names(LOCAL_CAPTURES)
    for name in local:
        if names is None or name in names:
            found.append(load_capture(name, LOCAL_CAPTURES / name))
    for name in _names(CAPTURES):
        if name in local or (names is not None and name not in names):
            continue
        walk = users_capture(load_capture(name, CAPTURES / name))
        if walk is None:
            log.info("%s: its frames allow no walk at the users' spacing", name)
        else:
            found.append(walk)
    return found


def dense_captures(names: list[str] | None = None) -> list[Capture]:
    """The dense set (``dense_names``; ``names`` restricts it)."""
    return [load_capture(name, None if name == "ners_espresso" else CAPTURES / name)
            for name in dense_names() if names is None or name in names]

"""Import a real capture as users take it: a few photos walking round the object.

A source (a bare git directory at a commit, or a plain folder of a clone) holds a dense
capture of one object (tens or hundreds of frames) and its reference cameras over all of
them (COLMAP, instant-ngp / nerfstudio ``transforms.json`` or LLFF ``poses_bounds.npy``:
``benchmarks.capture_sources``). This picks the frames a user would have taken, 30 to 60
degrees apart round the object by the reference cameras' azimuth
(``capture_spacing.choose_walk``), and writes them in the layout of
``../shared/eval/captures/<name>/``:

- ``images/NNN.jpg`` in walking order, no EXIF, turned upright as a phone's orientation
  sensor turns its photos (the world's up toward the image's top: the camera rolled with
  it), at most ``MAX_SIDE`` pixels on the long side;
- ``masks/NNN.png`` where the source has masks (white: the object);
- ``cameras.json``: per photo OpenCV ``c2w`` and ``K`` in the saved image's pixels, the
  source frame, azimuth and elevation, the distortion the source's camera model has beyond
  K; the 35 mm-equivalent focal length a phone's EXIF would give (``focal_35mm``);
- ``README.md``: source, commit, licence, frames, caveats.

Usage: ``python -m benchmarks.capture_import --git-dir DIR --name NAME --out data/captures
--source OWNER/REPO --licence TEXT [--model PATH] [--images DIR] [--masks DIR]``.
"""

from __future__ import annotations

import argparse
import io
import json
import logging
import math
import sys
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
from PIL import Image

from benchmarks.capture_sources import Frame, SourceTree, find_model, read_frames
from benchmarks.capture_spacing import (
    WalkSpec,
    choose_walk,
    object_centre,
    rays_from,
    ring_angles,
    up_axis,
    view_angles,
)

log = logging.getLogger("benchmarks.capture_import")

MAX_SIDE = 2000
"""Photos with a longer side than this are shrunk to ``SHRUNK_SIDE`` (a phone-like size)."""
SHRUNK_SIDE = 1600
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
CONVENTION = ("OpenCV camera axes (x right, y down, z forward), c2w = camera-to-world 4x4, "
              "K in pixels of the saved image")


def quarter_turns(c2w: np.ndarray, up: np.ndarray) -> int:
    """Clockwise quarter turns that bring the world's ``up`` [3] nearest the top of the image
    of camera ``c2w`` [4, 4] (what a phone's orientation sensor does)."""
    x, y = (c2w[:3, :3].T @ up)[:2]  # up in camera axes; the image's top is -y
    angle = math.degrees(math.atan2(x, -y))  # 0: up is the image's top; 90: its right
    return int(round(-angle / 90.0)) % 4


def turn_clockwise(image: np.ndarray, c2w: np.ndarray,
                   K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The image [H, W, ...] turned a quarter clockwise, the camera rolled with it and its
    intrinsics in the turned image's pixels."""
    height = image.shape[0]
    turned = np.ascontiguousarray(np.rot90(image, k=-1))
    c2w = c2w.copy()
    c2w[:3, :2] = np.stack([-c2w[:3, 1], c2w[:3, 0]], axis=1)  # x' = -y, y' = x
    K = np.array([[K[1, 1], 0.0, height - 1.0 - K[1, 2]], [0.0, K[0, 0], K[0, 2]],
                  [0.0, 0.0, 1.0]])
    return turned, c2w, K


def scaled_intrinsics(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Intrinsics of an image resampled by (sx, sy), pixel centres at integers."""
    out = K.copy()
    out[0, 0] *= sx
    out[1, 1] *= sy
    out[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    out[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return out


def focal_35mm(K: np.ndarray, width: int, height: int) -> float:
    """The 35 mm-equivalent focal length (the diagonal rule, as ``intake.photos`` reads EXIF)."""
    focal = 0.5 * (K[0, 0] + K[1, 1])
    return float(focal * FULL_FRAME_DIAGONAL_MM / math.hypot(width, height))


def find_mask(files: list[str], masks: str, image: str) -> str | None:
    """The mask of ``image`` in folder ``masks``: the file whose name is the image's stem, or
    its stem followed by a separator (``1-removebg-preview.png`` for ``1.jpg``)."""
    stem = PurePosixPath(image).stem
    for path in files:
        if not path.startswith(f"{masks}/"):
            continue
        name = PurePosixPath(path).name
        if PurePosixPath(name).stem == stem or (name.startswith(stem)
                                                 and name[len(stem)] in "-_."):
            return path
    return None


def read_mask(data: bytes, size: tuple[int, int]) -> np.ndarray:
    """A mask file as bool [H, W] at ``size`` (width, height): alpha where it has one, else
    grey above half."""
    with Image.open(io.BytesIO(data)) as opened:
        band = opened.getchannel("A") if "A" in opened.getbands() else opened.convert("L")
        band = band.resize(size, Image.Resampling.NEAREST) if band.size != size else band
        return np.asarray(band) > 127


def reprojection_px(seen: np.ndarray | None, c2w: np.ndarray, K: np.ndarray) -> float | None:
    """Median distance (pixels) between where camera (c2w, K) projects the points a frame saw
    (``Frame.seen``, their pixels carried into the same image) and where it saw them."""
    if seen is None or not len(seen):
        return None
    w2c = np.linalg.inv(c2w)
    projected = (K @ (w2c[:3, :3] @ seen[:, :3].T + w2c[:3, 3:])).T
    return float(np.median(np.linalg.norm(projected[:, :2] / projected[:, 2:] - seen[:, 3:],
                                          axis=1)))


def photo(tree: SourceTree, frame: Frame, up: np.ndarray, mask_path: str | None,
          max_side: int = MAX_SIDE) -> tuple[np.ndarray, np.ndarray | None, np.ndarray,
                                             np.ndarray, int, float | None]:
    """One frame as a user's photo: RGB [H, W, 3] uint8 upright, its mask (None without),
    c2w, K in its pixels, the quarter turns applied, and the median reprojection error in its
    pixels of the source's points it saw (``reprojection_px``; None without points).

    Raises:
        ValueError: the image's size is not the camera's (or a uniform scale of it).
    """
    with Image.open(io.BytesIO(tree.read(frame.image))) as opened:
        rgb = np.asarray(opened.convert("RGB"))  # raw pixels, as COLMAP saw them: no EXIF turn
    height, width = rgb.shape[:2]
    sx, sy = width / frame.width, height / frame.height
    if abs(sx - sy) > 0.01 * max(sx, sy):
        raise ValueError(f"{frame.image}: {width}x{height} is not a scale of the camera's "
                         f"{frame.width}x{frame.height}")
    K = scaled_intrinsics(frame.K, sx, sy)
    c2w = frame.c2w.copy()
    seen = None if frame.seen is None else frame.seen.copy()
    if seen is not None:
        seen[:, 3:] = (seen[:, 3:] + 0.5) * (sx, sy) - 0.5
    mask = None if mask_path is None else read_mask(tree.read(mask_path), (width, height))
    turns = quarter_turns(c2w, up)
    for _ in range(turns):
        if seen is not None:  # the pixels go where the turn takes them: (u, v) -> (H-1-v, u)
            seen[:, 3:] = np.stack([rgb.shape[0] - 1.0 - seen[:, 4], seen[:, 3]], axis=1)
        rotated, c2w, K = turn_clockwise(rgb, c2w, K)
        mask = None if mask is None else np.ascontiguousarray(np.rot90(mask, k=-1))
        rgb = rotated
    height, width = rgb.shape[:2]
    if max(width, height) > max_side:
        scale = SHRUNK_SIDE / max(width, height)
        size = (round(width * scale), round(height * scale))
        rgb = np.asarray(Image.fromarray(rgb).resize(size, Image.Resampling.LANCZOS))
        if mask is not None:
            mask = np.asarray(Image.fromarray(mask).resize(size, Image.Resampling.NEAREST))
        K = scaled_intrinsics(K, size[0] / width, size[1] / height)
        if seen is not None:
            seen[:, 3:] = (seen[:, 3:] + 0.5) * (size[0] / width, size[1] / height) - 0.5
    return rgb, mask, c2w, K, turns, reprojection_px(seen, c2w, K)


def walk_frames(frames: list[Frame], spec: WalkSpec) -> tuple[list[int], dict[str, Any]]:
    """The frames of a walk (``choose_walk``) and where the cameras stand (centre, up,
    azimuths and elevations of all frames)."""
    c2w = np.stack([f.c2w for f in frames])
    centre, up = object_centre(c2w), up_axis(c2w)
    azimuth, elevation = ring_angles(c2w, centre, up)
    chosen = choose_walk(azimuth, elevation, spec, rays_from(c2w, centre))
    return chosen, {"centre": centre, "up": up, "azimuth": azimuth, "elevation": elevation}


def write_photo(tree: SourceTree, frame: Frame, folder: Path, k: int, stand: dict[str, Any],
                index: int, mask_path: str | None) -> dict[str, Any]:
    """Write frame ``index`` as the capture's photo ``k`` (and its mask where it has one).
    Returns its ``cameras.json`` entry."""
    rgb, mask, c2w, K, turns, error = photo(tree, frame, stand["up"], mask_path)
    Image.fromarray(rgb).save(folder / "images" / f"{k:03d}.jpg", quality=95)
    entry: dict[str, Any] = {
        "image": f"images/{k:03d}.jpg", "K": K.tolist(), "c2w": c2w.tolist(),
        "width": int(rgb.shape[1]), "height": int(rgb.shape[0]), "source_image": frame.image,
        "azimuth_deg": round(float(stand["azimuth"][index]), 2),
        "elevation_deg": round(float(stand["elevation"][index]), 2), "quarter_turns": turns,
        **({"distortion": frame.distortion} if frame.distortion else {}),
        **({} if error is None else {"reprojection_px": round(error, 3)})}
    if mask is not None:
        (folder / "masks").mkdir(exist_ok=True)
        Image.fromarray(mask.astype(np.uint8) * 255).save(folder / "masks" / f"{k:03d}.png")
        entry["mask"] = f"masks/{k:03d}.png"
        entry["source_mask"] = mask_path
    return entry


def import_capture(tree: SourceTree, name: str, out: Path, meta: dict[str, str],
                   model: str | None = None, images: str | None = None,
                   masks: str | None = None, spec: WalkSpec | None = None) -> Path:
    """Write the capture ``name`` under ``out`` (the module's layout).

    Args:
        tree: the source.
        name: the capture's folder name.
        out: where captures go (``data/captures``).
        meta: ``source`` (owner/repo or URL), ``licence``, ``object`` (what it shows),
            ``caveats`` (free text; may be empty).
        model, images, masks: the reference cameras, the images' folder and the masks'
            folder in the source (None: found, found, none).
        spec: the walk's spacing (default: the users').
    Returns:
        The capture's folder.
    Raises:
        ValueError: no walk fits the frames.
    """
    model = model or find_model(tree)
    frames = [f for f in read_frames(tree, model, images) if tree.exists(f.image)]
    chosen, stand = walk_frames(frames, spec or WalkSpec())
    if not chosen:
        raise ValueError(f"{name}: no walk at the users' spacing fits the {len(frames)} frames")
    folder = out / name
    (folder / "images").mkdir(parents=True, exist_ok=True)
    files = tree.files()
    written = [write_photo(tree, frames[index], folder, k, stand, index,
                           None if masks is None else find_mask(files, masks, frames[index].image))
               for k, index in enumerate(chosen)]
    c2w_all = np.array([e["c2w"] for e in written])
    gaps = view_angles(c2w_all, stand["centre"])
    focal = float(np.median([focal_35mm(np.array(e["K"]), e["width"], e["height"])
                             for e in written]))
    cameras = {"convention": CONVENTION, "source": _source_line(tree, meta, model),
               "focal_35mm": round(focal), "object_centre_world": stand["centre"].tolist(),
               "up_world": stand["up"].tolist(), "reference_frames": len(frames),
               "frames": written}
    (folder / "cameras.json").write_text(json.dumps(cameras, indent=1) + "\n")
    (folder / "README.md").write_text(readme(name, tree, meta, model, len(frames), written,
                                             gaps, round(focal), masks))
    log.info("%s: %d photos of %d frames, %s deg apart", name, len(written), len(frames),
             ", ".join(f"{g:.0f}" for g in gaps))
    return folder


def _source_line(tree: SourceTree, meta: dict[str, str], model: str) -> str:
    return f"{meta['source']}@{tree.commit or 'folder'}:{model}"


def readme(name: str, tree: SourceTree, meta: dict[str, str], model: str, total: int,
           frames: list[dict[str, Any]], gaps: np.ndarray, focal: int,
           masks: str | None) -> str:
    """The capture's README (source, licence, frames, caveats)."""
    picked = ", ".join(f"{PurePosixPath(f['source_image']).name} ({f['azimuth_deg']:.0f} deg)"
                       for f in frames)
    turned = sorted({f["quarter_turns"] for f in frames} - {0})
    lines = [f"# {name} - {meta['object']}, {len(frames)} photos at the users' spacing", "",
             f"- Source: {meta['source']} at commit {tree.commit or '(a folder)'}; reference "
             f"cameras {model} over {total} frames.",
             f"- Licence: {meta['licence']}.",
             f"- Frames (walking order, azimuth about the object's centre): {picked}.",
             f"- Neighbours {', '.join(f'{g:.0f}' for g in gaps)} degrees apart as seen from "
             f"the object's centre (median {np.median(gaps):.0f}).",
             "- Cameras: OpenCV c2w and K in the saved image's pixels (principal point and "
             "scale carried through the resize); the source camera model's distortion beyond "
             "K is listed per frame, not applied. Scale and frame of the world arbitrary.",
             f"- focal_35mm {focal}: what a phone's EXIF would say (35 mm equivalent from the "
             "reference K, whole millimetres).",
             "- Photos saved without EXIF" + (
                 f"; turned {turned} quarter turn(s) clockwise so the world's up is the "
                 "image's top, as a phone's orientation sensor turns them (cameras rolled "
                 "with them)." if turned else "; already upright."),
             f"- Masks: {'from the source folder ' + masks if masks else 'none in the source'}."]
    errors = [f["reprojection_px"] for f in frames if "reprojection_px" in f]
    if errors:
        lines.append("- Validation: the source model's points reproject into the saved photos "
                     f"at a median {np.median(errors):.2f} px (per photo "
                     f"{min(errors):.2f}-{max(errors):.2f}; distortion beyond K unmodelled).")
    if meta.get("caveats"):
        lines.append(f"- Caveats: {meta['caveats']}")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Import one capture."""
    parser = argparse.ArgumentParser(description="Import a capture at the users' spacing")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--git-dir", type=Path, help="a bare git directory (a fetched mirror)")
    where.add_argument("--folder", type=Path, help="a plain folder (a clone)")
    parser.add_argument("--commit", default=None, help="the git commit (default HEAD)")
    parser.add_argument("--name", required=True)
    parser.add_argument("--out", type=Path, default=Path("data/captures"))
    parser.add_argument("--source", required=True, help="owner/repo, as cited")
    parser.add_argument("--licence", required=True)
    parser.add_argument("--object", default="an object")
    parser.add_argument("--caveats", default="")
    parser.add_argument("--model", default=None, help="reference cameras in the source")
    parser.add_argument("--images", default=None, help="the images' folder in the source")
    parser.add_argument("--masks", default=None, help="the masks' folder in the source")
    parser.add_argument("--high-deg", type=float, default=WalkSpec().high_deg)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    tree = SourceTree(args.git_dir or args.folder, args.commit)
    meta = {"source": args.source, "licence": args.licence, "object": args.object,
            "caveats": args.caveats}
    import_capture(tree, args.name, args.out, meta, args.model, args.images, args.masks,
                   WalkSpec(high_deg=args.high_deg))
    return 0


if __name__ == "__main__":
    sys.exit(main())

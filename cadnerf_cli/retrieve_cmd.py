"""``cadnerf retrieve``: the CAD model and a camera pose for every photo, without training."""

from __future__ import annotations

import dataclasses
import json
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from cadnerf_cli.eval_cmd import EXCLUDE_HELP, parse_model_ids, parse_overrides

if TYPE_CHECKING:
    import numpy as np

    from cadnerf_core.intake import Photo
    from cadnerf_core.library import Library
    from cadnerf_core.retrieval import RetrievalResult

class Solver(StrEnum):
    """Pose solver."""

    dp = "dp"
    paper = "paper"


class Walk(StrEnum):
    """Which way round the photos were taken."""

    auto = "auto"
    ccw = "ccw"
    cw = "cw"


class Order(StrEnum):
    """The photos' order."""

    auto = "auto"
    walk = "walk"
    any = "any"


ORDER_HELP = ("The photos' order: walk (taken walking round the object, in this order), any "
              "(no order: found from the photos), or auto (the given order unless the photos "
              "do not look like a walk in it; then the order found, with a warning).")


class Perspective(StrEnum):
    """Which library silhouette set to match."""

    auto = "auto"
    far = "far"
    near = "near"


FOCAL_HELP = ("The camera's focal length in 35 mm terms, for photos whose EXIF does not say "
              "(a phone's main lens: about 26; messaging apps strip EXIF).")
PERSPECTIVE_HELP = ("Library silhouettes to match: near (seen from about half as far, as a "
                    "phone's wide lens frames an object), far (a 40-degree camera), or auto "
                    "(chosen by the photos' EXIF focal length; far without one).")

TILE = 128  # pixels per tile in the match pictures
MASK_EXTENSIONS = (".png", ".jpg", ".jpeg", ".webp", ".bmp")


def resolve_mask_paths(photos: list[Path], masks: list[Path]) -> list[Path] | None:
    """The mask of each photo: the given files in order, or one folder matched by file stem.

    Raises:
        FileNotFoundError: a photo has no mask of the same stem in the folder.
    """
    if not masks:
        return None
    if len(masks) == 1 and masks[0].is_dir():
        found = []
        for photo in photos:
            candidates = [masks[0] / f"{photo.stem}{ext}" for ext in MASK_EXTENSIONS]
            match = next((c for c in candidates if c.is_file()), None)
            if match is None:
                raise FileNotFoundError(f"{photo.name}: no mask named {photo.stem}.png (or "
                                        f".jpg, .webp) in {masks[0]}")
            found.append(match)
        return found
    return masks


def _label(tile: np.ndarray, text: str) -> np.ndarray:
    """Write ``text`` on the top-left of an RGB uint8 tile (in place) and return it."""
    import cv2

    cv2.putText(tile, text, (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 2, cv2.LINE_AA)
    cv2.putText(tile, text, (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 0), 1,
                cv2.LINE_AA)
    return tile


def match_rows(photos: list[Photo], masks: list[np.ndarray], library: Library,
               result: RetrievalResult) -> list[np.ndarray]:
    """One picture per photo: canonical crop, its mask, the matched silhouette, the overlay.

    In the overlay, white is both, red the photo's mask only, cyan the silhouette only.

    Args:
        photos, masks: the photos and their full masks [H_i, W_i] bool.
        library: the library retrieved from.
        result: the retrieval result.
    Returns:
        One [TILE, 4 * TILE, 3] uint8 RGB row per photo.
    """
    import cv2
    import numpy as np

    from cadnerf_core.intake import canonical_views

    library = library.view_set(result.perspective)
    spec = library.spec
    rgb, crops, _ = canonical_views(photos, masks, spec.silhouette_size, spec.margin)
    m = library.index(result.model_id)
    rows = []
    for match, image, crop in zip(result.matches, rgb, crops, strict=True):
        sil = library.silhouettes[m, match.view]
        overlay = np.stack([crop, sil, sil], axis=-1).astype(np.float32)
        tiles = [image, np.repeat(crop[..., None], 3, -1), np.repeat(sil[..., None], 3, -1),
                 overlay]
        tiles = [cv2.resize((t * 255).astype(np.uint8), (TILE, TILE),
                            interpolation=cv2.INTER_NEAREST) for t in tiles]
        state = "discarded" if match.discarded else f"IoU {match.iou:.2f}"
        _label(tiles[0], match.name[:20])
        _label(tiles[2], f"az {match.azimuth:.0f} el {match.elevation:.0f}")
        _label(tiles[3], state)
        rows.append(np.concatenate(tiles, axis=1))
    return rows


def write_pictures(out: Path, rows: list[np.ndarray], names: list[str]) -> Path:
    """Write one PNG per photo and the combined ``sheet.png``. Returns the sheet's path."""
    import numpy as np
    from PIL import Image

    out.mkdir(parents=True, exist_ok=True)
    for i, (row, name) in enumerate(zip(rows, names, strict=True)):
        Image.fromarray(row).save(out / f"{i:03d}_{Path(name).stem}.png")
    sheet = out / "sheet.png"
    Image.fromarray(np.concatenate(rows, axis=0)).save(sheet)
    return sheet


def summary_lines(result: RetrievalResult) -> list[str]:
    """Human-readable lines: the model, the top models, and a line per photo."""
    lines = [f"model: {result.model_id} ({result.category})  solver: {result.solver}  "
             f"direction: {result.direction:+d}  perspective: {result.perspective}",
             "top models:"]
    if result.order and result.order != sorted(result.order):
        walked = ", ".join(result.matches[i].name for i in result.order)
        lines.insert(1, f"walking order{' (reordered)' if result.reordered else ''}: {walked}")
    from cadnerf_core.job_warnings import job_warnings

    names = [m.name for m in sorted(result.matches, key=lambda m: m.index)]
    for warning in reversed(job_warnings(result.to_json(), names)):
        lines.insert(1, f"warning: {warning}")
    lines += [f"  {t['model_id']:<24} {t['category']:<12} votes {t['votes']}  "
              f"summed IoU {t['score']:.2f}" for t in result.top_models]
    lines.append("photos:")
    for m in result.matches:
        flag = "  DISCARDED" if m.discarded else ""
        lines.append(f"  {m.index:>2} {m.name:<28} view {m.view:>3}  az {m.azimuth:5.1f}  "
                     f"el {m.elevation:4.1f}  IoU {m.iou:.3f}{flag}")
    return lines


def retrieve_command(
    photos: list[Path] = typer.Argument(..., help="Photos, in walking order unless --order "
                                        "says otherwise (JPEG, PNG, WebP, HEIC, AVIF)."),
    masks: list[Path] = typer.Option([], "--masks", "-m", help="A mask per photo, in order "
                                     "(repeat the option), or one folder of masks named "
                                     "like the photos."),
    library: Path = typer.Option(Path("library_data/build"), "--library",
                                 help="Library folder."),
    solver: Solver = typer.Option(Solver.dp, "--solver", help="Pose solver: dp (ours, exact "
                                  "cyclic order) or paper (Algorithm 1)."),
    walk: Walk = typer.Option(Walk.auto, "--walk", help="Which way round the photos were "
                              "taken: ccw (counter-clockwise seen from above, the object on "
                              "your left), cw, or auto (found from the photos)."),
    order: Order = typer.Option(Order.auto, "--order", help=ORDER_HELP),
    own_focal: bool = typer.Option(False, "--own-focal", help="Each photo keeps a focal "
                                   "length of its own (photos taken at different zooms); by "
                                   "default they share one."),
    perspective: Perspective = typer.Option(Perspective.auto, "--perspective",
                                            help=PERSPECTIVE_HELP),
    focal_35mm: float | None = typer.Option(None, "--focal-35mm", min=8.0, max=1200.0,
                                            help=FOCAL_HELP),
    exclude_models: list[str] = typer.Option([], "--exclude-models", help=EXCLUDE_HELP),
    preset: str = typer.Option("preview", "--preset", help="The preset a job would run "
                               "(its start's short silhouette fits): preview, standard, paper."),
    device: str = typer.Option("auto", "--device", help="auto, cpu, cuda, cuda:N."),
    settings: list[str] = typer.Option([], "--set", help="A setting key=value, as "
                                       "`cadnerf reconstruct --set` takes it; repeatable."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
    out: Path | None = typer.Option(None, "--out", help="Folder for match pictures."),
) -> None:
    """Find the CAD model and the camera every photo's training would start from."""
    import tempfile

    from cadnerf_core.errors import CadNerfError

    try:
        overrides = parse_overrides(settings) | option_overrides(
            solver, walk, order, own_focal, perspective, focal_35mm, exclude_models)
        with tempfile.TemporaryDirectory(prefix="cadnerf-retrieve-") as job:
            loaded, found, lib, result = start_cameras(photos, masks, library, preset,
                                                       overrides, device, Path(job))
    except (CadNerfError, FileNotFoundError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    if out is not None:
        sheet = write_pictures(out, match_rows(loaded, found, lib, result),
                               [p.name for p in loaded])
        if not as_json:
            typer.echo(f"pictures: {sheet}")
    data: dict[str, Any] = result.to_json()
    typer.echo(json.dumps(data, indent=1) if as_json else "\n".join(summary_lines(result)))


def option_overrides(solver: Solver, walk: Walk, order: Order, own_focal: bool,
                     perspective: Perspective, focal_35mm: float | None,
                     exclude_models: list[str]) -> dict[str, Any]:
    """The retrieval settings the command's options name, as dotted config overrides."""
    overrides: dict[str, Any] = {"retrieval.solver": "paper" if solver == Solver.paper else "dp"}
    if walk != Walk.auto:
        overrides["retrieval.walk"] = walk.value
    if order != Order.auto:
        overrides["retrieval.order"] = order.value
    if own_focal:
        overrides["retrieval.shared_focal"] = False
    if perspective != Perspective.auto:
        overrides["retrieval.perspective"] = perspective.value
    if focal_35mm is not None:
        overrides["retrieval.focal_35mm"] = focal_35mm
    if exclude_models:
        overrides["retrieval.exclude_models"] = list(parse_model_ids(exclude_models))
    return overrides


def start_cameras(photos: list[Path], masks: list[Path], library: Path, preset: str,
                  overrides: dict[str, Any], device: str, job: Path,
                  ) -> tuple[list[Photo], list[np.ndarray], Library, RetrievalResult]:
    """The photos, their masks, the library and the cameras a job on ``photos`` starts from:
    the same call as a job's (``pipeline.start_job``), in the scratch job folder ``job``."""
    from cadnerf_cli.reconstruct_cmd import stage_inputs
    from cadnerf_core.config import internal_config
    from cadnerf_core.jobfolder import JobFolder
    from cadnerf_core.library import load_library
    from cadnerf_core.nerf import resolve_device
    from cadnerf_core.pipeline import start_job
    from cadnerf_core.progress import Progress

    config = internal_config(preset, overrides)
    lib = load_library(library)
    stage_inputs(photos, resolve_mask_paths(photos, masks), job)
    JobFolder(job).write_config(config)
    intake, _ = start_job(job, lib, config, resolve_device(device), Progress())
    # The job folder numbers its copies; the user knows the photos by their own names.
    named = [dataclasses.replace(m, name=photos[m.index].name) for m in intake.retrieval.matches]
    return intake.photos, intake.masks, lib, dataclasses.replace(intake.retrieval, matches=named)


def register(app: typer.Typer) -> None:
    """Add the ``retrieve`` command to ``app``."""
    app.command("retrieve")(retrieve_command)

"""``cadnerf masks``: see the masks a job would use before spending minutes on it."""

from __future__ import annotations

import json
from enum import StrEnum
from pathlib import Path
from typing import Any

import typer


class Method(StrEnum):
    """Background removal for photos that bring no mask."""

    auto = "auto"
    learned = "learned"
    grabcut = "grabcut"


def write_masks(out: Path, photos: list[Any], results: list[Any]) -> list[dict[str, Any]]:
    """Write ``NNN.png`` (8-bit, 255 = object) and ``NNN_overlay.jpg`` per photo in ``out``;
    one JSON-ready record per photo."""
    from PIL import Image

    from cadnerf_core.intake import mask_overlay

    out.mkdir(parents=True, exist_ok=True)
    records = []
    for i, (photo, result) in enumerate(zip(photos, results, strict=True)):
        mask_file, overlay_file = out / f"{i:03d}.png", out / f"{i:03d}_overlay.jpg"
        Image.fromarray(result.mask.astype("uint8") * 255, mode="L").save(mask_file)
        Image.fromarray(mask_overlay(photo.rgb, result.mask)).save(overlay_file, quality=90)
        records.append({"index": i, "photo": photo.name, "method": result.source,
                        "cover": round(float(result.mask.mean()), 4), "mask": str(mask_file),
                        "overlay": str(overlay_file), "warnings": list(result.warnings)})
    return records


def masks_command(
    photos: list[Path] = typer.Argument(..., help="Photos, in walking order (JPEG, PNG, WebP); "
                                        "one with transparency keeps its alpha as its mask."),
    out: Path = typer.Option(..., "--out", help="Folder for NNN.png masks and overlays."),
    method: Method = typer.Option(Method.auto, "--method", help="auto (the learned remover "
                                  "where installed, else GrabCut), learned or grabcut."),
    mask_model: Path | None = typer.Option(None, "--mask-model", help="Your own ONNX "
                                           "saliency model (U-2-Net style) for the learned "
                                           "remover, instead of the bundled one."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
) -> None:
    """Write each photo's mask and an overlay picture, and print the method and warnings."""
    from cadnerf_core.errors import CadNerfError
    from cadnerf_core.intake import load_photos, photo_masks

    try:
        loaded = load_photos(photos)
        results = photo_masks(loaded, method.value, mask_model)
    except (CadNerfError, FileNotFoundError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    records = write_masks(out, loaded, results)
    if as_json:
        typer.echo(json.dumps(records, indent=1))
        return
    for record in records:
        typer.echo(f"{record['index']:03d} {record['photo']}: {record['method']}, "
                   f"{100 * record['cover']:.1f}% of the photo -> {record['mask']}")
        for warning in record["warnings"]:
            typer.echo(f"    warning: {warning}")


def register(app: typer.Typer) -> None:
    """Add the ``masks`` command to ``app``."""
    app.command("masks")(masks_command)

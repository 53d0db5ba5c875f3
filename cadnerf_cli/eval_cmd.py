"""``cadnerf eval``: run the method on a dataset with ground truth and report its metrics."""

from __future__ import annotations

import json
import os
import tempfile
from enum import StrEnum
from pathlib import Path
from typing import Any

import typer

DEFAULT_LIBRARY = Path("library_data/build")


class Align(StrEnum):
    """How held-out ground-truth cameras are mapped into the NeRF's frame."""

    photometric = "photometric"
    per_view = "per-view"
    centred = "centred"
    umeyama = "umeyama"

LPIPS_ENV = "CADNERF_LPIPS_WEIGHTS"


def parse_frames(text: str) -> list[int]:
    """``"2,5"`` -> ``[2, 5]`` (0-based frame positions); raises typer.BadParameter otherwise."""
    try:
        frames = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise typer.BadParameter(f"expected comma-separated frame numbers, got {text!r}") \
            from None
    if any(f < 0 for f in frames):
        raise typer.BadParameter(f"frame numbers start at 0, got {text!r}")
    return frames


def parse_views(text: str) -> list[int]:
    """``"3,6,9"`` -> ``[3, 6, 9]``; raises typer.BadParameter on anything else."""
    try:
        views = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise typer.BadParameter(f"expected comma-separated integers, got {text!r}") from None
    if not views or any(v < 1 for v in views):
        raise typer.BadParameter(f"expected positive view counts, got {text!r}")
    return views


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """``["phase2.steps=10", "use_cad_init=false"]`` -> dotted overrides (values as JSON).

    A value that is not JSON is kept as a string (``preset=paper``).
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"expected key=value, got {item!r}")
        try:
            value: Any = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        out[key.strip()] = value
    return out


EXCLUDE_HELP = ("Library model ids never to retrieve, comma-separated (repeatable): a "
                "leave-out test on objects the library has no look-alike of.")


def parse_model_ids(items: list[str]) -> tuple[str, ...]:
    """``["truck,duck_toy", "boot"]`` -> ``("truck", "duck_toy", "boot")``; blanks dropped."""
    return tuple(part.strip() for item in items for part in item.split(",") if part.strip())


def _summary(report: dict[str, Any]) -> str:
    img, ref, ret = report["image"], report["pose_refined"], report["pose_retrieved"]
    inside, on_mesh = report["image_masked"], report["image_mesh"]

    def num(value: Any, digits: int = 2) -> str:
        return "-" if value is None else f"{value:.{digits}f}"

    return (f"{report['n_views']} views: model {report['model_id']} | "
            f"PSNR {num(img['psnr'])} SSIM {num(img['ssim'], 3)} LPIPS {num(img['lpips'], 3)} "
            f"Avg {num(img['average'], 3)} | in the mask PSNR {num(inside['psnr'])} SSIM "
            f"{num(inside['ssim'], 3)}"
            + (f", mesh {num(on_mesh['psnr'])} / {num(on_mesh['ssim'], 3)}" if on_mesh else "")
            + f" | rotation {num(ret['rotation_deg'])} -> "
            f"{num(ref['rotation_deg'])} deg, translation x100 {num(ret['translation_x100'])} -> "
            f"{num(ref['translation_x100'])} | focal error "
            f"{num(100 * report['focal_error_retrieved'], 0)} -> "
            f"{num(100 * report['focal_error'], 0)} % | {report['seconds']:.0f} s")


def eval_command(
    dataset: Path = typer.Argument(..., help="Dataset folder with a test split (render-dataset "
                                   "--test-views, or a NeRF-synthetic scene), or a real "
                                   "capture (photos, masks, cameras.json) with --hold-out."),
    views: str = typer.Option("3,6,9", "--views", help="Comma-separated numbers of input views."),
    preset: str = typer.Option("preview", "--preset", help="Pipeline preset."),
    overrides: list[str] = typer.Option([], "--set", help="A setting key=value (dotted keys, "
                                        "JSON values; `cadnerf config --schema` lists them); "
                                        "repeatable."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the job."),
    exclude_models: list[str] = typer.Option([], "--exclude-models", help=EXCLUDE_HELP),
    as_json: bool = typer.Option(False, "--json", help="Print the reports as JSON."),
    library: Path = typer.Option(DEFAULT_LIBRARY, "--library", help="Built CAD library folder."),
    work: Path | None = typer.Option(None, "--work", help="Where job folders go (default: a "
                                     "temporary folder, removed afterwards)."),
    device: str = typer.Option("auto", "--device", help="auto, cpu or cuda."),
    align: Align = typer.Option(Align.photometric, "--align", help="Mapping of held-out cameras "
                              "into the NeRF: photometric (centred, then one correction for all "
                              "cameras fitted on the training photos), per-view (that from the "
                              "better of two starts, then each held-out camera refined on its "
                              "own photo, as BARF evaluates), centred (about the "
                              "object's centre, from the camera centres) or umeyama."),
    eval_size: int | None = typer.Option(None, "--eval-size", min=8, help="Score held-out "
                                         "views at this longer side in pixels (default: "
                                         "dataset's)."),
    hold_out: str = typer.Option("", "--hold-out", help="Frames (0-based, comma-separated) "
                                 "the job never sees, scored as held-out views: for a capture "
                                 "or a folder without a test split."),
    exif_focal: bool = typer.Option(False, "--exif-focal", help="Give the job each photo's "
                                    "true focal length as EXIF, as a phone's photos carry it."),
    mesh: bool = typer.Option(False, "--mesh", help="Also render the held-out views from the "
                              "job's textured mesh.glb and score them inside the mask."),
) -> None:
    """Evaluate novel views and camera poses on DATASET for each number of input views."""
    from cadnerf_cli.config_cmd import settings_error
    from cadnerf_core.config import resolve_config
    from cadnerf_core.errors import CadNerfError
    from cadnerf_core.evaluation import evaluate_dataset
    from cadnerf_core.evaluation.metrics import load_lpips
    from cadnerf_core.library import load_library

    counts = parse_views(views)
    held_out = parse_frames(hold_out)
    config = {**parse_overrides(overrides), "seed": seed}
    excluded = parse_model_ids(exclude_models)
    if excluded:
        config["retrieval.exclude_models"] = list(excluded)
    try:
        resolve_config(preset, config)  # --set takes the settings a client may send, no more
    except ValueError as exc:
        typer.echo(f"error: {settings_error(exc)}", err=True)
        raise typer.Exit(code=2) from None
    weights = os.environ.get(LPIPS_ENV)
    lpips_net = load_lpips(Path(weights) if weights else None)
    reports = []
    try:
        lib = load_library(library)
        with tempfile.TemporaryDirectory(prefix="cadnerf-eval-") as tmp:
            root = work or Path(tmp)
            for n in counts:
                report = evaluate_dataset(dataset, n, lib, preset=preset, overrides=config,
                                          job_dir=root / f"views{n}", lpips_net=lpips_net,
                                          device=device, align=align.value,
                                          eval_size=eval_size, exif_focal=exif_focal,
                                          hold_out=held_out, mesh=mesh)
                reports.append(report.to_json())
                if not as_json:
                    typer.echo(_summary(reports[-1]))
    except (CadNerfError, ValueError, OSError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    if as_json:
        typer.echo(json.dumps(reports, indent=2))


def register(app: typer.Typer) -> None:
    """Add the ``eval`` command to ``app``."""
    app.command("eval")(eval_command)

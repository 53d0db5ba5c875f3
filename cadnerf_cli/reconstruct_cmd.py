"""``cadnerf reconstruct``: the whole pipeline in-process, with a progress bar."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from cadnerf_cli.config_cmd import settings_error
from cadnerf_cli.eval_cmd import EXCLUDE_HELP, parse_model_ids, parse_overrides
from cadnerf_cli.retrieve_cmd import (
    FOCAL_HELP,
    ORDER_HELP,
    PERSPECTIVE_HELP,
    Order,
    Perspective,
    Walk,
)
from cadnerf_core.progress import STAGES

DEFAULT_LIBRARY = Path("library_data/build")


def stage_inputs(photos: list[Path], masks: list[Path] | None, out: Path) -> None:
    """Copy photos (and one mask each) into the job folder ``out``, in order, replacing any
    earlier inputs; each mask is stored under its photo's name (``JobFolder``)."""
    from cadnerf_core.jobfolder import JobFolder

    if masks and len(masks) != len(photos):
        raise ValueError(f"{len(masks)} masks for {len(photos)} photos: give one per photo")
    for path in [*photos, *(masks or [])]:
        if not path.is_file():
            raise ValueError(f"{path}: no such file")
    folder = JobFolder(out)
    folder.clear_inputs()
    for i, photo in enumerate(photos):
        stored = folder.add_photo(i, photo)
        if masks:
            folder.add_mask(stored, masks[i])


def reconstruct(
    photos: list[Path] = typer.Argument(..., help="3 to 10 photos, in walking order unless "
                                        "--order says otherwise."),
    out: Path = typer.Option(..., "--out", help="Job folder for the results."),
    masks: list[Path] | None = typer.Option(None, "--masks", help="One mask per photo."),
    preset: str = typer.Option("standard", "--preset", help="paper, standard or preview."),
    device: str = typer.Option("auto", "--device", help="auto, cpu, cuda, cuda:N."),
    library_dir: Path = typer.Option(DEFAULT_LIBRARY, "--library", help="CAD library folder."),
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
    mask_model: Path | None = typer.Option(None, "--mask-model", exists=True, dir_okay=False,
                                           help="Your own ONNX background-removal model for "
                                           "the learned masks (default: the built-in one)."),
    exclude_models: list[str] = typer.Option([], "--exclude-models", help=EXCLUDE_HELP),
    settings: list[str] = typer.Option([], "--set", help="A setting key=value (dotted keys, JSON "
                                       "values, e.g. phase2.steps=300; `cadnerf config "
                                       "--schema` lists them); repeatable."),
) -> None:
    """Poses, novel views, an orbit video and a mesh from ordered photos of an object."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from cadnerf_core.config import resolve_config
    from cadnerf_core.errors import CadNerfError
    from cadnerf_core.jobfolder import MASKS, MESH, ORBIT_VIDEO, POSES, RESULT, VIEWS, JobFolder
    from cadnerf_core.library import load_library
    from cadnerf_core.pipeline import run_job
    from cadnerf_core.progress import Progress as CoreProgress

    try:
        overrides: dict[str, Any] = parse_overrides(settings)
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
        config = resolve_config(preset, overrides)
        library = load_library(library_dir)
        stage_inputs(photos, masks, out)
        JobFolder(out).write_config(config)
        columns = (TextColumn("{task.description:<10}"), BarColumn(),
                   TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn())
        with Progress(*columns) as bar:
            tasks = {s: bar.add_task(s, total=1, visible=False) for s in STAGES}

            def report(stage: str, done: int, total: int) -> None:
                task = tasks.get(stage)
                if task is not None:
                    bar.update(task, completed=done, total=max(total, 1), visible=True)

            result = run_job(out, library, CoreProgress(report), device, mask_model)
    except (CadNerfError, ValueError, OSError) as exc:
        typer.echo(f"error: {settings_error(exc)}", err=True)
        raise typer.Exit(2) from exc
    psnr = result.metrics.mean_psnr
    typer.echo(f"model: {result.model.id} ({result.model.category}); mean training PSNR "
               + ("-" if psnr is None else f"{psnr:.2f} dB"))
    for warning in result.warnings:
        typer.echo(f"warning: {warning}")
    typer.echo(f"results in {out.resolve()}: {RESULT}, {ORBIT_VIDEO}, {MESH}, {POSES}, "
               f"{VIEWS}/, {MASKS}/")


def register(app: typer.Typer) -> None:
    """Add ``reconstruct`` to the ``cadnerf`` command."""
    app.command("reconstruct")(reconstruct)

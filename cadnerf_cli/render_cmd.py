"""``cadnerf render``: a finished job rendered at any cameras, as ``ns-render`` does."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer


class RenderSource(StrEnum):
    """What the views are rendered from."""

    field = "field"
    mesh = "mesh"


CAMERAS_HELP = ("A transforms.json (nerfstudio or NeRF-synthetic layout: OpenGL axes) or a "
                "COLMAP text model (a folder with cameras.txt and images.txt, or one of them). "
                "The cameras must be in the job's frame: the one its own transforms.json and "
                "sparse/0/ are written in (object centred at the origin in the unit sphere, "
                "+Y up); cameras of another reconstruction must be aligned to it first.")


def render_command(
    job: Path = typer.Argument(..., help="A finished job folder (cadnerf reconstruct --out, or "
                               "a downloaded results folder with its checkpoints)."),
    cameras: Path = typer.Option(..., "--cameras", help=CAMERAS_HELP),
    out: Path = typer.Option(..., "--out", help="Folder for the PNGs (one per camera, named "
                             "after its image)."),
    source: RenderSource = typer.Option(RenderSource.field, "--source", help="field: the "
                                        "trained NeRF; mesh: the exported textured mesh.glb."),
    size: int | None = typer.Option(None, "--size", min=8, max=4096, help="Longer side in "
                                    "pixels (default: each camera's own size)."),
    device: str = typer.Option("auto", "--device", help="auto, cpu, cuda, cuda:N."),
) -> None:
    """Render JOB at the cameras of a transforms.json or COLMAP model, given in the job's
    frame, into PNGs."""
    from cadnerf_core.errors import CadNerfError
    from cadnerf_core.evaluation.views import read_views, render_views

    try:
        views = read_views(cameras, size)
        written = render_views(job, views, out, source.value, device)
    except (CadNerfError, OSError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    typer.echo(f"rendered {len(written)} views from the {source.value} into {out}")


def register(app: typer.Typer) -> None:
    """Add the ``render`` command to ``app``."""
    app.command("render")(render_command)

"""``cadnerf render-dataset``: a synthetic dataset with ground-truth cameras from a mesh."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer


class UpAxis(StrEnum):
    """The mesh file's up axis."""

    y = "y"
    z = "z"


def render_dataset_command(
    mesh: Path = typer.Argument(..., help="Mesh file: OBJ (+MTL, textures), PLY, STL, OFF, GLB."),
    out: Path = typer.Option(..., "--out", help="Folder to write the dataset to."),
    views: int = typer.Option(12, "--views", min=1, help="Training views, in walking order."),
    size: int = typer.Option(128, "--size", min=8, help="Image side in pixels."),
    seed: int = typer.Option(0, "--seed", help="Seed of the random start, jitter, elevations."),
    up: UpAxis = typer.Option(UpAxis.y, "--up", help="Up axis of the mesh file."),
    test_views: int = typer.Option(0, "--test-views", min=0, help="Held-out test views."),
) -> None:
    """Render MESH into a NeRF-synthetic dataset (RGBA images, masks, transforms.json)."""
    from cadnerf_core.errors import CadNerfError
    from cadnerf_core.evaluation import render_dataset

    try:
        folder = render_dataset(mesh, out, n_views=views, size=size, seed=seed, up=up.value,
                                test_views=test_views)
    except CadNerfError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    typer.echo(f"wrote {views} views ({test_views} test) of {size}x{size} px to {folder}")


def register(app: typer.Typer) -> None:
    """Add the ``render-dataset`` command to ``app``."""
    app.command("render-dataset")(render_dataset_command)

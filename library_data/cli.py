"""The ``cadnerf library`` commands: build, list, add, remove, preview."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import typer

library_app = typer.Typer(help="The CAD mini library: build, list, add, remove, preview.",
                          no_args_is_help=True)


def _default_root() -> Path:
    from library_data.build import DEFAULT_OUT

    return DEFAULT_OUT


_ROOT_HELP = "Library folder (default: library_data/build)."


@contextmanager
def _errors() -> Iterator[None]:
    """Turn expected failures into a one-line message and exit status 1."""
    from cadnerf_core.errors import CadNerfError

    try:
        yield
    except CadNerfError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None


@library_app.command("build")
def build(out: Path = typer.Option(None, help=_ROOT_HELP),
          poses: int = typer.Option(None, help="Library poses (default: 36 azimuths per "
                                    "elevation, 180); a multiple of the number of elevations."),
          elevations: str = typer.Option(None, help="Camera elevations in degrees, comma-"
                                         "separated (default: 0,15,30,45,60)."),
          if_stale: bool = typer.Option(False, "--if-stale",
                                        help="Do nothing when the library is current."),
          jobs: int = typer.Option(None, help="Worker processes (default: CPU count).")) -> None:
    """Build the library: parametric models (and models added before), renders, occupancy."""
    from cadnerf_core.library.format import LibrarySpec
    from library_data.build import build_library

    default = LibrarySpec()
    levels = default.elevations
    if elevations is not None:
        try:
            levels = tuple(float(x) for x in elevations.split(","))
        except ValueError:
            levels = ()
        if not levels or not all(-89.0 <= e <= 89.0 for e in levels) \
                or len(set(levels)) != len(levels):
            typer.echo(f"error: --elevations {elevations!r} must be distinct degrees between "
                       "-89 and 89, comma-separated (e.g. 0,15,30,45,60)", err=True)
            raise typer.Exit(2)
    n_poses = default.n_azimuths * len(levels) if poses is None else poses
    if n_poses <= 0 or n_poses % len(levels):
        typer.echo(f"error: --poses must be a positive multiple of the {len(levels)} "
                   "elevations", err=True)
        raise typer.Exit(2)
    spec = LibrarySpec(n_azimuths=n_poses // len(levels), elevations=levels)
    with _errors():
        result = build_library(out or _default_root(), spec, jobs=jobs, if_stale=if_stale)
    verb = "built" if result.built else "up to date:"
    typer.echo(f"{verb} {result.n_models} models in {result.root} ({result.seconds:.1f} s)")


@library_app.command("list")
def list_models(library: Path = typer.Option(None, help=_ROOT_HELP),
                as_json: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
    """List the library's models."""
    from cadnerf_core.library.format import read_manifest

    root = library or _default_root()
    with _errors():
        data = read_manifest(root)
    models: list[dict[str, Any]] = data["models"]
    if as_json:
        typer.echo(json.dumps({"root": str(root), "spec": data["spec"], "models": models},
                              indent=1))
        return
    typer.echo(f"{'id':18} {'category':12} {'kind':7} {'triangles':>9}  source")
    for m in models:
        typer.echo(f"{m['id']:18} {m['category']:12} {m['kind']:7} {m['n_triangles']:>9}  "
                   f"{m['source']}")
    typer.echo(f"{len(models)} models in {root}")


@library_app.command("add")
def add(file: Path = typer.Argument(..., help="OBJ, OFF, PLY, STL or GLB file, or a ShapeNet "
                                    "model folder."),
        category: str = typer.Option(..., help="Object category, e.g. chair."),
        model_id: str = typer.Option(None, "--id", help="Model id (default: the file name)."),
        up: str = typer.Option("y", help="The file's up axis: y or z."),
        licence: str = typer.Option(None, help="Licence of the geometry, kept in the manifest."),
        library: Path = typer.Option(None, help=_ROOT_HELP)) -> None:
    """Import a CAD file: normalise, make watertight, pre-render, add to the manifest."""
    from library_data.importer import IMPORT_LICENCE, add_model

    if up not in ("y", "z"):
        typer.echo("error: --up must be y or z", err=True)
        raise typer.Exit(2)
    with _errors():
        entry = add_model(library or _default_root(), file, category, model_id,
                          "y" if up == "y" else "z", licence or IMPORT_LICENCE)
    typer.echo(f"added {entry.id} ({entry.category}, {entry.n_triangles} triangles)")


@library_app.command("remove")
def remove(model_id: str = typer.Argument(..., help="Id of the model to remove."),
           library: Path = typer.Option(None, help=_ROOT_HELP)) -> None:
    """Remove a model from the library."""
    from library_data.importer import remove_model

    with _errors():
        remove_model(library or _default_root(), model_id)
    typer.echo(f"removed {model_id}")


@library_app.command("preview")
def preview(out: Path = typer.Option(Path("docs/library.png"), help="PNG to write."),
            size: int = typer.Option(160, help="Tile side in pixels."),
            library: Path = typer.Option(None, help=_ROOT_HELP)) -> None:
    """Write a contact sheet: every model shaded from a three-quarter view, labelled."""
    from cadnerf_core.library.format import load_library
    from library_data.preview import write_contact_sheet

    with _errors():
        path = write_contact_sheet(load_library(library or _default_root()), out, size)
    typer.echo(f"wrote {path}")


def register(app: typer.Typer) -> None:
    """Add the ``library`` sub-command group to the ``cadnerf`` command."""
    app.add_typer(library_app, name="library")


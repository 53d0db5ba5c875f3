"""``cadnerf config``: the settings a client may send, as JSON Schema or as the guide's reference.

``--schema`` prints the JSON Schema of a job's ``overrides`` (what ``--set`` and the HTTP API
accept); ``--markdown`` the reference table of ``docs/guide.md``; ``--write FILE`` puts that
table between the file's settings markers (``make docs`` keeps the guide in step).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer


def settings_error(exc: Exception) -> str:
    """A clear message for a rejected ``--set``: each setting by its path, and why."""
    from pydantic import ValidationError

    from cadnerf_core.config import field_bounds
    from cadnerf_core.config_client import refused_names

    if not isinstance(exc, ValidationError):
        return str(exc)
    lines = []
    for err in exc.errors():
        loc = tuple(err.get("loc", ()))
        where = ".".join(str(p) for p in loc)
        if err.get("type") == "extra_forbidden":
            where = refused_names(loc, err.get("input"))
            lines.append(f"--set {where}: not a setting you may change "
                         "(`cadnerf config --schema` lists them)")
            continue
        bounds = field_bounds(loc)
        text = str(err.get("msg")).removeprefix("Value error, ")
        lines.append(f"--set {where}: {text}" + (f" (allowed: {bounds})" if bounds else ""))
    return "; ".join(lines)


def reference_markdown() -> str:
    """The settings reference: the table ``docs/guide.md`` holds between its markers."""
    from cadnerf_core.config_client import settings_markdown

    return settings_markdown()


def write_reference(path: Path) -> bool:
    """Put the reference between ``path``'s settings markers; True when the file changed."""
    from cadnerf_core.config_client import with_settings_reference

    before = path.read_text(encoding="utf-8")
    after = with_settings_reference(before, reference_markdown())
    if after != before:
        path.write_text(after, encoding="utf-8")
    return after != before


def register(app: typer.Typer) -> None:
    """Add ``cadnerf config`` to ``app``."""

    @app.command("config")
    def config_command(
        schema: bool = typer.Option(False, "--schema", help="Print the JSON Schema of the "
                                    "settings a client may send (`--set`, HTTP `overrides`)."),
        markdown: bool = typer.Option(False, "--markdown", help="Print them as the markdown "
                                      "reference of docs/guide.md instead."),
        write: Path | None = typer.Option(None, "--write", dir_okay=False, help="Write the "
                                          "markdown reference between this file's "
                                          "<!-- settings:start/end --> markers."),
    ) -> None:
        """The settings a client may send on top of a preset."""
        from cadnerf_core.config_client import client_schema

        if write is not None:
            try:
                changed = write_reference(write)
            except (OSError, ValueError) as exc:
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(2) from exc
            typer.echo(f"{write}: {'updated' if changed else 'already up to date'}")
        elif markdown:
            typer.echo(reference_markdown(), nl=False)
        elif schema:
            document: dict[str, Any] = {"$schema": "https://json-schema.org/draft/2020-12/schema",
                                        **client_schema()}
            typer.echo(json.dumps(document, indent=2))
        else:
            typer.echo("give --schema, --markdown or --write FILE", err=True)
            raise typer.Exit(2)

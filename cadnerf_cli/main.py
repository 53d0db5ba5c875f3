"""Entry point of the ``cadnerf`` console command."""

from __future__ import annotations

import logging

import typer

app = typer.Typer(
    name="cadnerf",
    help="CAD-NeRF: camera poses, novel views, an orbit video and a mesh from 3-10 photos.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _configure(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Debug logging."),
) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")


def _register() -> None:
    # Each module adds its own commands (a `register(app)` function); one line per module.
    # --- commands ---
    from cadnerf_cli import reconstruct_cmd
    reconstruct_cmd.register(app)
    from cadnerf_cli import eval_cmd
    eval_cmd.register(app)
    from library_data import cli as library_cli
    library_cli.register(app)
    from cadnerf_cli import retrieve_cmd
    retrieve_cmd.register(app)
    from cadnerf_cli import service_cmd
    service_cmd.register(app)
    from cadnerf_cli import demo_cmd
    demo_cmd.register(app)
    from cadnerf_cli import dataset_cmd
    dataset_cmd.register(app)
    from cadnerf_cli import masks_cmd
    masks_cmd.register(app)
    from cadnerf_cli import config_cmd
    config_cmd.register(app)
    from cadnerf_cli import render_cmd
    render_cmd.register(app)


_register()


def main() -> None:
    """Run the command line."""
    app()


if __name__ == "__main__":
    main()

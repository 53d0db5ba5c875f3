"""`cadnerf demo` (and the demo of `cadnerf serve --demo`): photos like a user's sent over HTTP,
followed to the result, whose page and orbit it names last."""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path
from typing import Any

import typer

from cadnerf_cli.demo_photos import HEIGHT, WIDTH, render_demo_photos

VIEWS = 10
"""Photos of the demo: about 36 degrees apart, as a careful walk round an object takes them
(at 8, 45 degrees apart, the chair's pairs are as often wrong as right, and the cameras of
half the photos rest on their outlines alone)."""


def run_demo(url: str, preset: str = "preview", views: int = VIEWS, size: int = WIDTH,
             out: Path | None = None, api_key: str | None = None,
             overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Photograph the demo chair (``views`` JPEGs ``size`` pixels wide, 4:3, with masks),
    submit them over HTTP, follow the job, download its orbit and say what to open.

    ``overrides`` go with the preset in the job's config, as an API client would send them.

    Returns:
        The job's final status.
    """
    from app.client import JobClient
    from cadnerf_core.jobfolder import ORBIT_VIDEO

    logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per poll is noise here
    out = out or Path(tempfile.mkdtemp(prefix="cadnerf-demo-"))
    photos, masks = render_demo_photos(out / "photos", views, size, size * HEIGHT // WIDTH)
    client = JobClient(url, api_key=api_key)
    try:
        submitted = time.monotonic()
        job = client.submit(photos, masks, config={"preset": preset,
                                                   "overrides": overrides or {}})
        typer.echo(f"demo job {job['id']}: {len(photos)} photos of a chair with their masks, "
                   f"preset {preset}; watch it at {url}/?job={job['id']}")
        final = client.follow(job["id"], on_update=StatusPrinter(), poll_s=1.0)
        if final["state"] != "succeeded":
            typer.echo(f"demo job {final['state']}: {final.get('error')}", err=True)
            return final
        result = client.result(job["id"])
        for warning in result["warnings"]:
            typer.echo(f"warning: {warning}")
        orbit = client.download(job["id"], ORBIT_VIDEO, out / ORBIT_VIDEO)
        kept = sum(not photo["discarded"] for photo in result["photos"])
        typer.echo(f"demo job succeeded in {time.monotonic() - submitted:.0f} s: "
                   f"{result['model']['id']}, {kept} of {len(photos)} photos placed")
        typer.echo(f"open the result page: {url}/?job={job['id']}")
        typer.echo(f"the orbit video: {orbit} "
                   f"(also {url}/v1/jobs/{job['id']}/artifacts/{ORBIT_VIDEO})")
        return final
    finally:
        client.close()


class StatusPrinter:
    """Prints a job's state, stage, progress and ETA when the state or stage changes, the
    progress moves by ``step`` or ``every_s`` seconds pass (not once per poll)."""

    def __init__(self, step: float = 0.05, every_s: float = 15.0) -> None:
        self.step, self.every_s = step, every_s
        self._last: tuple[str, str, float, float] | None = None

    def __call__(self, status: dict[str, Any]) -> None:
        state, stage = status["state"], status.get("stage") or "-"
        progress, now = float(status.get("progress") or 0), time.monotonic()
        last = self._last
        if last is not None and (state, stage) == last[:2] and progress < last[2] + self.step \
                and now < last[3] + self.every_s:
            return
        self._last = (state, stage, progress, now)
        eta = status.get("eta_s")
        running = state == "running" and isinstance(eta, int | float)
        eta_text = f", about {eta:.0f} s left" if running else ""
        typer.echo(f"  {state:9s} {stage:9s} {100 * progress:5.1f}%{eta_text}")


def demo(url: str = typer.Option("http://127.0.0.1:8000", help="The service's base URL."),
         preset: str = typer.Option("preview", help="Preset of the job."),
         views: int = typer.Option(VIEWS, min=3, max=10, help="Photos to take."),
         size: int = typer.Option(WIDTH, min=64, max=2048, help="Photo width in pixels (4:3)."),
         out: Path | None = typer.Option(None, help="Folder for the photos and the orbit."),
         api_key: str | None = typer.Option(None, envvar="CADNERF_DEMO_API_KEY",
                                            help="API key, if the server needs one.")) -> None:
    """Photograph a synthetic chair, send it to a running service and follow it to the orbit."""
    final = run_demo(url, preset, views, size, out, api_key)
    if final["state"] != "succeeded":
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add `demo` to the `cadnerf` command."""
    app.command("demo")(demo)

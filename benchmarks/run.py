"""``make bench``: run every area's benchmark and write docs/benchmarks.md.

Usage: ``python -m benchmarks.run [--quick] [--only AREA ...] --out docs/benchmarks.md``.
With ``--only``, the named areas are re-measured and the other areas' sections in ``--out``
are kept as they were, each with the commit, date and command that made it. Writing the
project's docs/benchmarks.md also renders the README's results table from docs/results.json
(``benchmarks.results``), where the areas record their headline figures.

Each area module ``benchmarks.bench_<area>`` has ``run(quick: bool) -> str`` returning a markdown
section. The known areas run in a fixed order (any other ``bench_*.py`` found joins them before
the evaluation, which runs last); one that is missing is listed as such, one that fails is
recorded with its error in the document and the others still run.
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib
import json
import logging
import os
import platform
import shlex
import subprocess
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from benchmarks import results
from benchmarks.harness import DOCS, LIBRARY_DIR, ROOT

log = logging.getLogger("benchmarks")

AREAS = ("renderer", "library", "retrieval", "training", "service", "eval")
# The preview-preset training benchmark (whole jobs at 128 px: the ablations on the two Table 5
# meshes, about 65 min on 2 cores, and the full method on the other 11, about 45 min) takes
# about 2 hours; QUICK covers training through the evaluation tables' shorter schedule.
FULL_ONLY = {"training": "the preview-preset training benchmark (ablations on two meshes, the "
                         "full method on every mesh) takes about 2 hours on 2 cores; run "
                         "`make bench` (without QUICK) for it"}


def area_main(run: Callable[[bool, Path], str] | Callable[[bool], str], description: str,
              argv: list[str] | None = None, library: bool = True, quick_help: str = "") -> int:
    """The command line of one area's module: ``[--quick] [--library DIR]`` (``--library``
    only where ``library``: ``run(quick, library)``, else ``run(quick)``), its section on
    standard output, progress logged."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--quick", action="store_true", help=quick_help or None)
    if library:
        parser.add_argument("--library", type=Path, default=LIBRARY_DIR)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    section = run(args.quick, args.library) if library else run(args.quick)  # type: ignore[call-arg]
    sys.stdout.write(section)
    return 0


def all_areas() -> list[str]:
    """The known areas in order, with any other ``bench_<area>.py`` inserted before ``eval``."""
    found = sorted(p.stem.removeprefix("bench_")
                   for p in Path(__file__).resolve().parent.glob("bench_*.py"))
    extra = [a for a in found if a not in AREAS]
    return [*AREAS[:-1], *extra, AREAS[-1]]


def _cpu_model() -> str:
    """The processor's name and its widest vector extension: machines under one name differ
    by up to twice in these benchmarks' times (a 2-core "AMD EPYC" listing AVX2 but no AVX-512
    took 587 s for a job that took 311 s on another 2-core "AMD EPYC")."""
    name, flags = "", set[str]()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and not name:
                name = line.split(":", 1)[1].strip()
            elif line.startswith("flags") and not flags:
                flags = set(line.split(":", 1)[1].split())
    except OSError:
        pass
    name = name or platform.processor() or platform.machine()
    vector = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else ""
    return f"{name} ({vector})" if vector else name


def cpu_summary() -> str:
    """This machine's processor (``_cpu_model``) and usable cores, for an area's row."""
    return f"{_cpu_model()}, {len(os.sched_getaffinity(0))} cores"


def _ram_gib() -> str:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                return f"{int(line.split()[1]) / 2**20:.1f} GiB"
    except OSError:
        pass
    return "unknown"


def _torch_and_gpu() -> tuple[str, str]:
    try:
        import torch
    except ImportError:
        return "not installed", "none"
    gpu = "none"
    if torch.cuda.is_available():
        props = torch.cuda.get_device_properties(0)
        gpu = f"{props.name} ({props.total_memory / 2**30:.0f} GiB)"
    return torch.__version__, gpu


def git_commit(root: Path = ROOT) -> str:
    """Short commit of the tree, ``uncommitted`` when the tree differs from it (or has none).

    Args:
        root: repository root.
    Returns:
        e.g. ``1a2b3c4``, ``1a2b3c4 (uncommitted changes)`` or ``uncommitted``.
    """
    def git(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True,
                              timeout=30, check=False)

    try:
        head = git("rev-parse", "--short", "HEAD")
        # docs/ holds this run's own outputs (pictures, this document): not a change of the code.
        dirty = git("status", "--porcelain", "--untracked-files=no", "--", ".",
                    ":(exclude)docs").stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "uncommitted"
    if head.returncode != 0:
        return "uncommitted"
    commit = head.stdout.strip()
    return f"{commit} (uncommitted changes)" if dirty else commit


def machine_lines() -> list[str]:
    """Markdown bullet lines describing this machine and software."""
    torch_version, gpu = _torch_and_gpu()
    return [
        f"- CPU: {_cpu_model()}, {os.cpu_count()} logical cores"
        f" ({len(os.sched_getaffinity(0))} usable)",
        f"- RAM: {_ram_gib()}",
        f"- GPU: {gpu}",
        f"- Python {platform.python_version()}, torch {torch_version}, {platform.platform()}",
    ]


def run_area(area: str, quick: bool) -> tuple[str, float]:
    """Run one area's benchmark, turning any failure into a section that says so.

    Args:
        area: e.g. ``"renderer"`` for ``benchmarks.bench_renderer``.
        quick: the reduced benchmark.
    Returns:
        (markdown section, seconds taken).
    """
    name = f"benchmarks.bench_{area}"
    if quick and area in FULL_ONLY:
        return f"## {area}\n\nNot run in QUICK mode: {FULL_ONLY[area]}.\n", 0.0
    start = time.perf_counter()
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name != name:
            return _failure(area, exc), time.perf_counter() - start
        return f"## {area}\n\nNot run: `{name}` does not exist yet.\n", 0.0
    except Exception as exc:  # noqa: BLE001 - a broken area must not stop the others
        return _failure(area, exc), time.perf_counter() - start
    try:
        section = str(module.run(quick))
    except Exception as exc:  # noqa: BLE001 - recorded in the document instead
        return _failure(area, exc), time.perf_counter() - start
    return section.rstrip() + "\n", time.perf_counter() - start


def _failure(area: str, exc: BaseException) -> str:
    log.exception("benchmark %s failed", area)
    trace = "".join(traceback.format_exception(exc)[-6:])
    return (f"## {area}\n\n**FAILED** with `{type(exc).__name__}: {exc}`.\n\n"
            f"```\n{trace.rstrip()}\n```\n")


MARKER = "<!-- area: "  # starts the line in front of each area's section


@dataclass(frozen=True)
class Section:
    """One area's measured section and how it was made."""

    area: str
    text: str  # markdown, starting with the section's heading
    seconds: float
    mode: str  # "QUICK" or "full"
    commit: str
    date: str  # UTC, minutes
    command: str
    cpu: str = ""  # the machine's processor (``cpu_summary``); "" in sections that predate it

    def block(self) -> str:
        """The section as stored: a marker line holding its run, then its markdown."""
        meta = json.dumps({"area": self.area, "seconds": round(self.seconds, 1),
                           "mode": self.mode, "commit": self.commit, "date": self.date,
                           "command": self.command, "cpu": self.cpu})
        return f"{MARKER}{meta} -->\n{self.text.rstrip()}\n"


def read_sections(document: str) -> dict[str, Section]:
    """The sections of an earlier docs/benchmarks.md, by area (none from an older layout)."""
    found: dict[str, Section] = {}
    chunks = document.split("\n" + MARKER)[1:]
    for chunk in chunks:
        meta, _, text = chunk.partition(" -->\n")
        try:
            info = json.loads(meta)
            found[info["area"]] = Section(info["area"], text, float(info["seconds"]),
                                          info["mode"], info["commit"], info["date"],
                                          info["command"], str(info.get("cpu", "")))
        except (ValueError, KeyError, TypeError):
            continue
    return found


def build_document(sections: list[Section]) -> str:
    """Assemble docs/benchmarks.md: the machine, a table of the areas (how and when each was
    measured), then each area's section.

    Args:
        sections: in the order they appear.
    Returns:
        The markdown document.
    """
    lines = [
        "# Benchmarks",
        "",
        "Generated by `make bench` (`benchmarks/run.py`); every figure below comes from the run"
        " its area's row names. `python -m benchmarks.run --only AREA` re-measures one area and"
        " keeps the others; each row names the processor its area ran on (times differ by up to"
        " twice between machines of one name). Do not edit by hand. The latest run's machine:",
        "",
        *machine_lines(),
        "",
        "| area | time (s) | mode | commit | date | CPU | command |",
        "| --- | ---: | --- | --- | --- | --- | --- |",
        *[f"| {s.area} | {s.seconds:.1f} | {s.mode} | {s.commit} | {s.date} | "
          f"{s.cpu or 'not recorded'} | `{s.command}` |" for s in sections],
        "",
    ]
    return "\n".join(lines) + "\n" + "\n".join(s.block() for s in sections)


def _ordered(sections: dict[str, Section]) -> list[Section]:
    known = all_areas()
    return sorted(sections.values(),
                  key=lambda s: (known.index(s.area) if s.area in known else len(known), s.area))


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the reduced benchmark (<15 min)")
    parser.add_argument("--out", type=Path, default=DOCS / "benchmarks.md")
    parser.add_argument("--only", nargs="*", choices=all_areas(),
                        help="run only these areas; the others' sections in --out are kept")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    command = shlex.join([os.path.relpath(sys.executable), "-m", "benchmarks.run",
                          *(argv if argv is not None else sys.argv[1:])])
    areas = args.only or all_areas()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    commit = git_commit()
    measured: dict[str, Section] = {}
    for area in areas:
        log.info("benchmark %s (%s)", area, "quick" if args.quick else "full")
        text, secs = run_area(area, args.quick)
        date = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        measured[area] = Section(area, text, secs, "QUICK" if args.quick else "full", commit,
                                 date, command, cpu_summary())
        log.info("benchmark %s done in %.1f s", area, secs)
        # Written after every area, so an interrupted run still leaves what it measured. With
        # --only the others' sections are read from the file as it is now, so that what a
        # run beside this one wrote meanwhile is kept.
        kept = read_sections(args.out.read_text()) if args.only and args.out.is_file() else {}
        args.out.write_text(build_document(_ordered({**kept, **measured})))
    log.info("wrote %s", args.out)
    if args.out.resolve() == (DOCS / "benchmarks.md").resolve():  # the project's, not a copy
        try:
            for document in results.update_documents():
                log.info("wrote the headline figures of %s", document)
        except ValueError as exc:
            log.warning("README.md's results table not written: %s", exc)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""GPU benchmark: whole jobs of presets ``preview`` (128 px) and ``standard`` (256 px) on CUDA.

The training benchmark's protocol (``benchmarks.bench_training``: the truck and the Duck, 6
training views in walking order, 12 held-out views, scored by ``evaluate_dataset``) with each
preset at its own photo size on the GPU: the full method, and the seconds of every stage of
the job. It answers "about a minute on a GPU" with a measured job time and test PSNR.

Where CUDA is present it runs, writes each preset's section into ``docs/bench_training_gpu.md``
between that preset's ``LATEST`` markers as soon as it is measured (the rest of that file
stays) and returns the sections. Where it is not (our 2-core machines, CI), it runs nothing and
returns the recorded sections, saying that they were not measured in this run.

Usage: ``python -m benchmarks.bench_gpu [--presets preview standard] [--meshes NAME...]
[--runs NAME...]`` (prints the sections).
"""

from __future__ import annotations

import argparse
import logging

from benchmarks.harness import DOCS, ROOT

RECORD = DOCS / "bench_training_gpu.md"
RUNS = ["full"]
PRESETS = {"preview": 128, "standard": 256}  # each preset at its own photo size


def markers(preset: str = "standard") -> tuple[str, str]:
    """The begin and end markers of a preset's latest section in the record."""
    tag = "" if preset == "standard" else f" {preset}"
    return f"<!-- LATEST{tag}: written by benchmarks.bench_gpu -->", f"<!-- /LATEST{tag} -->"


BEGIN, END = markers()


def latest(text: str, preset: str = "standard") -> str | None:
    """A preset's section between its markers in a record, or None when it has none."""
    begin, end = markers(preset)
    start, stop = text.find(begin), text.find(end)
    if start < 0 or stop < start:
        return None
    return text[start + len(begin):stop].strip()


def with_latest(text: str, section: str, preset: str = "standard") -> str:
    """The record with a preset's section between its markers replaced (added at the end when
    the record has no markers for it)."""
    begin, end = markers(preset)
    block = f"{begin}\n{section.strip()}\n{end}"
    start, stop = text.find(begin), text.find(end)
    if start < 0 or stop < start:
        return f"{text.rstrip()}\n\n{block}\n" if text.strip() else f"{block}\n"
    return text[:start] + block + text[stop + len(end):]


def _demote(section: str) -> str:
    """Headings one level down, to sit under this area's own heading."""
    return "\n".join(f"#{line}" if line.startswith("#") else line
                     for line in section.splitlines())


def _section(preset: str, meshes: list[str] | None, runs: list[str]) -> str:
    """One preset's part: measured where CUDA is present (and recorded), else the record's."""
    import torch

    heading = f"## Training on a GPU (preset `{preset}`, {PRESETS[preset]} px)"
    if not torch.cuda.is_available():
        recorded = latest(RECORD.read_text(), preset) if RECORD.is_file() else None
        if recorded is None:
            return f"{heading}\n\nNot measured: no CUDA device here and no recorded run.\n"
        return (f"{heading}\n\nNot measured in this run: no CUDA device here. The last "
                f"measurement on a GPU, recorded in `{RECORD.relative_to(ROOT)}` (which also "
                f"holds the runs that chose its schedule):\n\n{_demote(recorded)}\n")
    from benchmarks import bench_training

    section = bench_training.run(True, names=meshes, only=runs, preset=preset, device="cuda",
                                 size=PRESETS[preset])
    old = RECORD.read_text() if RECORD.is_file() else ""
    RECORD.write_text(with_latest(old, section, preset))
    return f"{heading}\n\n{_demote(section)}\n"


def run(quick: bool = True, presets: list[str] | None = None, meshes: list[str] | None = None,
        runs: list[str] | None = None) -> str:
    """The markdown section (see the module docstring): one part per preset (default: both),
    on ``meshes`` (default: ``--quick``'s two), runs ``runs`` (default: the full method).
    ``quick`` changes nothing: the GPU benchmark is the same set either way."""
    return "\n".join(_section(p, meshes, runs or RUNS) for p in presets or list(PRESETS))


def main() -> None:
    """Print the section; each preset's part is recorded as soon as it is measured."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", choices=list(PRESETS), default=None)
    parser.add_argument("--meshes", nargs="+", default=None)
    parser.add_argument("--runs", nargs="+", default=None)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    print(run(presets=args.presets, meshes=args.meshes, runs=args.runs))  # noqa: T201


if __name__ == "__main__":
    main()

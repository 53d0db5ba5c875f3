"""GPU benchmark: whole jobs of preset ``standard`` at 256 px on a CUDA device.

The training benchmark's protocol (``benchmarks.bench_training``: the truck and the Duck, 6
training views in walking order, 12 held-out views, scored by ``evaluate_dataset``) with the
default preset, 256-pixel photos and the GPU: the full method and the preset's own ablation
of G. It answers "about a minute on a GPU" with a measured job time and test PSNR.

Where CUDA is present it runs, writes its section into ``docs/bench_training_gpu.md`` between
the ``LATEST`` markers (the rest of that file stays) and returns the
section. Where it is not (our 2-core machines, CI), it runs nothing and returns the last
recorded section, saying that it was not measured in this run.

Usage: ``python -m benchmarks.bench_gpu`` (prints the section).
"""

from __future__ import annotations

import logging
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "docs" / "bench_training_gpu.md"
BEGIN = "<!-- LATEST: written by benchmarks.bench_gpu -->"
END = "<!-- /LATEST -->"
RUNS = ["full", "no G (D fitted in phase two)"]
PRESET = "standard"
SIZE = 256


def latest(text: str) -> str | None:
    """The section between the markers of a record, or None when it has none."""
    start, end = text.find(BEGIN), text.find(END)
    if start < 0 or end < start:
        return None
    return text[start + len(BEGIN):end].strip()


def with_latest(text: str, section: str) -> str:
    """The record with its section between the markers replaced (added at the end when the
    record has no markers)."""
    block = f"{BEGIN}\n{section.strip()}\n{END}"
    start, end = text.find(BEGIN), text.find(END)
    if start < 0 or end < start:
        return f"{text.rstrip()}\n\n{block}\n" if text.strip() else f"{block}\n"
    return text[:start] + block + text[end + len(END):]


def _demote(section: str) -> str:
    """Headings one level down, to sit under this area's own heading."""
    return "\n".join(f"#{line}" if line.startswith("#") else line
                     for line in section.splitlines())


def run(quick: bool = True) -> str:
    """The markdown section (see the module docstring). ``quick`` changes nothing: the GPU
    benchmark is the two-mesh set either way."""
    import torch

    heading = f"## Training on a GPU (preset `{PRESET}`, {SIZE} px)"
    if not torch.cuda.is_available():
        recorded = latest(RECORD.read_text()) if RECORD.is_file() else None
        if recorded is None:
            return f"{heading}\n\nNot measured: no CUDA device here and no recorded run.\n"
        return (f"{heading}\n\nNot measured in this run: no CUDA device here. The last "
                f"measurement on a GPU, recorded in `{RECORD.relative_to(ROOT)}` (which also "
                f"holds the runs that chose its schedule):\n\n{_demote(recorded)}\n")
    from benchmarks import bench_training

    section = bench_training.run(True, only=RUNS, preset=PRESET, device="cuda", size=SIZE)
    old = RECORD.read_text() if RECORD.is_file() else ""
    RECORD.write_text(with_latest(old, section))
    return f"{heading}\n\n{_demote(section)}\n"


def main() -> None:
    """Print the section."""
    logging.basicConfig(level=logging.INFO)
    print(run())  # noqa: T201 (the section is the command's output)


if __name__ == "__main__":
    main()

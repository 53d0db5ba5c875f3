"""The GPU benchmark's record: its latest section is replaced in place, the history stays, and
on a machine without CUDA the benchmark reports the recorded run as not measured here."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from benchmarks import bench_gpu


def test_with_latest_replaces_only_the_marked_section() -> None:
    first = bench_gpu.with_latest("# GPU\n\nintro\n", "## run 1\n\n22.36 dB")
    assert first.startswith("# GPU\n\nintro\n")
    assert bench_gpu.latest(first) == "## run 1\n\n22.36 dB"
    second = bench_gpu.with_latest(first + "\n## history\n\n180 s\n", "## run 2\n\n21.00 dB")
    assert bench_gpu.latest(second) == "## run 2\n\n21.00 dB"
    assert "run 1" not in second
    assert second.startswith("# GPU\n\nintro\n") and second.endswith("## history\n\n180 s\n")


def test_latest_without_markers_is_none() -> None:
    assert bench_gpu.latest("# nothing recorded\n") is None
    assert bench_gpu.latest(f"{bench_gpu.END} before {bench_gpu.BEGIN}") is None


def test_without_cuda_the_recorded_run_is_reported_not_measured(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    record = tmp_path / "docs" / "gpu.md"
    record.parent.mkdir()
    monkeypatch.setattr(bench_gpu, "ROOT", tmp_path)
    monkeypatch.setattr(bench_gpu, "RECORD", record)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert "no recorded run" in bench_gpu.run()
    record.write_text(bench_gpu.with_latest("# GPU\n", "## Training\n\n| full | 22.36 |"))
    section = bench_gpu.run()
    assert "Not measured in this run: no CUDA device here" in section
    assert "### Training" in section and "| full | 22.36 |" in section
    assert "docs/gpu.md" in section


def test_each_preset_keeps_its_own_section() -> None:
    record = bench_gpu.with_latest("# GPU\n", "## standard\n\n86 s")
    record = bench_gpu.with_latest(record, "## preview\n\n69 s", "preview")
    record = bench_gpu.with_latest(record, "## standard\n\n80 s")
    assert bench_gpu.latest(record) == "## standard\n\n80 s"
    assert bench_gpu.latest(record, "preview") == "## preview\n\n69 s"
    assert "86 s" not in record

"""The fidelity benchmark's pieces (``benchmarks.bench_fidelity``): the held-out photos, how far
the frame fit moved a camera, the table, and a clean skip without the captures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks import bench_fidelity
from benchmarks.bench_fidelity import camera_move, held_out_frames, table
from cadnerf_core.cameras import orbit_pose


def test_two_held_out_photos_with_kept_ones_on_both_sides() -> None:
    assert held_out_frames(8) == [2, 5]
    assert held_out_frames(10) == [3, 6]
    assert held_out_frames(4) == [2]
    for n in range(5, 12):
        frames = held_out_frames(n)
        assert len(frames) == 2 and 0 < frames[0] < frames[1] < n - 1


def test_camera_move_is_the_turn_and_the_share_of_the_distance() -> None:
    before = orbit_pose(20.0, 10.0, 4.0)
    after = before.copy()
    after[:3, :3] = Rotation.from_rotvec([0.0, np.radians(3.0), 0.0]).as_matrix() @ before[:3, :3]
    after[:3, 3] += [0.2, 0.0, 0.0]
    turn, shift = camera_move(before, after)
    assert turn == pytest.approx(3.0) and shift == pytest.approx(0.05)


def test_table_rows_and_means() -> None:
    row = {"capture": "thing", "model": "mug", "photos": 8, "kept": 6, "held_out": ["002", "005"],
           "masks": "dataset", "field": {"psnr": 20.0, "ssim": 0.5, "lpips": None},
           "mesh": {"psnr": 18.0, "ssim": 0.4, "lpips": None}, "whole_psnr": 22.0,
           "rotation_deg": 2.5, "fit_turn_deg": 0.4, "fit_shift": 0.01, "view_turn_deg": 1.5,
           "view_shift": 0.03, "focal_error": 0.02,
           "seconds": 100.0}
    lines = table([row, {**row, "capture": "other", "field": {"psnr": 22.0, "ssim": 0.7,
                                                              "lpips": None}}])
    assert "| thing | mug | 6/6 | 002, 005 | dataset | **20.00** | 0.500 | **18.00** |" in lines[2]
    assert "| 2.5 | 0.40, 1.0 | 1.50, 3.0 | +2 % | 100 |" in lines[2]
    assert "field **21.00 dB**, SSIM 0.600; mesh **18.00 dB**" in lines[-1]


def test_without_the_captures_the_section_says_so(monkeypatch: pytest.MonkeyPatch,
                                                  tmp_path: Path) -> None:
    monkeypatch.setattr(bench_fidelity, "CAPTURES", tmp_path / "absent")
    section = bench_fidelity.run(quick=True)
    assert section.startswith("## Fidelity") and "`../shared/eval` is absent" in section
    assert "python -m benchmarks.bench_fidelity --quick" in section


def test_a_full_run_records_the_mean_of_the_field_and_of_the_mesh(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from benchmarks import results

    monkeypatch.setattr(results, "RESULTS", tmp_path / "results.json")
    rows = [{"field": {"psnr": 20.0}, "mesh": {"psnr": 17.0}},
            {"field": {"psnr": 23.0}, "mesh": {"psnr": 18.0}}]
    bench_fidelity.record_means(rows)
    found = results.read_results()
    assert found["fidelity_field_psnr"].value == pytest.approx(21.5)
    assert found["fidelity_mesh_psnr"].value == pytest.approx(17.5)
    assert "2 real captures at 512 px" in found["fidelity_field_psnr"].quantity
    assert found["fidelity_mesh_psnr"].command.endswith("bench_fidelity --rows ROWS")

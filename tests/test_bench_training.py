"""The training benchmark's plan: `make bench` makes the ablations on the two Table 5 meshes and
the full method on every mesh, and reports the two means apart; `--quick` and `--meshes` make
every selected run on every mesh."""

from __future__ import annotations

from typing import Any

from benchmarks import training_plan as bt

MESHES = ["CesiumMilkTruck", "Duck", "spot"]
EVERY_RUN = [*bt.ABLATIONS, bt.ORACLE]


def test_whole_set_runs_ablations_on_the_table5_meshes_and_full_everywhere() -> None:
    plan = dict(bt.run_plan(MESHES, every_run_everywhere=False))
    assert plan[MESHES[0]] == EVERY_RUN and plan[MESHES[1]] == EVERY_RUN
    assert plan[MESHES[2]] == ["full"]


def test_quick_or_named_meshes_get_every_selected_run() -> None:
    plan = bt.run_plan(MESHES, every_run_everywhere=True)
    assert [runs for _, runs in plan] == [EVERY_RUN] * 3
    only = bt.run_plan(MESHES, every_run_everywhere=True, only=["no deformation", "full"])
    assert [runs for _, runs in only] == [["full", "no deformation"]] * 3


def test_a_mesh_outside_table5_is_left_out_when_full_is_not_selected() -> None:
    plan = bt.run_plan(MESHES, every_run_everywhere=False, only=["no CAD init"])
    assert [mesh for mesh, _ in plan] == ["CesiumMilkTruck", "Duck"]


def _row(mesh: str, name: str, psnr: float) -> tuple[str, str, dict[str, Any]]:
    return mesh, name, {"seed": 0, "psnr": psnr, "psnr_centred": psnr - 1,
                        "psnr_tta": psnr + 1, "rot_after": 3.0, "seconds": 100.0}


def test_whole_set_summary_keeps_the_table5_means_apart_from_every_mesh() -> None:
    rows = [_row("Duck", "full", 24.0), _row("CesiumMilkTruck", "full", 20.0),
            _row("Duck", "no deformation", 23.0), _row("spot", "full", 14.0)]
    text = "\n".join(bt.summaries(rows, every_run_everywhere=False))
    table5, everywhere = text.split("The full method over every mesh (3):")
    assert "| full | 22.00 |" in table5 and "| no deformation | 23.00 |" in table5
    assert "| full | 19.33 |" in everywhere and "no deformation" not in everywhere
    assert "| full | 19.33 |" in "\n".join(bt.summaries(rows, every_run_everywhere=True))

"""The README's results table: made from docs/results.json by ``benchmarks.results``, so the two
cannot drift apart; the renderer, the splice and the record keep one figure per quantity."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import results
from benchmarks.results import Result


def _result(key: str, value: float, unit: str = "dB", digits: int = 2) -> Result:
    return Result(key, f"the {key}", value, unit, digits, "2 CPU cores", f"make {key}",
                  "2026-11-28")


def test_readme_table_is_what_results_json_renders() -> None:
    recorded = results.read_results()
    assert recorded, "docs/results.json holds no figure"
    assert all(r.command for r in recorded.values()), "a figure without its command"
    table = results.render_table(results.ordered(recorded))
    assert results.readme_block(results.README.read_text()) == table, (
        "README.md's results table differs from docs/results.json: run "
        "`python -c 'from benchmarks import results; results.update_readme()'`")


def test_render_table_shows_each_value_with_its_digits_unit_and_conditions() -> None:
    table = results.render_table([_result("psnr", 20.8934), _result("iou", 0.9061, "", 3),
                                  _result("job", 156.6, "s", 0)])
    assert table.splitlines() == [
        "| quantity | value | conditions |", "| --- | --- | --- |",
        "| the psnr | 20.89 dB | 2 CPU cores |", "| the iou | 0.906 | 2 CPU cores |",
        "| the job | 157 s | 2 CPU cores |"]


def test_rows_follow_the_fixed_order_then_the_other_keys() -> None:
    found = {k: _result(k, 1.0) for k in ("zeta", "matching_ten_photos", "alpha",
                                          "unseen_psnr")}
    assert [r.key for r in results.ordered(found)] == [
        "unseen_psnr", "matching_ten_photos", "alpha", "zeta"]


def test_splice_replaces_only_the_block_between_the_markers() -> None:
    document = (f"# Title\n\nbefore\n\n{results.START}\nold table\n{results.END}\n\nafter\n")
    new = results.splice(document, "| new |\n")
    assert new == f"# Title\n\nbefore\n\n{results.START}\n| new |\n{results.END}\n\nafter\n"
    assert results.readme_block(new) == "| new |\n"
    with pytest.raises(ValueError, match="results:start"):
        results.splice("# no markers\n", "| new |\n")


def test_record_keeps_one_figure_per_key(tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    results.record(_result("unseen_psnr", 20.0), path)
    results.record(_result("masks_iou_robot", 0.9, "", 3), path)
    results.record(_result("unseen_psnr", 21.5), path)
    stored = json.loads(path.read_text())["results"]
    assert [(r["key"], r["value"]) for r in stored] == [("unseen_psnr", 21.5),
                                                        ("masks_iou_robot", 0.9)]


def test_update_readme_writes_the_recorded_figures(tmp_path: Path) -> None:
    path, readme = tmp_path / "results.json", tmp_path / "README.md"
    readme.write_text(f"intro\n{results.START}\n{results.END}\nrest\n")
    results.record(_result("unseen_psnr", 20.0), path)
    assert results.update_readme(readme, path)
    assert "| the unseen_psnr | 20.00 dB | 2 CPU cores |" in readme.read_text()
    assert readme.read_text().startswith("intro\n") and readme.read_text().endswith("rest\n")
    assert not results.update_readme(readme, path)  # nothing new: the file is left alone

"""The pairs benchmark's table (``benchmarks.bench_pairs``): one row a capture, then totals."""

from __future__ import annotations

from benchmarks.bench_pairs import table


def test_the_table_counts_each_kind_of_pair_and_totals_them() -> None:
    rows = [{"capture": "a", "pairs": 8, "plain_right": 5, "plain_wrong": 2, "orbit_right": 5,
             "orbit_wrong": 1, "all_right": 9, "all_wrong": 4, "mapper_right": 8,
             "mapper_wrong": 0},
            {"capture": "b", "pairs": 6, "plain_right": 1, "plain_wrong": 3, "orbit_right": 1,
             "orbit_wrong": 2, "all_right": 2, "all_wrong": 5, "mapper_right": 2,
             "mapper_wrong": 1}]
    lines = table(rows)
    assert lines[2] == "| a | 8 | 5 / 2 | 5 / 1 | 9 / 4 | 8 / 0 |"
    assert lines[-1] == "| **all** | 14 | 6 / 5 | 6 / 3 | 11 / 9 | 10 / 1 |"
    assert lines[0].count("|") == lines[1].count("|") == lines[2].count("|")

"""The start benchmark's summary counts (``benchmarks.bench_starts``)."""

from __future__ import annotations

from benchmarks.bench_starts import StartRow, summary_lines, table_lines


def _row(direction: int, guessed: bool, retrieved_deg: float, chosen_deg: float,
         chosen_direction: int = 1) -> StartRow:
    return StartRow("fuze", 40.0, direction, guessed, ("bottle", 1, retrieved_deg),
                    ("bottle", chosen_direction, chosen_deg), 3, 5.0)


def test_the_summary_counts_right_walks_per_direction_and_switches() -> None:
    rows = [_row(1, True, 12.0, 150.0, -1),  # a guess the start turned the wrong way
            _row(-1, True, 160.0, 14.0, -1),  # a guess the start turned the right way
            _row(-1, True, 158.0, 158.0),  # a guess left as it was: wrong
            _row(1, False, 9.0, 8.0)]  # not a guess
    ccw, cw, both, switched = summary_lines(rows)
    assert "flagged a guess on 1 of 2 walks" in ccw
    assert "retrieval's walk 1 of 1, the start chosen 0 of 1" in ccw
    assert "retrieval 1 of 1, the start 1 of 1" in ccw
    assert "flagged a guess on 2 of 2 walks" in cw
    assert "retrieval's walk 0 of 2, the start chosen 1 of 2" in cw
    assert "retrieval's walk 1 of 3, the start chosen 1 of 3" in both
    assert "turned the walk round on 2, rightly on 1" in switched
    table = table_lines(rows)
    assert len(table) == 2 + len(rows)
    assert "| fuze | 40 | cw | yes | bottle +1 | 160.0 | bottle -1 | 14.0 | 3 | 5 |" in table

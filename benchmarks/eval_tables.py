"""Markdown tables for the benchmark sections: per-object rows plus a mean row."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

Row = dict[str, Any]


def fmt(value: Any, digits: int = 2) -> str:
    """One table cell: floats rounded, ``None`` as a dash, infinities spelled out."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:.{digits}f}"
    return str(value)


def markdown_table(columns: Sequence[tuple[str, str, int]], rows: Sequence[Row]) -> str:
    """A markdown table.

    Args:
        columns: (header, row key, digits) per column; the first column is left-aligned.
        rows: dicts holding the keys (missing keys print as a dash).
    Returns:
        The table, one line per row, without a trailing newline.
    """
    head = "| " + " | ".join(c[0] for c in columns) + " |"
    align = "| " + " | ".join("---" if i == 0 else "---:" for i in range(len(columns))) + " |"
    body = ["| " + " | ".join(fmt(row.get(key), digits) for _, key, digits in columns) + " |"
            for row in rows]
    return "\n".join([head, align, *body])


def mean_row(rows: Sequence[Row], label_key: str, label: str = "**mean**") -> Row:
    """The mean of every numeric key over rows that have a finite value for it.

    Args:
        rows: per-object rows.
        label_key: key of the label column (set to ``label``).
        label: text of the label cell.
    Returns:
        A row; keys with no finite value in any row are ``None``.
    """
    keys = {k for row in rows for k, v in row.items()
            if isinstance(v, int | float) and not isinstance(v, bool)}
    out: Row = {label_key: label}
    for key in sorted(keys):
        values = [float(row[key]) for row in rows
                  if isinstance(row.get(key), int | float) and not isinstance(row.get(key), bool)
                  and math.isfinite(float(row[key]))]
        out[key] = sum(values) / len(values) if values else None
    return out


def with_mean(rows: Sequence[Row], label_key: str) -> list[Row]:
    """Rows followed by their mean row (nothing added for no rows)."""
    return [*rows, mean_row(rows, label_key)] if rows else []


def worst(rows: Sequence[Row], key: str, lower_is_worse: bool = True) -> Row | None:
    """The row with the worst finite value of ``key`` (lowest by default), or ``None``."""
    finite = [r for r in rows if isinstance(r.get(key), int | float)
              and math.isfinite(float(r[key]))]
    if not finite:
        return None
    pick: Callable[..., Row] = min if lower_is_worse else max
    return pick(finite, key=lambda r: float(r[key]))

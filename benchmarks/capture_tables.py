"""The capture benchmark's tables: one row a job (``capture_jobs``), then what they add up to."""

from __future__ import annotations

from typing import Any

import numpy as np

from benchmarks.capture_jobs import VARIANTS

UNTEXTURED = {"dino_ring": "matte white ceramic", "dino_walk": "matte white ceramic"}
"""Captures whose object shows next to no texture (the acceptance's median leaves them out)."""
WORSE_MARGIN_DEG = 2.0
"""How much worse than silhouettes alone the matches may leave a capture's cameras."""
GOOD_DEG = 10.0
"""A capture's cameras count as good within this median rotation error (the acceptance's
share of captures)."""


def final_error(row: dict[str, Any]) -> float:
    """The row's last cameras' error: refined after training, else (cameras only) started."""
    refined = row.get("refined")
    return float(row["started"] if refined is None else refined)


def _cell(value: Any, form: str, bold: bool = False) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "-"
    text = format(value, form)
    return f"**{text}**" if bold else text


def _pairs(row: dict[str, Any]) -> str:
    if "pairs_right" not in row:
        return str(row.get("pairs", "-"))
    used = "" if "used_right" not in row else f" ({row['used_right']} / {row['used_wrong']})"
    return f"{row['pairs_right']} / {row['pairs_wrong']}{used}"


def _registered(row: dict[str, Any]) -> str:
    registered = row.get("registered")
    return "-" if registered is None else f"{registered}/{row.get('kept', row['photos'])}"


def table(rows: list[dict[str, Any]]) -> list[str]:
    """The per-job table and the summary lines (``summary``)."""
    lines = ["| capture | variant | model | photos | spacing (deg) | EXIF | registered | "
             "pairs right / wrong (used) | start | retrieved (deg) | started (deg) | "
             "refined (deg) | mirrored | focal error | PSNR (dB) | seconds |",
             "|---|---|---|---:|---:|---|---:|---:|---|---:|---:|---:|---|---:|---:|---:|"]
    for r in rows:
        focal = "-" if r.get("focal") is None else f"{100 * r['focal']:+.0f} %"
        refined = r.get("refined")
        lines.append(
            f"| {r['capture']} | {r['variant']} | {r.get('model', '')} | "
            f"{r.get('kept', r['photos'])}/{r['photos']} | {_cell(r.get('spacing'), '.0f')} | "
            f"{'yes' if r.get('exif') else 'no'} | {_registered(r)} | {_pairs(r)} | "
            f"{r.get('start', '')} | "
            f"{_cell(r['retrieved'], '.1f')} | {_cell(r['started'], '.1f', refined is None)} | "
            f"{_cell(refined, '.1f', True)} | {_mirrored(r)} | {focal} | "
            f"{_cell(r.get('psnr'), '.2f')} | {_cell(r.get('seconds'), '.0f')} |")
    return [*lines, "", *summary(rows)]


def _mirrored(row: dict[str, Any]) -> str:
    return "" if row.get("mirrored") is None else ("yes" if row["mirrored"] else "no")


def textured_errors(rows: list[dict[str, Any]], variant: str) -> list[float]:
    """The last cameras' errors (``final_error``) of ``variant``'s jobs on captures with
    texture."""
    return [final_error(r) for r in rows if r["variant"] == variant
            and r["capture"] not in UNTEXTURED]


def summary(rows: list[dict[str, Any]]) -> list[str]:
    """Per variant: the median error over the textured captures, the share within
    ``GOOD_DEG``, the mirrored walks; then the captures the matches left worse than
    silhouettes alone."""
    lines = []
    stage = "refined" if all(r.get("refined") is not None for r in rows) else "started"
    for variant in VARIANTS:
        errors = textured_errors(rows, variant)
        if not errors:
            continue
        flipped = sum(bool(r.get("mirrored")) for r in rows if r["variant"] == variant)
        good = sum(e <= GOOD_DEG for e in errors)
        lines.append(f"- {variant}: median {stage} rotation error over the {len(errors)} "
                     f"textured captures **{np.median(errors):.1f} deg**; within "
                     f"{GOOD_DEG:.0f} deg: {good} of {len(errors)} "
                     f"({100 * good / len(errors):.0f} %); mirrored walks: {flipped}.")
    worse = worse_than_silhouettes(rows)
    if worse is not None:
        lines.append("- matches worse than silhouettes alone by more than "
                     f"{WORSE_MARGIN_DEG:.0f} degrees: "
                     + (", ".join(f"{name} ({gap:+.1f})" for name, gap in worse) or "none")
                     + ".")
    return lines


def worse_than_silhouettes(rows: list[dict[str, Any]]) -> list[tuple[str, float]] | None:
    """The textured captures whose error with the matches exceeds the one on silhouettes
    alone by more than ``WORSE_MARGIN_DEG`` (name, difference); None when no capture ran
    both ways."""
    error = {(r["capture"], r["variant"]): final_error(r) for r in rows}
    both = [name for name, variant in error if variant == "matches"
            and (name, "silhouettes") in error and name not in UNTEXTURED]
    if not both:
        return None
    gaps = [(name, error[(name, "matches")] - error[(name, "silhouettes")]) for name in both]
    return [(name, gap) for name, gap in gaps if gap > WORSE_MARGIN_DEG]

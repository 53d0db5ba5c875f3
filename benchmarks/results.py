"""The headline figures: ``docs/results.json`` and the README's results table made from it.

Each benchmark that measures a headline figure records it here (``record``) when it runs in
full (a QUICK run leaves them alone): one value per quantity, with the command that made it,
the conditions it was measured in ("2 CPU cores", "one GPU": never a processor's name) and
the day. ``make bench`` (``benchmarks.run``) then renders the table between the README's
markers ``<!-- results:start -->`` and ``<!-- results:end -->`` (``update_readme``);
``tests/test_bench_results.py`` checks that the README's table is what the file renders.

Elsewhere a document quotes a headline figure only between ``<!-- result:KEY -->`` and
``<!-- /result -->`` (``FIGURE``): ``update_documents`` rewrites each such figure from the file,
and ``tests/test_docs.py`` fails where one differs from it or a figure stands unmarked.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
from dataclasses import asdict, dataclass
from pathlib import Path

from benchmarks.harness import DOCS, ROOT

RESULTS = DOCS / "results.json"
README = ROOT / "README.md"
START = "<!-- results:start -->"
END = "<!-- results:end -->"
FIGURE = re.compile(r"<!-- result:(\w+) -->(.*?)<!-- /result -->", re.S)
"""A headline figure quoted in a document: its key, then the figure as the table shows it."""
DOCUMENTS = (README, *sorted(DOCS.glob("*.md")))
"""The documents whose quoted figures ``update_documents`` keeps current."""
# The table's rows in this order; a key not listed follows them, by name.
ORDER = ("unseen_psnr", "unseen_rotation", "captures_users_rotation", "captures_real_rotation",
         "captures_textured_rotation", "fidelity_field_psnr", "fidelity_mesh_psnr",
         "mesh_f_score", "masks_iou_espresso", "masks_iou_robot",
         "preview_job_photos", "preview_job_cpu", "preview_job_gpu", "matching_ten_photos")


@dataclass(frozen=True)
class Result:
    """One headline figure."""

    key: str  # what it is, for the code: e.g. ``unseen_psnr``
    quantity: str  # what it is, for a reader (the table's first column)
    value: float
    unit: str  # after the value: "dB", "degrees (median)", "s"
    digits: int  # decimals shown
    conditions: str  # where and how: "leave-out, 78 jobs, 2 CPU cores"
    command: str  # the command that measured it
    date: str  # UTC day it was measured, YYYY-MM-DD

    def text(self) -> str:
        """The value as the table shows it."""
        return f"{self.value:.{self.digits}f} {self.unit}".rstrip()


def cpu_cores() -> str:
    """This machine's usable cores, as a figure's conditions name them: "2 CPU cores"."""
    count = len(os.sched_getaffinity(0))
    return f"{count} CPU core{'s' if count != 1 else ''}"


def today() -> str:
    """The UTC day, as ``Result.date`` holds it."""
    return dt.datetime.now(dt.UTC).strftime("%Y-%m-%d")


def read_results(path: Path | None = None) -> dict[str, Result]:
    """The recorded figures by key (none where the file is absent; default ``RESULTS``)."""
    path = path or RESULTS
    if not path.is_file():
        return {}
    return {item["key"]: Result(**item) for item in json.loads(path.read_text())["results"]}


def ordered(results: dict[str, Result]) -> list[Result]:
    """The figures in the table's order (``ORDER``, then the others by key)."""
    rank = {key: i for i, key in enumerate(ORDER)}
    return sorted(results.values(), key=lambda r: (rank.get(r.key, len(ORDER)), r.key))


def write_results(results: dict[str, Result], path: Path | None = None) -> None:
    """Write the figures, in the table's order (default ``RESULTS``)."""
    path = path or RESULTS
    items = [asdict(r) for r in ordered(results)]
    path.write_text(json.dumps({"results": items}, indent=1) + "\n")


def record(result: Result, path: Path | None = None) -> None:
    """Record one figure in place of the one of its key (read again just before, so that what
    another benchmark recorded meanwhile is kept)."""
    write_results({**read_results(path), result.key: result}, path)


def render_table(results: list[Result]) -> str:
    """The README's markdown table of the figures (quantity | value | conditions)."""
    lines = ["| quantity | value | conditions |", "| --- | --- | --- |"]
    lines += [f"| {r.quantity} | {r.text()} | {r.conditions} |" for r in results]
    return "\n".join(lines) + "\n"


def splice(document: str, table: str) -> str:
    """``document`` with ``table`` between its results markers, the rest as it was.

    Raises:
        ValueError: the markers are missing or out of order.
    """
    start, end = document.find(START), document.find(END)
    if start < 0 or end < start:
        raise ValueError(f"no {START} ... {END} block")
    return document[:start + len(START)] + "\n" + table + document[end:]


def readme_block(document: str) -> str:
    """What stands between the results markers of ``document``."""
    start, end = document.find(START), document.find(END)
    if start < 0 or end < start:
        raise ValueError(f"no {START} ... {END} block")
    return document[start + len(START):end].lstrip("\n")


def update_readme(readme: Path | None = None, path: Path | None = None) -> bool:
    """Render the recorded figures (default ``RESULTS``) into the README's block (default
    ``README``). Returns whether it changed."""
    readme = readme or README
    old = readme.read_text()
    new = splice(old, render_table(ordered(read_results(path))))
    if new != old:
        readme.write_text(new)
    return new != old


def quoted_figures(document: str) -> list[tuple[str, str]]:
    """The headline figures ``document`` quotes: (key, text as written), in order."""
    return [(match.group(1), match.group(2)) for match in FIGURE.finditer(document)]


def splice_figures(document: str, results: dict[str, Result]) -> str:
    """``document`` with each quoted figure of a recorded key written from ``results``."""
    def current(match: re.Match[str]) -> str:
        found = results.get(match.group(1))
        text = match.group(2) if found is None else found.text()
        return f"<!-- result:{match.group(1)} -->{text}<!-- /result -->"

    return FIGURE.sub(current, document)


def update_documents(path: Path | None = None) -> list[Path]:
    """The README's table and every quoted figure in ``DOCUMENTS`` from the recorded figures
    (default ``RESULTS``). Returns the documents changed."""
    changed = [README] if update_readme(path=path) else []
    recorded = read_results(path)
    for document in DOCUMENTS:
        old = document.read_text()
        new = splice_figures(old, recorded)
        if new != old:
            document.write_text(new)
            changed.append(document)
    return sorted(set(changed))

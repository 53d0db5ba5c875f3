"""docs/architecture.md against the code: the library's numbers, the progress stages, the stage
subpackages and every API name the document lists. Either side drifting fails here."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

from cadnerf_core.intake.crop import DEFAULT_MARGIN
from cadnerf_core.library.format import LibrarySpec

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "architecture.md").read_text()
CORE = ROOT / "cadnerf_core"


def _number(pattern: str, group: int = 1) -> float:
    found = re.search(pattern, " ".join(DOC.split()))
    assert found is not None, f"docs/architecture.md no longer says {pattern!r}"
    return float(found.group(group))


def test_the_library_numbers_are_the_code_defaults() -> None:
    spec = LibrarySpec()
    steps = {b - a for a, b in zip(spec.elevations, spec.elevations[1:], strict=False)}
    assert _number(r"(\d+) azimuths x \d+ elevations") == spec.n_azimuths
    assert _number(r"\d+ azimuths x (\d+) elevations") == len(spec.elevations)
    assert _number(r"elevations \(0 to (\d+) degrees") == max(spec.elevations)
    assert min(spec.elevations) == 0 and steps == {_number(r"([\d.]+)-degree steps\)")}
    assert _number(r"= (\d+) views a model") == spec.n_views
    assert _number(r"camera distance ([\d.]+)") == spec.distance
    assert _number(r"view `a \* (\d+) \+ e`") == len(spec.elevations)
    assert _number(r"renders (\d+) px") == spec.render_size
    assert _number(r"at a (\d+)-degree horizontal field of view") == spec.fov_deg
    assert _number(r"silhouettes (\d+) px") == spec.silhouette_size
    assert _number(r"with margin ([\d.]+)") == spec.margin == DEFAULT_MARGIN
    assert _number(r"occupancy grids (\d+) cells") == spec.grid_size
    assert _number(r"Near set: distance ([\d.]+)") == spec.near_distance
    assert _number(r"Near set: distance [\d.]+ at (\d+) degrees") == spec.near_fov_deg


def _reported_stages() -> set[str]:
    """Stage names the core passes to its progress calls (``.step("x", ...)`` and the phases'
    ``_report(progress, "x", ...)``), read from the source."""
    stages = set()
    for path in CORE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Call):
                continue
            name = getattr(node.func, "attr", None) or getattr(node.func, "id", None)
            if name not in ("step", "_report"):
                continue
            for arg in node.args[:2]:
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                    stages.add(arg.value)
    return stages


def test_the_documented_stages_are_those_the_core_reports() -> None:
    found = re.search(r"Stage names, in order: (.*?)\.\n", DOC, re.S)
    assert found is not None
    documented = re.findall(r"`(\w+)`", found.group(1))
    assert documented[:2] == ["masks", "retrieval"] and len(set(documented)) == len(documented)
    assert set(documented) == _reported_stages()


def test_every_stage_subpackage_has_its_section() -> None:
    packages = sorted(p.parent.name for p in CORE.glob("*/__init__.py"))
    assert packages, "no subpackages found"
    for name in packages:
        assert f"### `cadnerf_core/{name}/`" in DOC, f"docs/architecture.md lacks {name}/"
    for name in re.findall(r"### `cadnerf_core/(\w+)/`", DOC):
        assert name in packages, f"docs/architecture.md documents a missing cadnerf_core/{name}/"


def _api_names() -> list[str]:
    """The dotted names that open each line of the document's python blocks."""
    names = []
    for block in re.findall(r"```python\n(.*?)```", DOC, re.S):
        names += [m.group(1) for m in re.finditer(r"^([a-z_]+(?:\.\w+)+)", block, re.M)]
    return names


@pytest.mark.parametrize("dotted", _api_names())
def test_every_documented_api_name_exists(dotted: str) -> None:
    parts = dotted.split(".")
    for cut in range(len(parts) - 1, 0, -1):
        try:
            obj: object = importlib.import_module("cadnerf_core." + ".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attribute in parts[cut:]:
            assert hasattr(obj, attribute), f"{dotted}: no {attribute}"
            obj = getattr(obj, attribute)
        return
    pytest.fail(f"{dotted}: no such module in cadnerf_core")


def test_the_job_folder_section_lists_every_file_the_owner_names() -> None:
    from cadnerf_core import jobfolder

    section = DOC.split("\n## Job folder\n", 1)[1].split("\n## ", 1)[0]
    names = [jobfolder.INPUTS, jobfolder.CONFIG, jobfolder.RETRIEVAL, jobfolder.MASK_SOURCES,
             jobfolder.RESULT, jobfolder.WARNINGS,
             jobfolder.POSES, jobfolder.TRANSFORMS, jobfolder.METRICS, jobfolder.ORBIT_VIDEO,
             jobfolder.MESH, jobfolder.LOG, jobfolder.overlay_name(0).replace("000", "NNN")]
    assert [n for n in names if n not in section] == []


# Each headline figure once: docs/results.json (``benchmarks.results``).

HAND_WRITTEN = ("README.md", "docs/guide.md", "docs/presets.md", "docs/architecture.md",
                "docs/reliability.md")
"""The documents written by hand (the others are benchmarks' output, of which each headline
figure is recorded from)."""


def _documents() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_every_quoted_headline_figure_is_the_one_in_results_json() -> None:
    from benchmarks import results

    recorded = results.read_results()
    quoted = {str(p.relative_to(ROOT)): results.quoted_figures(p.read_text())
              for p in _documents()}
    assert quoted["docs/presets.md"], "the presets page quotes no headline figure"
    wrong = {name: [(key, text) for key, text in figures
                    if key not in recorded or text != recorded[key].text()]
             for name, figures in quoted.items()}
    assert not {name: bad for name, bad in wrong.items() if bad}, (
        "a quoted figure differs from docs/results.json: run "
        "`python -c 'from benchmarks import results; results.update_documents()'`")


def _unmarked(text: str) -> str:
    """``text`` without its results table and its quoted figures."""
    from benchmarks import results

    start, end = text.find(results.START), text.find(results.END)
    if 0 <= start < end:
        text = text[:start] + text[end:]
    return results.FIGURE.sub("", text)


def test_hand_written_docs_state_a_headline_figure_only_quoted() -> None:
    """A figure restated by hand would stay behind when the benchmark runs again."""
    from benchmarks import results

    stated = {}
    for name in HAND_WRITTEN:
        text = " ".join(_unmarked((ROOT / name).read_text()).split())
        for r in results.read_results().values():
            figure = f"{r.value:.{r.digits}f}" + (f" {r.unit.split()[0]}" if r.unit else "")
            if re.search(rf"(?<![\d.]){re.escape(figure)}(?![\d])", text):
                stated.setdefault(name, []).append((r.key, figure))
    assert not stated, f"quote these as <!-- result:KEY -->...<!-- /result -->: {stated}"


def test_splicing_writes_each_quoted_figure_from_the_recorded_one() -> None:
    from benchmarks.results import Result, quoted_figures, splice_figures

    recorded = {"job": Result("job", "a job", 101.4, "s", 0, "2 CPU cores", "make job",
                              "2026-12-01")}
    old = "took <!-- result:job -->157 s<!-- /result -->, <!-- result:gone -->1 s<!-- /result -->"
    new = splice_figures(old, recorded)
    assert quoted_figures(new) == [("job", "101 s"), ("gone", "1 s")]


@pytest.mark.parametrize("name", HAND_WRITTEN)
def test_the_hand_written_docs_point_at_nothing_outside_the_repository(name: str) -> None:
    path = ROOT / name
    text = path.read_text()
    targets = re.findall(r"\]\(([^)#\s]+)", text)  # links (``../x`` in code is an example)
    outside = [t for t in targets if not t.startswith(("http://", "https://"))
               and not (path.parent / t).resolve().is_relative_to(ROOT)]
    assert not outside, f"{name} points outside the repository: {outside}"
    assert "/work/" not in text and "../shared" not in text


def test_the_reliability_page_holds_what_is_held_not_a_history_of_defects() -> None:
    text = (ROOT / "docs" / "reliability.md").read_text()
    headings = re.findall(r"^#+ (.*)$", text, re.M)
    assert not [h for h in headings if re.search(r"defect|fix|bug", h, re.I)], headings
    assert not re.search(r"\bFix:|\(fix \d+\)", text)

"""The dependency direction of STYLE.md, checked in fresh interpreters through sys.modules."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules_after(code: str) -> set[str]:
    script = f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, env={"PATH": "/usr/bin:/bin",
                                                       "CADNERF_REDIS_URL": "redis://127.0.0.1:1/0"})
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.strip().splitlines()[-1]))


def _top(modules: set[str]) -> set[str]:
    return {name.split(".")[0] for name in modules}


@pytest.mark.parametrize("code", [
    "import app",
    "import app.main\napp.main.create_app()",
    "import app.state, app.queue, app.uploads, app.results, app.embedded, app.client",
])
def test_the_service_never_imports_torch(code: str) -> None:
    modules = _modules_after(code)
    assert "torch" not in _top(modules)
    light = {"cadnerf_core.config", "cadnerf_core.jobfolder", "cadnerf_core.jobnames",
             "cadnerf_core.jobstorage",
             "cadnerf_core.progress", "cadnerf_core.errors", "cadnerf_core.config_bounds",
             "cadnerf_core.config_retrieval", "cadnerf_core.config_matches",
             "cadnerf_core.config_client", "cadnerf_core.jobresult", "cadnerf_core.intake",
             "cadnerf_core.intake.limits",
             "cadnerf_core.facade"}  # the contracts the service shares with the core
    assert not {m for m in modules if m.startswith("cadnerf_core.")} - light


def test_the_app_reaches_the_core_only_through_app_core() -> None:
    reaching = {}
    for path in (ROOT / "app").rglob("*.py"):
        tree = ast.parse(path.read_text(), str(path))
        found = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
                 and (n.module or "").split(".")[0] == "cadnerf_core"]
        found += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import)
                  for a in n.names if a.name.split(".")[0] == "cadnerf_core"]
        if found:
            reaching[str(path.relative_to(ROOT))] = found
    assert "app/core.py" in reaching  # the check sees imports at all
    assert set(reaching) == {"app/core.py"}, reaching


def _names(path: Path) -> set[str]:
    """Every name, attribute and string constant a file spells."""
    tree = ast.parse(path.read_text(), str(path))
    return ({n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
            | {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
            | {n.name for n in ast.walk(tree) if isinstance(n, ast.alias)}
            | set(_strings(path)))


def test_the_app_serves_the_result_the_pipeline_wrote_and_reads_no_stage_file() -> None:
    """The result is built once, by the pipeline (``result.json``); the API reads neither the
    retrieval's nor the poses' file, nor remakes the warnings."""
    stage_files = {"read_retrieval", "read_poses", "read_metrics", "read_warnings",
                   "read_mask_sources", "RETRIEVAL", "POSES", "METRICS", "WARNINGS",
                   "retrieval.json", "poses.json", "job_warnings", "walk_order"}
    seen = {str(p.relative_to(ROOT)): _names(p) for p in (ROOT / "app").rglob("*.py")}
    assert "read_result" in seen["app/results.py"]  # the check sees the reader at all
    assert not {f: names & stage_files for f, names in seen.items() if names & stage_files}


def test_the_core_never_imports_the_service_stack() -> None:
    modules = _top(_modules_after("import cadnerf_core"))
    assert not modules & {"fastapi", "starlette", "celery", "kombu", "redis", "app", "worker"}


def test_the_worker_task_module_stays_light_until_a_job_runs() -> None:
    modules = _top(_modules_after("import worker.tasks, worker.celery_app"))
    assert "torch" not in modules and "fastapi" not in modules


def _app_imports(path: Path) -> list[str]:
    """Modules of ``app`` a file imports (``from app import x`` counts as ``app.x``)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.split(".")[0] == "app"]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "app":
                found += [f"app.{a.name}" for a in node.names]
            elif node.module.startswith("app."):
                found.append(node.module)
    return found


def test_the_worker_imports_from_app_only_the_state_package_and_the_settings() -> None:
    imports = {str(p.relative_to(ROOT)): _app_imports(p) for p in (ROOT / "worker").glob("*.py")}
    assert any(imports.values())  # the check sees the worker's imports at all
    outside = {f: [m for m in mods if m not in ("app.state", "app.settings")]
               for f, mods in imports.items()}
    assert not {f: mods for f, mods in outside.items() if mods}


def test_the_worker_loads_no_other_part_of_app() -> None:
    modules = _modules_after("import worker.tasks, worker.celery_app, worker.runner, "
                             "worker.liveness, worker.progress, worker.webhook")
    apps = {m for m in modules if m.split(".")[0] == "app"}
    assert "app.state" in apps
    assert not {m for m in apps if m not in ("app", "app.settings", "app.core")
                and not m.startswith("app.state")}


def test_the_state_package_loads_no_web_queue_or_torch() -> None:
    modules = _top(_modules_after("import app.state, app.settings\napp.settings.load_settings()"))
    assert not modules & {"fastapi", "starlette", "celery", "kombu", "torch", "worker"}


def _strings(path: Path) -> list[str]:
    """String literals of a file, f-strings' literal parts included."""
    tree = ast.parse(path.read_text(), str(path))
    return [n.value for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str)]


def test_redis_key_names_are_spelled_in_one_place() -> None:
    keys_module = ROOT / "app" / "state" / "keys.py"
    assert any("cadnerf:" in s or s == "cadnerf" for s in _strings(keys_module))
    for folder in ("app", "worker", "cadnerf_cli"):
        for path in (ROOT / folder).rglob("*.py"):
            if path != keys_module:
                assert not [s for s in _strings(path) if "cadnerf:" in s], path
    # The Lua scripts build no key: every key comes in through KEYS.
    for script in _strings(ROOT / "app" / "state" / "scripts.py"):
        if "redis.call" in script:
            assert "cadnerf" not in script and ".." not in script, script


STAGES = ("intake", "library", "retrieval", "cameras", "nerf", "export", "evaluation", "mesh")


@pytest.mark.parametrize("stage", STAGES)
def test_each_stage_names_its_public_functions_and_loads_them_on_use(stage: str) -> None:
    import importlib

    package = importlib.import_module(f"cadnerf_core.{stage}")
    assert package.__all__ and set(package.__all__) <= set(dir(package))
    for name in package.__all__:
        assert callable(getattr(package, name)) or name.isupper(), name
    with pytest.raises(AttributeError, match="no attribute"):
        _ = package.not_a_public_name
    # Importing the facade loads none of its modules (nor torch) until a name is used.
    modules = _modules_after(f"import cadnerf_core.{stage}")
    assert "torch" not in _top(modules)
    loaded = {m for m in modules if m.startswith(f"cadnerf_core.{stage}.")}
    assert loaded <= {"cadnerf_core.cameras.conventions"}, loaded

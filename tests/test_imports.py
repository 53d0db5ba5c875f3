"""The dependency direction of STYLE.md, checked in fresh interpreters through sys.modules."""

from __future__ import annotations

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
    "import app.store, app.queue, app.uploads, app.results, app.embedded, app.client",
])
def test_the_service_never_imports_torch(code: str) -> None:
    modules = _modules_after(code)
    assert "torch" not in _top(modules)
    assert not {m for m in modules if m.startswith("cadnerf_core.")} - {"cadnerf_core.config",
                                                                       "cadnerf_core.jobfolder"}


def test_the_core_never_imports_the_service_stack() -> None:
    modules = _top(_modules_after("import cadnerf_core"))
    assert not modules & {"fastapi", "starlette", "celery", "kombu", "redis", "app", "worker"}


def test_the_worker_task_module_stays_light_until_a_job_runs() -> None:
    modules = _top(_modules_after("import worker.tasks, worker.celery_app"))
    assert "torch" not in modules and "fastapi" not in modules

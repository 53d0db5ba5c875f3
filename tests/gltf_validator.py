"""The Khronos glTF validator (npm package ``gltf-validator``, run on node) for tests, with the
reasons to skip where it cannot run."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

VALIDATOR = Path(__file__).resolve().parents[1] / "node_modules" / "gltf-validator"

_SCRIPT = ("const v = require(process.argv[1]); const fs = require('fs');"
           "v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])))"
           ".then(r => console.log(JSON.stringify(r.issues)))"
           ".catch(e => { console.error(String(e)); process.exit(2); });")


def _why_not() -> str | None:
    """Why the validator cannot run here, or None."""
    if shutil.which("node") is None:
        return "node is not installed (the Khronos glTF validator runs on node)"
    if not VALIDATOR.is_dir():
        return "node_modules/gltf-validator absent: run `make setup` (npm ci)"
    return None


_WHY_NOT = _why_not()
needs_validator = pytest.mark.skipif(_WHY_NOT is not None, reason=_WHY_NOT or "")
"""Mark a test that runs ``validate``: skipped, with the reason, where it cannot run."""


def validate(glb: Path) -> dict[str, Any]:
    """The validator's ``issues`` report of a binary glTF file (``numErrors``,
    ``numWarnings``, ``messages`` with ``severity`` 0 = error, 1 = warning)."""
    run = subprocess.run(["node", "-e", _SCRIPT, str(VALIDATOR), str(glb)],
                         capture_output=True, text=True, timeout=120, check=True)
    issues: dict[str, Any] = json.loads(run.stdout)
    return issues


def assert_no_errors_or_warnings(glb: Path) -> None:
    """Fail with the errors and warnings listed unless the validator reports none."""
    issues = validate(glb)
    problems = [m for m in issues["messages"] if m["severity"] <= 1]
    assert (issues["numErrors"], issues["numWarnings"]) == (0, 0), problems

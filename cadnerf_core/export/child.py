"""Native steps of the export in a child process: xatlas's unwrap and USD's package.

Both libraries keep the interpreter while they work (their bindings hold the GIL; USD's
thread pool can deadlock against it), xatlas for over twenty seconds on a noisy surface and
for ever on the meshes it hangs on. Inside the job's process that silences the worker's
heartbeat (the service then takes the running job for orphaned) and a cancel waits for it. In
a child the job only waits on a pipe: the heartbeat goes on, a cancel or delete ends the child
at once, and a child that fails or runs past its limit costs that one output, never the job.

A child is ``python -m <module>`` whose ``__main__`` calls ``serve``: arrays in as ``.npz`` on
stdin, arrays out as ``.npz`` on stdout.
"""

from __future__ import annotations

import io
import logging
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

POLL_S = 0.25
"""How often the wait asks whether the job was cancelled."""

Arrays = dict[str, np.ndarray]


def child_command(module: str) -> list[str]:
    """The command line of a child running ``module`` with this process's Python."""
    return [sys.executable, "-m", module]


def _npz(arrays: Mapping[str, Any]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


def run_child(module: str, given: Mapping[str, Any], limit_s: float, what: str,
              check: Callable[[], None] | None = None) -> Arrays | None:
    """Run ``module``'s ``serve`` on ``given`` in a child process and return what it wrote.

    Args:
        module: the child's module (``python -m module``).
        given: arrays (or scalars and strings) the child reads.
        limit_s: the longest wait.
        what: names the step in the log (``"xatlas (20000 triangles)"``).
        check: called while waiting; whatever it raises (a cancel) ends the child and passes on.
    Returns:
        The child's arrays, or None (with the reason logged) when it failed or passed
        ``limit_s``.
    """
    with tempfile.TemporaryFile() as sent:  # a file: a pipe would need a writer of its own
        sent.write(_npz(given))
        sent.seek(0)
        child = subprocess.Popen(child_command(module), stdin=sent, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE)
    deadline = time.monotonic() + limit_s
    try:
        while True:
            try:
                out, err = child.communicate(timeout=POLL_S)
                break
            except subprocess.TimeoutExpired:
                if check is not None:
                    check()
                if time.monotonic() > deadline:
                    log.warning("%s did not finish in %.0f s; stopped", what, limit_s)
                    return None
    finally:
        if child.poll() is None:
            child.kill()
            child.communicate()
    if child.returncode != 0:
        lines = err.decode(errors="replace").strip().splitlines()
        log.warning("%s failed: %s", what, lines[-1] if lines else
                    f"exit status {child.returncode}")
        return None
    answer = np.load(io.BytesIO(out))
    return {key: answer[key] for key in answer.files}


def serve(work: Callable[[Arrays], Mapping[str, Any]]) -> None:
    """The child's side: ``work`` on the arrays from stdin, its arrays to stdout."""
    given = np.load(io.BytesIO(sys.stdin.buffer.read()))
    sys.stdout.buffer.write(_npz(work({key: given[key] for key in given.files})))
    sys.stdout.buffer.flush()

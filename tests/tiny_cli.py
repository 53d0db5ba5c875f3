"""``cadnerf`` with the suite's ``tiny`` preset registered: what the tests' child processes run
(``python -m tests.tiny_cli worker``), and the app factory of their uvicorn processes
(``tests.tiny_cli:create_app``)."""

from __future__ import annotations

from typing import Any

import tests.configs  # noqa: F401  (registers the tiny preset)
from cadnerf_cli.main import main


def create_app() -> Any:
    """``app.main.create_app`` in a process that knows the tiny preset."""
    from app.main import create_app as create

    return create()


if __name__ == "__main__":
    main()

"""Lazy public names for a subpackage's ``__init__`` (as trimesh's and SciPy's lazy loaders do):
``from cadnerf_core.cameras import place_cameras`` loads ``cameras.stage`` only then, so a
package is cheap to import and torch loads only with the module that needs it."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any


def lazy_exports(package: str, exports: Mapping[str, Sequence[str]],
                 ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """A module ``__getattr__`` and ``__dir__`` serving ``exports``' names from their modules.

    Args:
        package: the package's ``__name__``.
        exports: module name (relative to the package) -> the public names it holds.
    Returns:
        ``(__getattr__, __dir__)`` for the package's namespace.
    """
    owner = {name: module for module, names in exports.items() for name in names}

    def get(name: str) -> Any:
        module = owner.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    def names() -> list[str]:
        return sorted(set(owner) | set(vars(sys.modules[package])))

    return get, names

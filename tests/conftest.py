"""Shared fixtures: a tiny CAD library built once per test session, and (for the service
tests) the real-Redis fixtures of tests/redis_fixture.py."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest


def pytest_configure(config: pytest.Config) -> None:
    """Load the shared real-Redis fixtures (tests/redis_fixture.py) and the S3 endpoint's
    (tests/s3_fixture.py) once for the session."""
    from tests import redis_fixture, s3_fixture

    if not config.pluginmanager.is_registered(redis_fixture):
        config.pluginmanager.register(redis_fixture, "cadnerf_redis_fixture")
    if not config.pluginmanager.is_registered(s3_fixture):
        config.pluginmanager.register(s3_fixture, "cadnerf_s3_fixture")


TINY_MODELS = ["chair_wood", "mug", "cuboid_slab"]
"""Models of the tiny library: a chair, a mug and a cuboid."""


def build_tiny_library(root: Path) -> Path:
    """Build the tiny library into ``root``: 8 azimuths x 2 elevations, 32 px crops, 32^3 grid.

    Returns:
        The library folder.
    """
    from cadnerf_core.library.format import LibrarySpec
    from library_data.build import build_library

    spec = LibrarySpec(n_azimuths=8, elevations=(0.0, 30.0), silhouette_size=32, grid_size=32)
    build_library(root, spec, jobs=1, model_ids=TINY_MODELS)
    return root


@pytest.fixture(scope="session")
def tiny_library_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Folder of the tiny library (built once per session; do not modify it)."""
    return build_tiny_library(tmp_path_factory.mktemp("tiny_library") / "library")


@pytest.fixture(scope="session")
def tiny_library(tiny_library_dir: Path) -> Any:
    """The tiny library, loaded (a ``library.format.Library``; its folder is ``.root``)."""
    from cadnerf_core.library.format import load_library

    return load_library(tiny_library_dir)

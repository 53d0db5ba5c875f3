"""The export's native steps in child processes: xatlas's atlas (a child that fails, hangs or
is cancelled leaves a grid of triangles, or the cancel, instead of a held worker) and USD's
package (a child that fails leaves the job without mesh.usdz)."""

from __future__ import annotations

import logging
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
from PIL import Image

from cadnerf_core.export import atlas, child, usdz
from cadnerf_core.export.texture import PADDING, bake_texture, rasterize_uv


def _sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=2, radius=0.6)


class _Spy:
    """subprocess.Popen that keeps every child it starts."""

    def __init__(self) -> None:
        self.children: list[subprocess.Popen[bytes]] = []
        self.popen = subprocess.Popen

    def __call__(self, *args: Any, **kwargs: Any) -> subprocess.Popen[bytes]:
        child: subprocess.Popen[bytes] = self.popen(*args, **kwargs)
        self.children.append(child)
        return child


@pytest.fixture()
def spy(monkeypatch: pytest.MonkeyPatch) -> _Spy:
    spy = _Spy()
    monkeypatch.setattr(child.subprocess, "Popen", spy)
    return spy


def test_xatlas_runs_in_the_child_with_the_same_atlas(monkeypatch: pytest.MonkeyPatch,
                                                       spy: _Spy) -> None:
    mesh = _sphere()
    here = atlas.xatlas_atlas(mesh.vertices, mesh.faces, 128, PADDING)
    monkeypatch.setitem(sys.modules, "xatlas", None)  # importing it here now fails
    there = atlas.unwrap(mesh.vertices, mesh.faces, 128, PADDING)
    assert len(spy.children) == 1 and spy.children[0].returncode == 0
    for ours, theirs in zip(here, there, strict=True):
        assert np.array_equal(ours, theirs)
    vmapping, faces, uv = there
    assert len(faces) == len(mesh.faces) and vmapping.max() < len(mesh.vertices)
    assert np.allclose(mesh.vertices[vmapping][faces], mesh.vertices[mesh.faces], atol=1e-6)


def test_a_grid_atlas_gives_every_triangle_its_own_texels() -> None:
    faces = _sphere().faces
    vmapping, split, uv = atlas.grid_atlas(faces, 256, PADDING)
    assert np.array_equal(vmapping[split], faces)  # the same corners, each vertex split
    assert (uv > 0).all() and (uv < 1).all()
    texel, face, _ = rasterize_uv(uv, split, 256, margin=0.0)
    assert set(face.tolist()) == set(range(len(faces)))  # every triangle covers a texel
    owners = {}
    for t, f in zip(texel.tolist(), face.tolist(), strict=True):
        owners.setdefault(t, f)
    assert len(owners) == len(texel)  # and no texel is claimed by two


@pytest.mark.parametrize("command", [
    [sys.executable, "-c", "raise SystemExit('xatlas crashed')"],  # fails
    [sys.executable, "-c", "import time; time.sleep(60)"],  # hangs past the limit
])
def test_a_child_that_fails_or_hangs_leaves_the_grid(monkeypatch: pytest.MonkeyPatch,
                                                     spy: _Spy, command: list[str]) -> None:
    monkeypatch.setattr(child, "child_command", lambda module: command)
    mesh = _sphere()
    got = atlas.unwrap(mesh.vertices, mesh.faces, 128, PADDING, limit_s=1.0)
    for ours, grid in zip(got, atlas.grid_atlas(mesh.faces, 128, PADDING), strict=True):
        assert np.array_equal(ours, grid)
    assert spy.children[0].poll() is not None  # no child left behind


def test_a_cancel_while_waiting_ends_the_child(monkeypatch: pytest.MonkeyPatch,
                                               spy: _Spy) -> None:
    monkeypatch.setattr(child, "child_command",
                        lambda module: [sys.executable, "-c", "import time; time.sleep(60)"])

    class Cancelled(Exception):
        pass

    def check() -> None:
        raise Cancelled

    mesh = _sphere()
    with pytest.raises(Cancelled):
        bake_texture(mesh, lambda p, d: np.zeros((len(p), 3), np.float32), 64, check)
    assert spy.children[0].poll() is not None


def test_usd_writes_the_package_in_a_child(tmp_path: Path, spy: _Spy) -> None:
    pytest.importorskip("pxr", reason="Pixar's USD (usd-core) is not installed")
    mesh = bake_texture(_sphere(), lambda p, d: np.full((len(p), 3), 0.5, np.float32), 64)
    texture = tmp_path / "texture.png"
    Image.fromarray(mesh.texture).save(texture)
    assert usdz.write_usdz(tmp_path / "mesh.usdz", mesh, texture)
    assert spy.children[-1].args[-1] == usdz.__name__ and spy.children[-1].returncode == 0
    assert zipfile.is_zipfile(tmp_path / "mesh.usdz")


def test_a_usd_child_that_fails_leaves_no_package(tmp_path: Path, spy: _Spy,
                                                  monkeypatch: pytest.MonkeyPatch,
                                                  caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(usdz, "usd_available", lambda: True)
    monkeypatch.setattr(child, "child_command",
                        lambda module: [sys.executable, "-c", "raise SystemExit('USD crashed')"])
    mesh = bake_texture(_sphere(), lambda p, d: np.zeros((len(p), 3), np.float32), 16)
    with caplog.at_level(logging.WARNING):
        assert not usdz.write_usdz(tmp_path / "mesh.usdz", mesh, tmp_path / "texture.png")
    assert not (tmp_path / "mesh.usdz").exists()
    assert "USD crashed" in caplog.text and "mesh.usdz skipped" in caplog.text


def test_a_child_slow_to_read_still_gets_all_it_is_given(monkeypatch: pytest.MonkeyPatch) -> None:
    """More than a pipe holds, read only after the parent's first wait has timed out."""
    echo = "import time; time.sleep(1.0); from cadnerf_core.export.child import serve; serve(dict)"
    monkeypatch.setattr(child, "child_command", lambda module: [sys.executable, "-c", echo])
    given = {"big": np.arange(300_000, dtype=np.float64), "name": "mesh.usdz"}
    got = child.run_child("echo", given, 60.0, "echo")
    assert got is not None and np.array_equal(got["big"], given["big"])
    assert str(got["name"]) == "mesh.usdz"

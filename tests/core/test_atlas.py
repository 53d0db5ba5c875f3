"""The UV atlas: xatlas runs in a child process, and a child that fails, hangs or is cancelled
leaves a grid of triangles (or the cancel) instead of a held worker."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import numpy as np
import pytest
import trimesh

from cadnerf_core.export import atlas
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
    monkeypatch.setattr(atlas.subprocess, "Popen", spy)
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
    monkeypatch.setattr(atlas, "child_command", lambda: command)
    mesh = _sphere()
    got = atlas.unwrap(mesh.vertices, mesh.faces, 128, PADDING, limit_s=1.0)
    for ours, grid in zip(got, atlas.grid_atlas(mesh.faces, 128, PADDING), strict=True):
        assert np.array_equal(ours, grid)
    assert spy.children[0].poll() is not None  # no child left behind


def test_a_cancel_while_waiting_ends_the_child(monkeypatch: pytest.MonkeyPatch,
                                               spy: _Spy) -> None:
    monkeypatch.setattr(atlas, "child_command",
                        lambda: [sys.executable, "-c", "import time; time.sleep(60)"])

    class Cancelled(Exception):
        pass

    def check() -> None:
        raise Cancelled

    mesh = _sphere()
    with pytest.raises(Cancelled):
        bake_texture(mesh, lambda p, d: np.zeros((len(p), 3), np.float32), 64, check)
    assert spy.children[0].poll() is not None

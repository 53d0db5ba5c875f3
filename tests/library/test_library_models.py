"""The parametric models: watertight, normalised, deterministic, oriented, varied."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from library_data.basic import CUBOIDS
from library_data.catalog import LICENCE, MODELS, SOURCE, ParametricModel, find_model


@pytest.fixture(scope="module")
def meshes() -> dict[str, trimesh.Trimesh]:
    return {m.id: m.mesh() for m in MODELS}


def test_catalog_covers_the_brief() -> None:
    objects = [m for m in MODELS if m.kind == "object"]
    assert len(objects) >= 24
    assert len({m.category for m in objects}) >= 18
    for category in ("chair", "car", "table"):
        assert sum(m.category == category for m in objects) >= 2
    basics = {m.id for m in MODELS if m.kind == "basic"}
    assert {"cylinder", "sphere"} <= basics and len(CUBOIDS) >= 4
    ratios = {tuple(sorted(np.round(np.array(v) / max(v), 3))) for v in CUBOIDS.values()}
    assert len(ratios) >= 4
    assert len({m.id for m in MODELS}) == len(MODELS)
    assert SOURCE == "parametric:cadnerf" and LICENCE.startswith("MIT")


@pytest.mark.parametrize("model", MODELS, ids=[m.id for m in MODELS])
def test_model_is_watertight_and_normalised(model: ParametricModel,
                                            meshes: dict[str, trimesh.Trimesh]) -> None:
    mesh = meshes[model.id]
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    lo, hi = mesh.bounds
    assert np.allclose((lo + hi) / 2, 0.0, atol=1e-6)
    assert np.linalg.norm(mesh.vertices, axis=1).max() == pytest.approx(1.0, abs=1e-6)
    assert 12 <= len(mesh.faces) <= 6000  # modest: 24-32 circular segments


def test_models_are_byte_for_byte_deterministic(meshes: dict[str, trimesh.Trimesh]) -> None:
    for model in MODELS:
        again = model.mesh()
        assert again.export(file_type="ply") == meshes[model.id].export(file_type="ply"), model.id


def _centroid(mesh: trimesh.Trimesh, where: np.ndarray) -> np.ndarray:
    return np.asarray(mesh.vertices[where].mean(axis=0))


def test_models_face_plus_z_with_y_up(meshes: dict[str, trimesh.Trimesh]) -> None:
    chair = meshes["chair_wood"]
    assert _centroid(chair, chair.vertices[:, 1] > 0.3)[2] < -0.2  # the back is behind the seat
    plane = meshes["airplane"]
    assert plane.vertices[np.argmax(plane.vertices[:, 2])][1] == pytest.approx(0.0, abs=0.15)
    fin = plane.vertices[plane.vertices[:, 1] > 0.2]
    assert fin[:, 2].max() < -0.5  # the tail fin is at the back
    for car_id in ("car_sedan", "car_suv"):
        car = meshes[car_id]
        roof = car.vertices[car.vertices[:, 1] > car.bounds[1, 1] - 0.05]
        assert roof[:, 2].mean() < 0.0, car_id  # cabin set back from the bonnet at +Z
    toilet, bed = meshes["toilet"], meshes["bed"]
    assert _centroid(toilet, toilet.vertices[:, 1] > 0.3)[2] < 0  # cistern at the back
    assert _centroid(bed, bed.vertices[:, 1] > 0.1)[2] < -0.5  # headboard at the back
    monitor = meshes["monitor"]
    assert monitor.extents[2] < 0.5 * monitor.extents[0]  # a thin panel facing +Z


def _top(mesh: trimesh.Trimesh, depth: float = 0.15) -> np.ndarray:
    """Vertices within ``depth`` of the mesh's highest point."""
    return np.asarray(mesh.vertices[mesh.vertices[:, 1] > mesh.bounds[1, 1] - depth])


def _front_tip(mesh: trimesh.Trimesh) -> np.ndarray:
    """The vertex furthest toward +Z."""
    return np.asarray(mesh.vertices[np.argmax(mesh.vertices[:, 2])])


def test_added_common_objects_face_plus_z(meshes: dict[str, trimesh.Trimesh]) -> None:
    # What sticks up is at the back: a backrest, a cargo box, a boot's shaft, a shoe's heel.
    for model_id in ("armchair", "truck", "boot", "sneaker"):
        assert _top(meshes[model_id])[:, 2].mean() < -0.2, model_id
    # Heads are in front and up.
    for model_id in ("duck_toy", "cow_toy", "dog_toy"):
        assert _top(meshes[model_id])[:, 2].mean() > 0.2, model_id
    # Toes are in front and low; a drill's bit is in front and high; an espresso machine's
    # portafilter handle sticks out in front at mid height.
    for model_id in ("boot", "sneaker"):
        assert _front_tip(meshes[model_id])[1] < -0.3, model_id
    assert _front_tip(meshes["drill"])[1] > 0.2
    assert abs(_front_tip(meshes["espresso_machine"])[1]) < 0.2


def test_find_model() -> None:
    assert find_model("mug").category == "mug"
    with pytest.raises(KeyError):
        find_model("no_such_model")

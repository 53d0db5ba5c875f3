"""The texture cue for the walking direction, on rendered walks round a textured cylinder."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
from cadnerf_core.cameras.direction import walk_direction_evidence
from cadnerf_core.config import RetrievalConfig
from cadnerf_core.intake.photos import canonical_masks
from cadnerf_core.mesh.renderer import MeshRenderer
from cadnerf_core.retrieval.posesearch import cyclic_dp
from cadnerf_core.retrieval.search import direction_evidence
from cadnerf_core.retrieval.walks import solve_poses

SIZE = 128


def _cylinder(textured: bool) -> trimesh.Trimesh:
    """A body of revolution (same silhouette from every side), with a colour ramp round it
    and a few irregular stripes, or plain grey."""
    mesh = trimesh.creation.cylinder(radius=0.5, height=1.4, sections=180)
    angle = np.arctan2(mesh.vertices[:, 0], mesh.vertices[:, 2])  # [-pi, pi]
    ramp = (angle + np.pi) / (2 * np.pi)
    stripes = (np.sin(7.0 * angle + 2.0 * np.sin(3.0 * angle)) > 0.3).astype(float)
    rgb = np.stack([ramp, 0.3 + 0.6 * stripes, 1.0 - ramp], axis=1) if textured \
        else np.full((len(angle), 3), 0.6)
    colours = np.concatenate([(255 * rgb).astype(np.uint8),
                              np.full((len(angle), 1), 255, np.uint8)], axis=1)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
    return mesh


def _walk(mesh: trimesh.Trimesh, direction: int, n: int = 6, start: float = 37.0,
          elevation: float = 20.0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    renderer = MeshRenderer(mesh)
    K = intrinsics_from_fov(40.0, SIZE)
    images, masks = [], []
    for i in range(n):
        view = renderer.render(K, orbit_pose(start + direction * i * 360.0 / n, elevation, 4.0),
                               SIZE, SIZE)
        images.append(view.rgb)
        masks.append(view.mask)
    return images, masks


def _evidence(images: list[np.ndarray], masks: list[np.ndarray]) -> float:
    _, boxes = canonical_masks(masks, 64, 0.1)
    return direction_evidence(images, masks, boxes)


@pytest.mark.parametrize("direction", [1, -1])
def test_texture_tells_the_walking_direction_round_a_symmetric_object(direction: int) -> None:
    images, masks = _walk(_cylinder(textured=True), direction)
    evidence = _evidence(images, masks)
    # Clear evidence, of the walk's sign, and above the threshold the solver uses.
    assert np.sign(evidence) == direction
    assert abs(evidence) >= RetrievalConfig().appearance_threshold


def test_a_plain_object_gives_no_evidence() -> None:
    images, masks = _walk(_cylinder(textured=False), 1)
    assert abs(_evidence(images, masks)) < RetrievalConfig().appearance_threshold


def test_evidence_of_one_photo_or_none_is_zero() -> None:
    rgb = np.ones((1, 32, 32, 3), np.float32)
    assert walk_direction_evidence(rgb, np.ones((1, 32, 32), bool)) == 0.0


def test_evidence_decides_the_direction_only_when_the_silhouettes_cannot() -> None:
    n_az, n_el = 12, 2
    az_index = np.repeat(np.arange(n_az), n_el)
    config = RetrievalConfig()
    flat = np.full((4, n_az * n_el), 0.8)  # a symmetric object: every view fits equally
    assert solve_poses(flat, az_index, n_az, config).direction == 1  # the tie-break
    assert solve_poses(flat, az_index, n_az, config, evidence=-1.0).direction == -1
    weak = -0.9 * config.appearance_threshold
    assert solve_poses(flat, az_index, n_az, config, evidence=weak).direction == 1
    # A clear decreasing walk in the silhouettes outweighs texture evidence for +1.
    walk = np.full((4, n_az * n_el), 0.2)
    for p, a in enumerate((9, 6, 3, 0)):
        walk[p, a * n_el] = 0.95
    assert cyclic_dp(walk, az_index, n_az, spread_weight=config.spread_weight).direction == -1
    assert solve_poses(walk, az_index, n_az, config, evidence=2.0).direction == -1

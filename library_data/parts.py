"""Solid building blocks for the parametric CAD models, on top of manifold3d.

Every helper returns a ``manifold3d.Manifold`` (a closed, oriented solid), so any union or
difference of them is watertight by construction. Coordinates are in the model's own units
(roughly metres) with +Y up and the object's front toward +Z; ``to_trimesh`` normalises.
"""

from __future__ import annotations

from collections.abc import Sequence

import manifold3d as mf
import numpy as np
import trimesh

SEGMENTS = 28  # circular segments: round enough for 128 px silhouettes, few triangles

Vec = Sequence[float]


def box(size: Vec, center: Vec = (0.0, 0.0, 0.0)) -> mf.Manifold:
    """Axis-aligned box of ``size`` (x, y, z) centred at ``center``."""
    return mf.Manifold.cube(tuple(float(s) for s in size), center=True).translate(
        tuple(float(c) for c in center))


def _frame_to(direction: np.ndarray) -> np.ndarray:
    """Rotation [3, 3] taking +Z onto the unit vector ``direction``."""
    z = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def place(solid: mf.Manifold, rotation: np.ndarray,
          translation: Vec | np.ndarray) -> mf.Manifold:
    """Apply ``x -> rotation @ x + translation`` to a solid."""
    matrix = np.concatenate([rotation, np.asarray(translation, dtype=np.float64)[:, None]], 1)
    return solid.transform(matrix)


def rod(p0: Vec, p1: Vec, r0: float, r1: float | None = None,
        segments: int = SEGMENTS) -> mf.Manifold:
    """Cylinder (or cone frustum) from point ``p0`` (radius ``r0``) to ``p1`` (radius ``r1``)."""
    a, b = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    length = float(np.linalg.norm(b - a))
    top = r0 if r1 is None else r1
    solid = mf.Manifold.cylinder(length, r0, top, segments)
    return place(solid, _frame_to(b - a), a)


def ball(center: Vec, radius: float, segments: int = SEGMENTS) -> mf.Manifold:
    """Sphere."""
    return mf.Manifold.sphere(radius, segments).translate(tuple(float(c) for c in center))


def ellipsoid(center: Vec, radii: Vec, segments: int = SEGMENTS) -> mf.Manifold:
    """Axis-aligned ellipsoid with semi-axes ``radii``."""
    return mf.Manifold.sphere(1.0, segments).scale(tuple(float(r) for r in radii)).translate(
        tuple(float(c) for c in center))


def rounded_box(size: Vec, radius: float, center: Vec = (0.0, 0.0, 0.0),
                segments: int = 16) -> mf.Manifold:
    """Box with all edges rounded by ``radius`` (convex hull of eight corner spheres)."""
    half = np.asarray(size, dtype=np.float64) / 2.0 - radius
    corners = [ball(np.asarray(center) + half * np.array(s), radius, segments)
               for s in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)]
    return mf.Manifold.batch_hull(corners)


def torus(center: Vec, major: float, minor: float, axis: str = "y", sweep_deg: float = 360.0,
          segments: int = SEGMENTS) -> mf.Manifold:
    """Torus (or an arc of one, from angle 0 in the plane normal to ``axis``).

    Args:
        center: centre of the ring.
        major: ring radius; minor: tube radius.
        axis: the ring's axis, "x", "y" or "z".
        sweep_deg: arc angle; the arc starts on the local +X side (see ``_AXES``).
    """
    ring = mf.CrossSection.circle(minor, 16).translate((major, 0.0)).revolve(segments, sweep_deg)
    return place(ring, _AXES[axis], center)


# Rotations taking a solid built around +Z (revolve, cylinder) to one around the named axis.
_AXES = {
    "z": np.eye(3),
    "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
    "x": np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]),
}


def lathe(profile: Sequence[tuple[float, float]], segments: int = SEGMENTS,
          base: Vec = (0.0, 0.0, 0.0), axis: str = "y") -> mf.Manifold:
    """Solid of revolution of a closed (radius, height) profile about ``axis`` through ``base``."""
    section = mf.CrossSection([np.asarray(profile, dtype=np.float64)], mf.FillRule.NonZero)
    return place(section.revolve(segments), _AXES[axis], base)


def slab(outline: Sequence[tuple[float, float]], thickness: float, axis: str = "z",
         offset: float = 0.0) -> mf.Manifold:
    """Prism: a 2-D ``outline`` extruded ``thickness`` along ``axis``, centred on ``offset``.

    The outline's (u, v) coordinates are (x, y) for axis "z", (z, y) for "x", (x, -z) for "y".
    """
    section = mf.CrossSection([np.asarray(outline, dtype=np.float64)], mf.FillRule.NonZero)
    solid = section.extrude(thickness).translate((0.0, 0.0, offset - thickness / 2.0))
    if axis == "z":
        return solid
    if axis == "x":
        return solid.transform(np.array([[0.0, 0, 1, 0], [0, 1, 0, 0], [1, 0, 0, 0]]))
    return solid.transform(np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]]))


def union(parts: Sequence[mf.Manifold]) -> mf.Manifold:
    """Boolean union of solids."""
    return mf.Manifold.batch_boolean(list(parts), mf.OpType.Add)


def subtract(solid: mf.Manifold, cutters: Sequence[mf.Manifold]) -> mf.Manifold:
    """``solid`` minus every cutter."""
    return mf.Manifold.batch_boolean([solid, *cutters], mf.OpType.Subtract)


def mirror_x(parts: Sequence[mf.Manifold]) -> list[mf.Manifold]:
    """The parts and their mirror images across the x = 0 plane."""
    return [*parts, *(p.mirror((1.0, 0.0, 0.0)) for p in parts)]


def to_trimesh(solid: mf.Manifold) -> trimesh.Trimesh:
    """Normalised triangle mesh of a solid: bbox centre at the origin, max |vertex| = 1.

    Vertices are rounded to 1e-9 so the bytes do not depend on float noise.

    Raises:
        ValueError: if the solid is empty or not a valid manifold.
    """
    if solid.status() != mf.Error.NoError or solid.is_empty():
        raise ValueError(f"invalid solid: {solid.status()}")
    mesh = solid.to_mesh()
    vertices = np.asarray(mesh.vert_properties[:, :3], dtype=np.float64)
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    lo, hi = vertices.min(0), vertices.max(0)
    vertices = vertices - (lo + hi) / 2.0
    vertices /= np.linalg.norm(vertices, axis=1).max()
    return trimesh.Trimesh(np.round(vertices, 9), faces, process=True)

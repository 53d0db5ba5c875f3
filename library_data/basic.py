"""Basic shapes: cuboids of several aspect ratios, a cylinder and a sphere.

They catch objects the library has no close model for (boxes, cans, balls).
"""

from __future__ import annotations

import manifold3d as mf

from library_data.parts import SEGMENTS, box, rod

# Cuboid proportions (x, y, z): +Y is up, so "tower" stands and "plate" lies flat.
CUBOIDS: dict[str, tuple[float, float, float]] = {
    "cube": (1.0, 1.0, 1.0),
    "bar": (3.0, 1.0, 1.0),
    "tower": (1.0, 3.0, 1.0),
    "plate": (2.0, 0.4, 2.0),
    "slab": (2.0, 1.0, 0.5),
}


def cuboid(name: str) -> mf.Manifold:
    """Cuboid with the named proportions from ``CUBOIDS``."""
    return box(CUBOIDS[name])


def cylinder() -> mf.Manifold:
    """Upright cylinder as tall as it is wide."""
    return rod((0.0, -0.5, 0.0), (0.0, 0.5, 0.0), 0.5, segments=32)


def sphere() -> mf.Manifold:
    """Sphere."""
    return mf.Manifold.sphere(1.0, SEGMENTS + 4)

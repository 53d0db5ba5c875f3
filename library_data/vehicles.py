"""Parametric vehicles: airliner, sedan, SUV, delivery truck, bicycle.

Units are roughly metres; +Y up, the vehicle travels toward +Z (its front).
"""

from __future__ import annotations

import manifold3d as mf

from library_data.parts import (
    ball,
    box,
    ellipsoid,
    mirror_x,
    rod,
    slab,
    subtract,
    torus,
    union,
)


def airplane() -> mf.Manifold:
    """Airliner: fuselage with nose and tail cone, swept wings with engines, tailplane, fin."""
    fuselage = rod((0, 0, -1.5), (0, 0, 1.2), 0.2)
    nose = ellipsoid((0.0, 0.0, 1.2), (0.2, 0.2, 0.42))
    tail = rod((0, 0, -1.5), (0, 0.12, -2.1), 0.2, 0.05)
    wings = mirror_x([slab([(0.0, -0.5), (1.6, 0.35), (1.6, 0.6), (0.0, 0.3)], 0.05, "y", -0.06)])
    tailplane = mirror_x([slab([(0.0, 1.55), (0.62, 1.9), (0.62, 2.02), (0.0, 1.98)], 0.03,
                               "y", 0.1)])
    fin = slab([(-1.4, 0.12), (-1.95, 0.2), (-2.1, 0.78), (-1.85, 0.78)], 0.03, "x")
    engines = mirror_x([rod((0.62, -0.2, 0.45), (0.62, -0.2, -0.05), 0.1),
                        box((0.03, 0.12, 0.3), (0.62, -0.1, 0.08))])
    return union([fuselage, nose, tail, *wings, *tailplane, fin, *engines])


def _wheels(axle_z: tuple[float, float], radius: float, half_track: float,
            width: float) -> list[mf.Manifold]:
    """Four wheels (tyre plus hub) on axles along X at the given z positions."""
    out = []
    for z in axle_z:
        for side in (-1.0, 1.0):
            x0, x1 = side * (half_track - width / 2), side * (half_track + width / 2)
            out.append(rod((x0, radius, z), (x1, radius, z), radius))
            out.append(rod((x1, radius, z), (x1 + side * 0.02, radius, z), radius * 0.55))
    return out


def _arches(axle_z: tuple[float, float], radius: float) -> list[mf.Manifold]:
    """Wheel-arch cutters through the whole body width."""
    return [rod((-1.2, radius, z), (1.2, radius, z), radius * 1.18) for z in axle_z]


def car_sedan() -> mf.Manifold:
    """Saloon car: low body with bonnet and boot, glasshouse cabin, four wheels."""
    axles = (1.35, -1.35)
    body = slab([(-2.25, 0.28), (2.2, 0.28), (2.28, 0.55), (2.15, 0.76), (0.95, 0.86),
                 (-1.65, 0.88), (-2.2, 0.84), (-2.3, 0.55)], 1.8, "x")
    cabin = slab([(1.0, 0.82), (0.25, 1.32), (-1.05, 1.32), (-1.75, 0.85)], 1.56, "x")
    mirrors = mirror_x([box((0.16, 0.06, 0.08), (0.9, 0.95, 0.75))])
    shell = subtract(union([body, cabin, *mirrors]), _arches(axles, 0.33))
    return union([shell, *_wheels(axles, 0.33, 0.78, 0.22)])


def car_suv() -> mf.Manifold:
    """Sport utility vehicle: tall boxy body, upright cabin, roof rails, rear spare wheel."""
    axles = (1.4, -1.3)
    body = slab([(-2.2, 0.42), (2.2, 0.42), (2.3, 0.7), (2.22, 1.02), (1.3, 1.12),
                 (-2.22, 1.12), (-2.28, 0.7)], 1.9, "x")
    cabin = slab([(1.35, 1.05), (0.75, 1.78), (-2.1, 1.8), (-2.22, 1.05)], 1.72, "x")
    rails = mirror_x([box((0.05, 0.06, 2.3), (0.72, 1.83, -0.7))])
    spare = rod((0.0, 0.95, -2.25), (0.0, 0.95, -2.5), 0.36)
    shell = subtract(union([body, cabin, *rails]), _arches(axles, 0.38))
    return union([shell, spare, *_wheels(axles, 0.38, 0.8, 0.26)])


def truck() -> mf.Manifold:
    """Box delivery truck: tall cargo box at the back, lower cab at +Z, chassis, four wheels."""
    axles = (2.35, -1.7)
    cargo = box((2.3, 2.3, 4.3), (0.0, 2.05, -0.95))
    chassis = box((1.5, 0.35, 5.6), (0.0, 0.75, 0.2))
    cab = slab([(1.3, 0.45), (3.25, 0.45), (3.3, 1.25), (3.05, 1.45), (2.65, 2.45),
                (1.3, 2.5)], 2.2, "x")
    windscreen = slab([(3.03, 1.55), (2.68, 2.35), (2.5, 2.35), (2.85, 1.55)], 2.0, "x")
    bumper = box((2.3, 0.3, 0.2), (0.0, 0.6, 3.3))
    mirrors = mirror_x([box((0.1, 0.35, 0.08), (1.2, 1.8, 2.6)),
                        box((0.2, 0.05, 0.05), (1.1, 1.8, 2.6))])
    shell = subtract(union([cargo, cab, bumper, *mirrors]), [*_arches(axles, 0.5), windscreen])
    return union([shell, chassis, *_wheels(axles, 0.5, 0.9, 0.36)])


def bicycle() -> mf.Manifold:
    """Bicycle: two spoked-looking wheels, diamond frame, fork, handlebar, saddle, cranks."""
    parts: list[mf.Manifold] = []
    for z in (-0.52, 0.55):
        parts.append(torus((0.0, 0.35, z), 0.33, 0.022, "x"))
        parts.append(rod((-0.05, 0.35, z), (0.05, 0.35, z), 0.03, segments=12))
        for dy, dz in ((1.0, 0.0), (0.0, 1.0), (0.7, 0.7), (0.7, -0.7)):  # spokes
            parts.append(rod((0.0, 0.35 + 0.31 * dy, z + 0.31 * dz),
                             (0.0, 0.35 - 0.31 * dy, z - 0.31 * dz), 0.006, segments=6))
    bb, seat, head_top, head_low = (0, 0.3, 0), (0, 0.85, -0.14), (0, 0.85, 0.42), (0, 0.68, 0.46)
    tubes = [(bb, seat), (seat, head_top), (bb, head_low), (head_top, head_low),
             (bb, (0, 0.35, -0.52)), (seat, (0, 0.35, -0.52)), (head_low, (0, 0.35, 0.55))]
    parts += [rod(a, b, 0.018, segments=12) for a, b in tubes]
    parts.append(rod(head_top, (0.0, 0.98, 0.38), 0.015, segments=12))
    parts.append(rod((-0.25, 0.98, 0.38), (0.25, 0.98, 0.38), 0.014, segments=12))
    parts.append(rod(seat, (0.0, 0.92, -0.16), 0.013, segments=12))
    parts.append(ellipsoid((0.0, 0.94, -0.13), (0.07, 0.03, 0.13), 16))
    parts += [rod((0.0, 0.3, 0.0), (0.0, 0.45, 0.1), 0.012, segments=8),
              ball((0.0, 0.3, 0.0), 0.05, 12)]
    return union(parts)

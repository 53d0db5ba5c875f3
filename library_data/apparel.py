"""Parametric footwear: ankle boot, sneaker.

Units are roughly metres; the shoe stands on y = 0, +Y up, its toe toward +Z.
"""

from __future__ import annotations

import manifold3d as mf

from library_data.parts import Vec, box, ellipsoid, rod, rounded_box, subtract, union


def _sole(length: float, thickness: float, toe_spring: float) -> mf.Manifold:
    """Foot-shaped sole (narrow heel, wide ball, rounded toe) from z = -length/2 to +length/2,
    its toe raised by ``toe_spring``."""
    half = length / 2.0
    heel = rod((0, 0, -half + 0.035), (0, thickness, -half + 0.035), 0.035, segments=24)
    ball_ = rod((0, 0, 0.2 * half), (0, thickness, 0.2 * half), 0.048, segments=24)
    toe = rod((0.004, toe_spring, half - 0.04), (0.004, toe_spring + thickness, half - 0.04),
              0.04, segments=24)
    return mf.Manifold.batch_hull([heel, ball_, toe])


def _upper(length: float, ankle: Vec, ankle_radii: Vec) -> mf.Manifold:
    """Rounded upper over a sole of ``length``: hull of a toe box, a vamp and the ankle part."""
    half = length / 2.0
    return mf.Manifold.batch_hull([
        ellipsoid((0.002, 0.03, half - 0.055), (0.042, 0.028, 0.05), 20),
        ellipsoid((0.0, 0.045, 0.25 * half), (0.046, 0.04, 0.06), 20),
        ellipsoid(ankle, ankle_radii, 20),
    ])


def sneaker() -> mf.Manifold:
    """Low sneaker: thick foot-shaped sole, rounded upper with the collar opening at the heel,
    tongue, toe cap."""
    length = 0.28
    sole = _sole(length, 0.025, 0.012)
    upper = _upper(length, (0.0, 0.066, -0.085), (0.042, 0.046, 0.056))
    opening = ellipsoid((0.0, 0.112, -0.065), (0.03, 0.022, 0.055), 20)
    tongue = ellipsoid((0.0, 0.0, 0.0), (0.026, 0.01, 0.045), 20).rotate(
        (25.0, 0.0, 0.0)).translate((0.0, 0.084, -0.01))
    heel_tab = rounded_box((0.03, 0.04, 0.02), 0.008, (0.0, 0.1, -0.128))
    return union([sole, subtract(upper, [opening]), tongue, heel_tab])


def boot() -> mf.Manifold:
    """Ankle boot: sole with a heel block, rounded foot part, a shaft rising at the heel with
    an open top and a pull tab at the back."""
    length = 0.29
    sole = _sole(length, 0.018, 0.01)
    heel = rounded_box((0.07, 0.03, 0.075), 0.01, (0.0, 0.015, -0.1))
    foot = _upper(length, (0.0, 0.07, -0.07), (0.045, 0.05, 0.06)).translate((0.0, 0.01, 0.0))
    shaft_z = -0.065
    shaft = rod((0.0, 0.05, 0.0), (0.0, 0.19, 0.004), 0.05, 0.046, 28).scale(
        (1.0, 1.0, 1.15)).translate((0.0, 0.0, shaft_z))
    instep = mf.Manifold.batch_hull([ellipsoid((0.0, 0.055, 0.02), (0.046, 0.042, 0.05), 20),
                                     ellipsoid((0.0, 0.13, -0.055), (0.048, 0.03, 0.05), 20)])
    opening = rod((0.0, 0.16, 0.0), (0.0, 0.2, 0.0), 0.039, segments=24).scale(
        (1.0, 1.0, 1.15)).translate((0.0, 0.0, shaft_z + 0.004))
    tab = box((0.02, 0.045, 0.012), (0.0, 0.19, shaft_z - 0.05))
    return union([sole, heel, subtract(union([foot, instep, shaft]), [opening]), tab])

"""Parametric hand tools: cordless drill.

Units are roughly metres; +Y up, the working end (chuck and bit) toward +Z.
"""

from __future__ import annotations

import manifold3d as mf

from library_data.parts import ball, box, ellipsoid, rod, rounded_box, union


def drill() -> mf.Manifold:
    """Cordless drill: motor body along Z, clutch ring, chuck and bit at +Z, pistol grip with a
    trigger, battery pack under the grip."""
    axis_y = 0.18
    motor = rod((0, axis_y, -0.09), (0, axis_y, 0.05), 0.036, 0.034, 28)
    back = ellipsoid((0.0, axis_y, -0.09), (0.036, 0.036, 0.028), 20)
    gearbox = rod((0, axis_y, 0.05), (0, axis_y, 0.085), 0.031, 0.029, 28)
    clutch = rod((0, axis_y, 0.085), (0, axis_y, 0.102), 0.034, segments=28)
    chuck = rod((0, axis_y, 0.102), (0, axis_y, 0.152), 0.022, 0.016, 24)
    bit = rod((0, axis_y, 0.15), (0, axis_y, 0.23), 0.004, 0.003, 12)
    grip = mf.Manifold.batch_hull([
        ellipsoid((0.0, 0.16, -0.035), (0.022, 0.02, 0.034), 20),
        ellipsoid((0.0, 0.06, -0.052), (0.021, 0.02, 0.03), 20)])
    trigger = rounded_box((0.014, 0.03, 0.022), 0.005, (0.0, 0.135, 0.0))
    guard = ball((0.0, 0.15, -0.01), 0.018, 16)
    battery = rounded_box((0.07, 0.055, 0.11), 0.01, (0.0, 0.0275, -0.04))
    foot = box((0.05, 0.012, 0.08), (0.0, 0.06, -0.04))
    return union([motor, back, gearbox, clutch, chuck, bit, grip, trigger, guard, battery, foot])

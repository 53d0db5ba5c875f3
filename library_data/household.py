"""Parametric household objects: mug, cup, bottle, vase, lamp, bathtub, toilet, microwave.

Units are roughly metres; the object stands on y = 0, +Y up, its front toward +Z.
"""

from __future__ import annotations

import manifold3d as mf

from library_data.parts import (
    ball,
    box,
    ellipsoid,
    lathe,
    rod,
    rounded_box,
    subtract,
    torus,
    union,
)


def mug() -> mf.Manifold:
    """Coffee mug: a straight cylinder hollowed from the top, with a loop handle on +X."""
    body = rod((0, 0, 0), (0, 0.1, 0), 0.042, segments=32)
    handle = torus((0.047, 0.052, 0.0), 0.027, 0.0065, "z")
    cavity = rod((0, 0.008, 0), (0, 0.11, 0), 0.036, segments=32)
    return subtract(union([body, handle]), [cavity])


def cup() -> mf.Manifold:
    """Teacup on a saucer: a flared bowl on a foot, a small handle, a rimmed saucer."""
    saucer = lathe([(0.0, 0.0), (0.05, 0.0), (0.078, 0.012), (0.078, 0.017), (0.05, 0.008),
                    (0.0, 0.008)], segments=32)
    bowl = lathe([(0.0, 0.008), (0.028, 0.008), (0.03, 0.016), (0.045, 0.04), (0.052, 0.075),
                  (0.0, 0.075)], segments=32)
    handle = torus((0.053, 0.05, 0.0), 0.016, 0.005, "z")
    cavity = lathe([(0.0, 0.02), (0.026, 0.02), (0.04, 0.04), (0.047, 0.08), (0.0, 0.08)],
                   segments=32)
    return subtract(union([saucer, bowl, handle]), [cavity])


def bottle() -> mf.Manifold:
    """Wine bottle: cylindrical body, rounded shoulder, long neck with a lip."""
    return lathe([(0.0, 0.0), (0.036, 0.0), (0.037, 0.005), (0.037, 0.2), (0.032, 0.225),
                  (0.02, 0.245), (0.013, 0.26), (0.012, 0.3), (0.014, 0.305), (0.014, 0.315),
                  (0.0, 0.315)], segments=32)


def vase() -> mf.Manifold:
    """Amphora-like vase: bulging body, narrow neck, flared open mouth."""
    outer = [(0.0, 0.0), (0.06, 0.0), (0.1, 0.06), (0.125, 0.14), (0.115, 0.2), (0.07, 0.28),
             (0.05, 0.33), (0.055, 0.37), (0.075, 0.4), (0.0, 0.4)]
    inner = [(0.0, 0.02), (0.05, 0.02), (0.09, 0.06), (0.11, 0.14), (0.1, 0.2), (0.056, 0.28),
             (0.037, 0.33), (0.042, 0.37), (0.062, 0.41), (0.0, 0.41)]
    return subtract(lathe(outer, 32), [lathe(inner, 32)])


def lamp() -> mf.Manifold:
    """Floor lamp: weighted disc base, thin pole, bulb, open conical shade."""
    base = lathe([(0.0, 0.0), (0.16, 0.0), (0.16, 0.015), (0.12, 0.035), (0.0, 0.035)], 32)
    pole = rod((0, 0.03, 0), (0, 1.14, 0), 0.012, segments=16)
    bulb = ball((0.0, 1.17, 0.0), 0.04, 16)
    shade = lathe([(0.23, 1.02), (0.245, 1.02), (0.145, 1.35), (0.13, 1.35)], 32)
    spokes = [box((0.26, 0.012, 0.012), (0.0, 1.3, 0.0)),
              box((0.012, 0.012, 0.26), (0.0, 1.3, 0.0))]
    cap = rod((0, 1.14, 0), (0, 1.31, 0), 0.012, segments=16)
    return union([base, pole, bulb, shade, *spokes, cap])


def bathtub() -> mf.Manifold:
    """Freestanding bathtub: rounded tub hollowed from the top, on four ball feet."""
    tub = rounded_box((1.7, 0.5, 0.8), 0.12, (0.0, 0.37, 0.0))
    basin = rounded_box((1.54, 0.6, 0.64), 0.12, (0.0, 0.72, 0.0))
    feet = [ball((x, 0.07, z), 0.07, 16) for x in (-0.65, 0.65) for z in (-0.26, 0.26)]
    faucet = rod((-0.78, 0.6, 0.0), (-0.78, 0.72, 0.0), 0.018, segments=16)
    spout = rod((-0.78, 0.71, 0.0), (-0.68, 0.71, 0.0), 0.014, segments=16)
    return union([subtract(tub, [basin]), *feet, faucet, spout])


def toilet() -> mf.Manifold:
    """Toilet: pedestal, oval bowl with seat, cistern with lid behind it (at -Z)."""
    pedestal = lathe([(0.0, 0.0), (0.13, 0.0), (0.11, 0.2), (0.15, 0.3), (0.0, 0.3)], 32)
    pedestal = pedestal.scale((1.0, 1.0, 1.3)).translate((0.0, 0.0, 0.05))
    bowl = ellipsoid((0.0, 0.38, 0.08), (0.19, 0.12, 0.26))
    bowl = subtract(bowl, [box((0.5, 0.2, 0.7), (0.0, 0.49, 0.08))])
    seat = torus((0.0, 0.0, 0.0), 0.15, 0.025, "y").scale((1.2, 1.0, 1.6)).translate((0, 0.4, 0.08))
    hole = ellipsoid((0.0, 0.42, 0.08), (0.14, 0.1, 0.2))
    tank = rounded_box((0.44, 0.38, 0.18), 0.03, (0.0, 0.6, -0.22))
    lid = rounded_box((0.47, 0.04, 0.21), 0.015, (0.0, 0.8, -0.22))
    neck = box((0.3, 0.12, 0.1), (0.0, 0.37, -0.14))
    return subtract(union([pedestal, bowl, seat, tank, lid, neck]), [hole])


def microwave() -> mf.Manifold:
    """Microwave oven: cabinet, recessed door window, control panel with dial, door handle."""
    cabinet = rounded_box((0.5, 0.3, 0.38), 0.015, (0.0, 0.17, 0.0))
    window = box((0.28, 0.18, 0.02), (-0.06, 0.17, 0.19))
    panel = box((0.1, 0.26, 0.01), (0.18, 0.17, 0.19))
    dial = rod((0.18, 0.1, 0.19), (0.18, 0.1, 0.21), 0.025, segments=24)
    handle = box((0.02, 0.2, 0.03), (0.115, 0.17, 0.2))
    feet = [box((0.04, 0.02, 0.04), (x, 0.01, z)) for x in (-0.2, 0.2) for z in (-0.15, 0.15)]
    return union([subtract(cabinet, [window]), panel, dial, handle, *feet])

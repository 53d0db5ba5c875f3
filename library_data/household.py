"""Parametric household objects: mug, cup, bottles, vase, lamps, bathtub, toilet, microwave,
teapot, kettle, espresso machine.

Units are roughly metres; the object stands on y = 0, +Y up, its front toward +Z.
"""

from __future__ import annotations

from collections.abc import Sequence

import manifold3d as mf
import numpy as np

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


def espresso_machine() -> mf.Manifold:
    """Home espresso machine: box body with a cup recess low in the front, group head and
    portafilter whose handle sticks out toward +Z, drip tray, steam wand on the +X side."""
    body = rounded_box((0.24, 0.3, 0.28), 0.015, (0.0, 0.15, 0.0))
    recess = box((0.17, 0.13, 0.12), (0.0, 0.095, 0.1))
    tray = box((0.18, 0.025, 0.1), (0.0, 0.0125, 0.13))
    group = rod((0.0, 0.17, 0.1), (0.0, 0.145, 0.1), 0.035, segments=24)
    basket = rod((0.0, 0.15, 0.1), (0.0, 0.13, 0.1), 0.032, segments=24)
    handle = rod((0.0, 0.14, 0.125), (0.02, 0.13, 0.27), 0.013, 0.016, segments=16)
    wand = rod((0.125, 0.25, 0.06), (0.14, 0.09, 0.11), 0.006, segments=12)
    knob = rod((0.125, 0.25, 0.06), (0.15, 0.25, 0.06), 0.015, segments=16)
    return union([subtract(body, [recess]), tray, group, basket, handle, wand, knob])


def _tube(points: Sequence[tuple[float, float, float]], r0: float, r1: float,
          segments: int = 16) -> mf.Manifold:
    """Tapering tube through ``points``: hulls of consecutive balls, radius ``r0`` to ``r1``."""
    radii = np.linspace(r0, r1, len(points))
    balls = [ball(p, float(r), segments) for p, r in zip(points, radii, strict=True)]
    return union([mf.Manifold.hull(a + b) for a, b in zip(balls[:-1], balls[1:], strict=True)])


def _curve(p0: tuple[float, float, float], p1: tuple[float, float, float],
           p2: tuple[float, float, float], n: int = 6) -> list[tuple[float, float, float]]:
    """``n`` points on the quadratic Bezier curve with control points ``p0``, ``p1``, ``p2``."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = (1 - t) ** 2 * np.asarray(p0) + 2 * t * (1 - t) * np.asarray(p1) + t**2 * np.asarray(p2)
    return [(float(x), float(y), float(z)) for x, y, z in pts]


def teapot() -> mf.Manifold:
    """Teapot: squat round body, curved spout on +X, loop handle on -X, lid with a knob."""
    body = lathe([(0.0, 0.0), (0.055, 0.0), (0.072, 0.008), (0.087, 0.03), (0.093, 0.055),
                  (0.089, 0.08), (0.076, 0.103), (0.056, 0.118), (0.046, 0.12), (0.0, 0.12)], 32)
    lid = lathe([(0.0, 0.118), (0.05, 0.118), (0.05, 0.124), (0.036, 0.137), (0.014, 0.143),
                 (0.0, 0.143)], 32)
    knob = ellipsoid((0.0, 0.151, 0.0), (0.013, 0.011, 0.013), 16)
    spout = _tube(_curve((0.06, 0.04, 0.0), (0.135, 0.045, 0.0), (0.16, 0.128, 0.0)), 0.022,
                  0.008)
    handle = torus((0.0, 0.0, 0.0), 0.042, 0.008, "z", sweep_deg=220.0).rotate(
        (0.0, 0.0, 70.0)).scale((0.9, 1.05, 1.0)).translate((-0.083, 0.068, 0.0))
    return union([body, lid, knob, spout, handle])


def kettle() -> mf.Manifold:
    """Stovetop kettle: body tapering up, lid with a knob, spout on +X, arched handle over it."""
    body = lathe([(0.0, 0.0), (0.085, 0.0), (0.092, 0.01), (0.09, 0.05), (0.076, 0.14),
                  (0.058, 0.18), (0.046, 0.19), (0.0, 0.19)], 32)
    lid = lathe([(0.0, 0.188), (0.048, 0.188), (0.048, 0.194), (0.03, 0.203), (0.0, 0.206)], 32)
    knob = ball((0.0, 0.213, 0.0), 0.011, 16)
    spout = _tube(_curve((0.06, 0.05, 0.0), (0.12, 0.09, 0.0), (0.15, 0.17, 0.0)), 0.02, 0.009)
    arch = torus((0.0, 0.0, 0.0), 0.062, 0.008, "z", sweep_deg=180.0).scale(
        (1.0, 1.25, 1.0)).translate((0.0, 0.165, 0.0))
    grip = rod((-0.03, 0.243, 0.0), (0.03, 0.243, 0.0), 0.012, segments=16)
    return union([body, lid, knob, spout, arch, grip])


def oil_lamp() -> mf.Manifold:
    """Hurricane lantern: round fount, bulged glass chimney, side tubes, cap, wire bail."""
    fount = lathe([(0.0, 0.0), (0.075, 0.0), (0.08, 0.01), (0.08, 0.04), (0.062, 0.06),
                   (0.038, 0.068), (0.0, 0.068)], 32)
    burner = rod((0, 0.066, 0), (0, 0.085, 0), 0.042, segments=32)
    glass = lathe([(0.0, 0.084), (0.038, 0.084), (0.056, 0.12), (0.061, 0.16), (0.052, 0.2),
                   (0.036, 0.225), (0.0, 0.225)], 32)
    cap = lathe([(0.0, 0.222), (0.05, 0.222), (0.052, 0.232), (0.032, 0.252), (0.018, 0.256),
                 (0.0, 0.256)], 32)
    tubes = [rod((x, 0.04, 0.0), (x, 0.235, 0.0), 0.006, segments=12) for x in (-0.07, 0.07)]
    struts = [rod((x, 0.234, 0.0), (0.0, 0.234, 0.0), 0.005, segments=12) for x in (-0.07, 0.07)]
    bail = torus((0.0, 0.235, 0.0), 0.07, 0.0035, "z", sweep_deg=180.0, segments=32)
    return union([fount, burner, glass, cap, *tubes, *struts, bail])


def sports_bottle() -> mf.Manifold:
    """Squeeze sports bottle: cylinder with a waist, dome shoulder, ribbed cap, push-pull spout."""
    body = lathe([(0.0, 0.0), (0.034, 0.0), (0.038, 0.005), (0.038, 0.075), (0.032, 0.1),
                  (0.038, 0.125), (0.038, 0.175), (0.033, 0.195), (0.024, 0.207), (0.0, 0.207)],
                 32)
    cap = lathe([(0.0, 0.204), (0.026, 0.204), (0.026, 0.228), (0.016, 0.234), (0.0, 0.234)], 32)
    spout = lathe([(0.0, 0.232), (0.011, 0.232), (0.011, 0.25), (0.008, 0.258), (0.0, 0.258)],
                  24)
    ring = rod((0, 0.214, 0), (0, 0.222, 0), 0.028, segments=32)
    return union([body, cap, spout, ring])


def squeeze_bottle() -> mf.Manifold:
    """Mustard bottle: rounded flat-sided body, tapered shoulder, conical nozzle cap."""
    body = rounded_box((0.075, 0.14, 0.048), 0.018, (0.0, 0.07, 0.0))
    shoulder = mf.Manifold.batch_hull([
        rounded_box((0.075, 0.02, 0.048), 0.009, (0.0, 0.13, 0.0)),
        rod((0, 0.165, 0), (0, 0.17, 0), 0.017, segments=28)])
    cap = rod((0, 0.168, 0), (0, 0.19, 0), 0.019, segments=28)
    nozzle = rod((0, 0.19, 0), (0, 0.228, 0), 0.011, 0.003, segments=20)
    return union([body, shoulder, cap, nozzle])

"""Parametric gadgets and carried things: monitor, camera, headphones, handbag, guitar.

Units are roughly metres; +Y up, the object's front (screen, lens, strings) toward +Z.
"""

from __future__ import annotations

import manifold3d as mf

from library_data.parts import box, mirror_x, rod, rounded_box, slab, subtract, torus, union


def monitor() -> mf.Manifold:
    """Flat-panel monitor: thin panel with a recessed screen facing +Z, neck, oval base."""
    panel = rounded_box((0.62, 0.38, 0.035), 0.01, (0.0, 0.43, 0.0))
    screen = box((0.58, 0.33, 0.01), (0.0, 0.44, 0.0175))
    back = rounded_box((0.36, 0.24, 0.05), 0.02, (0.0, 0.42, -0.035))
    neck = box((0.06, 0.36, 0.025), (0.0, 0.2, -0.07))
    base = rounded_box((0.28, 0.018, 0.2), 0.008, (0.0, 0.009, -0.04))
    return union([subtract(panel, [screen]), back, neck, base])


def camera() -> mf.Manifold:
    """DSLR camera: body with a hand grip, prism hump, lens barrel toward +Z, shutter button."""
    body = rounded_box((0.14, 0.095, 0.07), 0.012, (0.0, 0.0475, 0.0))
    grip = rounded_box((0.035, 0.09, 0.09), 0.015, (-0.055, 0.045, 0.01))
    hump = slab([(-0.03, 0.09), (0.03, 0.09), (0.018, 0.125), (-0.018, 0.125)], 0.06, "z")
    lens = rod((0.01, 0.045, 0.03), (0.01, 0.045, 0.1), 0.034, segments=32)
    ring = rod((0.01, 0.045, 0.085), (0.01, 0.045, 0.11), 0.037, segments=32)
    glass = rod((0.01, 0.045, 0.105), (0.01, 0.045, 0.12), 0.025, segments=32)
    button = rod((-0.05, 0.09, 0.01), (-0.05, 0.102, 0.01), 0.008, segments=12)
    return subtract(union([body, grip, hump, lens, ring, button]), [glass])


def headphones() -> mf.Manifold:
    """Over-ear headphones: arched headband, two ear cups with cushions facing each other."""
    band = torus((0.0, 0.0, 0.0), 0.1, 0.012, "z", sweep_deg=180.0)
    pad = torus((0.0, 0.0, 0.0), 0.097, 0.016, "z", sweep_deg=100.0).rotate((0.0, 0.0, 40.0))
    parts = [band, pad]
    for side in (-1.0, 1.0):
        parts.append(box((0.012, 0.06, 0.02), (side * 0.1, -0.02, 0.0)))
        parts.append(rod((side * 0.115, -0.08, 0.0), (side * 0.085, -0.08, 0.0), 0.045))
        parts.append(rod((side * 0.088, -0.08, 0.0), (side * 0.07, -0.08, 0.0), 0.04, 0.036))
    return union(parts)


def handbag() -> mf.Manifold:
    """Handbag: trapezoid body wider at the bottom, flap with a clasp, two arched handles."""
    body = rounded_box((0.34, 0.24, 0.12), 0.02, (0.0, 0.12, 0.0))
    tapers = mirror_x([slab([(0.172, -0.01), (0.3, -0.01), (0.3, 0.3), (0.135, 0.3)], 0.2, "z")])
    flap = box((0.26, 0.1, 0.01), (0.0, 0.2, 0.062))
    clasp = box((0.04, 0.025, 0.012), (0.0, 0.15, 0.068))
    handles = [torus((0.0, 0.22, z), 0.09, 0.009, "z", sweep_deg=180.0) for z in (-0.035, 0.035)]
    return union([subtract(body, tapers), flap, clasp, *handles])


def guitar() -> mf.Manifold:
    """Acoustic guitar standing upright: waisted body, sound hole facing +Z, neck, headstock."""
    lower = mf.CrossSection.circle(0.19, 32).translate((0.0, 0.2))
    upper = mf.CrossSection.circle(0.145, 32).translate((0.0, 0.47))
    waist = mf.CrossSection.square((0.22, 0.2), center=True).translate((0.0, 0.34))
    outline = mf.CrossSection.batch_boolean([lower, upper, waist], mf.OpType.Add)
    body = outline.extrude(0.1).translate((0.0, 0.0, -0.05))
    hole = rod((0, 0.4, 0.03), (0, 0.4, 0.06), 0.045, segments=28)
    bridge = box((0.14, 0.025, 0.012), (0.0, 0.17, 0.055))
    neck = box((0.05, 0.5, 0.03), (0.0, 0.83, 0.02))
    head = box((0.08, 0.18, 0.02)).rotate((-12.0, 0.0, 0.0)).translate((0.0, 1.17, 0.0))
    pegs = [rod((s * 0.04, 1.1 + 0.05 * k, 0.0), (s * 0.06, 1.1 + 0.05 * k, 0.0), 0.008, segments=8)
            for s in (-1, 1) for k in range(3)]
    return union([subtract(body, [hole]), bridge, neck, head, *pegs])

"""Parametric furniture: chairs, armchair, tables, bench, sofa, bed, bookshelf, desk, stool,
piano.

Units are roughly metres; the floor is y = 0, +Y up, the front (where a person sits or stands)
toward +Z.
"""

from __future__ import annotations

import math

import manifold3d as mf

from library_data.parts import ball, box, mirror_x, rod, rounded_box, subtract, torus, union


def chair_wood() -> mf.Manifold:
    """Dining chair: four square legs, a seat, a back of two posts, a top rail and slats."""
    legs = [box((0.04, 0.45, 0.04), (x, 0.225, z)) for x in (-0.19, 0.19) for z in (-0.19, 0.19)]
    posts = [box((0.04, 0.5, 0.04), (x, 0.7, -0.19)) for x in (-0.19, 0.19)]
    seat = box((0.46, 0.04, 0.46), (0.0, 0.47, 0.0))
    rail = box((0.42, 0.09, 0.03), (0.0, 0.9, -0.19))
    slats = [box((0.04, 0.34, 0.02), (x, 0.67, -0.19)) for x in (-0.1, 0.0, 0.1)]
    stretchers = [box((0.38, 0.025, 0.025), (0.0, 0.15, z)) for z in (-0.19, 0.19)]
    return union([*legs, *posts, seat, rail, *slats, *stretchers])


def chair_office() -> mf.Manifold:
    """Office chair: five-star base on casters, gas column, padded seat, back and armrests."""
    parts = [rod((0, 0.06, 0), (0, 0.42, 0), 0.03), rod((0, 0.04, 0), (0, 0.12, 0), 0.05)]
    for k in range(5):
        angle = 2 * math.pi * k / 5
        end = (0.3 * math.sin(angle), 0.08, 0.3 * math.cos(angle))
        parts += [rod((0, 0.08, 0), end, 0.02), ball((end[0], 0.03, end[2]), 0.03, 12)]
    parts.append(rounded_box((0.5, 0.08, 0.48), 0.03, (0.0, 0.46, 0.02)))
    parts.append(rounded_box((0.46, 0.56, 0.06), 0.03, (0.0, 0.86, -0.25)))
    parts.append(box((0.06, 0.36, 0.04), (0.0, 0.58, -0.24)))
    for x in (-0.28, 0.28):
        parts += [box((0.03, 0.2, 0.03), (x, 0.57, -0.02)), box((0.06, 0.03, 0.26), (x, 0.68, 0.0))]
    parts.append(box((0.6, 0.03, 0.05), (0.0, 0.5, -0.02)))
    return union(parts)


def table_dining() -> mf.Manifold:
    """Rectangular dining table: top, four legs, aprons."""
    top = box((1.6, 0.04, 0.9), (0.0, 0.74, 0.0))
    legs = [box((0.07, 0.72, 0.07), (x, 0.36, z)) for x in (-0.72, 0.72) for z in (-0.37, 0.37)]
    aprons = [box((1.4, 0.1, 0.03), (0.0, 0.66, z)) for z in (-0.37, 0.37)]
    aprons += [box((0.03, 0.1, 0.7), (x, 0.66, 0.0)) for x in (-0.72, 0.72)]
    return union([top, *legs, *aprons])


def table_round() -> mf.Manifold:
    """Round cafe table: disc top, pedestal column, four feet."""
    parts = [rod((0, 0.7, 0), (0, 0.74, 0), 0.45, segments=32),
             rod((0, 0.05, 0), (0, 0.7, 0), 0.04)]
    parts += [box((0.7, 0.04, 0.06), (0.0, 0.03, 0.0)), box((0.06, 0.04, 0.7), (0.0, 0.03, 0.0))]
    parts.append(rod((0, 0.62, 0), (0, 0.7, 0), 0.04, 0.12))
    return union(parts)


def bench() -> mf.Manifold:
    """Park bench: slatted seat and backrest on two side frames with armrests."""
    seat = [box((1.5, 0.03, 0.1), (0.0, 0.45, z)) for z in (-0.14, -0.02, 0.1, 0.22)]
    back = [box((1.5, 0.1, 0.03), (0.0, y, -0.24 - 0.15 * (y - 0.5))) for y in (0.6, 0.76)]
    frames = []
    for x in (-0.68, 0.68):
        frames += [box((0.05, 0.45, 0.05), (x, 0.225, 0.22)),
                   rod((x, 0, -0.2), (x, 0.85, -0.3), 0.03)]
        frames += [box((0.05, 0.04, 0.52), (x, 0.42, 0.02)),
                   box((0.05, 0.04, 0.45), (x, 0.64, 0.02))]
        frames.append(box((0.05, 0.2, 0.05), (x, 0.53, 0.2)))
    return union([*seat, *back, *frames])


def sofa() -> mf.Manifold:
    """Three-seat sofa: base, three seat cushions, backrest, two arms, feet."""
    parts = [rounded_box((2.0, 0.26, 0.9), 0.04, (0.0, 0.26, 0.0))]
    parts += [rounded_box((0.6, 0.16, 0.7), 0.05, (x, 0.46, 0.08)) for x in (-0.6, 0.0, 0.6)]
    parts.append(rounded_box((2.0, 0.52, 0.24), 0.08, (0.0, 0.6, -0.33)))
    parts += [rounded_box((0.22, 0.34, 0.9), 0.08, (x, 0.5, 0.0)) for x in (-0.92, 0.92)]
    parts += [rod((x, 0, z), (x, 0.13, z), 0.03, 0.035, 16)
              for x in (-0.9, 0.9) for z in (-0.38, 0.38)]
    return union(parts)


def bed() -> mf.Manifold:
    """Double bed: frame on legs, mattress, headboard, low footboard, two pillows."""
    parts = [box((1.6, 0.2, 2.1), (0.0, 0.3, 0.0))]
    parts.append(rounded_box((1.55, 0.22, 2.0), 0.06, (0.0, 0.5, 0.02)))
    parts.append(box((1.7, 1.05, 0.07), (0.0, 0.525, -1.07)))
    parts.append(box((1.7, 0.5, 0.06), (0.0, 0.25, 1.07)))
    parts += [rounded_box((0.6, 0.13, 0.38), 0.06, (x, 0.66, -0.78)) for x in (-0.37, 0.37)]
    parts += [box((0.06, 0.2, 0.06), (x, 0.1, z)) for x in (-0.75, 0.75) for z in (-0.98, 0.98)]
    return union(parts)


def bookshelf() -> mf.Manifold:
    """Bookshelf: a case open at the front with three compartments, two holding books."""
    bottoms = (0.08, 0.55, 1.02)  # compartment floors; boards are 0.05 thick
    case = subtract(box((0.8, 1.49, 0.32), (0.0, 0.745, 0.0)),
                    [box((0.7, 0.42, 0.3), (0.0, y + 0.21, 0.04)) for y in bottoms])
    # Gaps between books stay wider than a grid cell so occupancy and ray tests resolve them.
    books = [box((0.05, 0.3 - 0.03 * (i % 3), 0.24), (-0.3 + 0.08 * i, bottoms[0] + 0.15
                                                       - 0.015 * (i % 3), 0.03))
             for i in range(6)]
    books += [box((0.32 - 0.03 * j, 0.06, 0.24), (0.12, bottoms[1] + 0.03 + 0.06 * j, 0.03))
              for j in range(3)]
    return union([case, *books])


def desk() -> mf.Manifold:
    """Office desk: top, drawer pedestal on the left, side panel on the right, modesty panel."""
    top = box((1.4, 0.03, 0.7), (0.0, 0.745, 0.0))
    pedestal = subtract(box((0.42, 0.73, 0.66), (-0.48, 0.365, 0.0)),
                        [box((0.38, 0.006, 0.02), (-0.48, y, 0.33)) for y in (0.22, 0.46)])
    knobs = [box((0.1, 0.02, 0.02), (-0.48, y, 0.34)) for y in (0.12, 0.34, 0.6)]
    side = box((0.03, 0.73, 0.66), (0.675, 0.365, 0.0))
    modesty = box((0.92, 0.4, 0.02), (0.2, 0.5, -0.3))
    return union([top, pedestal, *knobs, side, modesty])


def stool() -> mf.Manifold:
    """Bar stool: round seat on four splayed legs with a foot ring."""
    seat = rod((0, 0.7, 0), (0, 0.75, 0), 0.18)
    legs = [rod((0.12 * sx, 0.7, 0.12 * sz), (0.21 * sx, 0.0, 0.21 * sz), 0.018)
            for sx in (-1, 1) for sz in (-1, 1)]
    ring = torus((0.0, 0.28, 0.0), 0.233, 0.012, "y")
    return union([seat, *legs, ring])


def piano() -> mf.Manifold:
    """Upright piano: cabinet, keyboard shelf with keys, front legs, music desk, pedals."""
    cabinet = subtract(box((1.5, 1.25, 0.36), (0.0, 0.625, -0.15)),
                       [box((1.2, 0.45, 0.1), (0.0, 0.225, 0.05))])
    shelf = box((1.5, 0.08, 0.3), (0.0, 0.7, 0.15))
    keys = box((1.3, 0.03, 0.16), (0.0, 0.755, 0.2))
    legs = mirror_x([box((0.07, 0.66, 0.07), (0.68, 0.33, 0.26))])
    rest = box((0.9, 0.22, 0.03), (0.0, 0.97, 0.05))
    lid = box((1.56, 0.04, 0.42), (0.0, 1.27, -0.15))
    pedals = [box((0.05, 0.02, 0.1), (x, 0.05, 0.06)) for x in (-0.1, 0.0, 0.1)]
    return union([cabinet, shelf, keys, *legs, rest, lid, *pedals])


def armchair() -> mf.Manifold:
    """Upholstered armchair: thick base, seat cushion, reclined backrest, two arms, short legs."""
    base = rounded_box((0.84, 0.26, 0.82), 0.05, (0.0, 0.26, 0.0))
    cushion = rounded_box((0.58, 0.15, 0.66), 0.06, (0.0, 0.45, 0.06))
    back = rounded_box((0.84, 0.62, 0.22), 0.08, (0.0, 0.0, 0.0)).rotate(
        (-10.0, 0.0, 0.0)).translate((0.0, 0.68, -0.31))
    arms = mirror_x([rounded_box((0.15, 0.36, 0.8), 0.07, (0.345, 0.49, 0.0))])
    legs = [rod((x, 0.0, z), (x, 0.14, z), 0.022, 0.03, 16)
            for x in (-0.36, 0.36) for z in (-0.34, 0.34)]
    return union([base, cushion, back, *arms, *legs])

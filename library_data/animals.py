"""Parametric toy animals: rubber duck, cow, dog.

Organic shapes are unions of ellipsoids and of hulls of a few balls. Units are roughly metres;
the animal stands on y = 0, +Y up, its head toward +Z.
"""

from __future__ import annotations

import manifold3d as mf

from library_data.parts import Vec, ball, box, ellipsoid, mirror_x, rod, subtract, union


def _blob(*spheres: tuple[Vec, float]) -> mf.Manifold:
    """Convex hull of balls given as (centre, radius): a smooth capsule-like limb or body."""
    return mf.Manifold.batch_hull([ball(c, r, 20) for c, r in spheres])


def duck_toy() -> mf.Manifold:
    """Rubber duck: flat-bottomed ellipsoid body, raised tail tip, round head, flat beak at +Z."""
    body = ellipsoid((0.0, 0.042, -0.005), (0.052, 0.042, 0.068))
    tail = _blob(((0.0, 0.05, -0.045), 0.028), ((0.0, 0.082, -0.083), 0.009))
    head = ball((0.0, 0.105, 0.03), 0.036)
    neck = _blob(((0.0, 0.07, 0.015), 0.035), ((0.0, 0.095, 0.028), 0.03))
    beak = ellipsoid((0.0, 0.098, 0.068), (0.021, 0.007, 0.022), 20)
    eyes = mirror_x([ball((0.024, 0.117, 0.055), 0.006, 12)])
    wings = mirror_x([ellipsoid((0.046, 0.048, -0.012), (0.012, 0.022, 0.038), 20)])
    floor = box((0.2, 0.02, 0.3), (0.0, -0.006, 0.0))
    return subtract(union([body, tail, head, neck, beak, *eyes, *wings]), [floor])


def _legs(x: float, zs: tuple[float, float], top: float, radius: float) -> list[mf.Manifold]:
    """Four straight legs from height ``top`` to the ground, each ending in a wider hoof/paw."""
    legs = []
    for z in zs:
        for sx in (-x, x):
            legs.append(rod((sx, 0.0, z), (sx, top, z), radius * 0.8, radius, 16))
            legs.append(rod((sx, 0.0, z), (sx, 0.06 * top + 0.01, z), radius * 1.05, segments=16))
    return legs


def cow_toy() -> mf.Manifold:
    """Toy cow: barrel body along Z, four legs, neck and lowered head at +Z, horns, ears, udder,
    tail with a tuft."""
    body = mf.Manifold.batch_hull([ellipsoid((0.0, 1.04, 0.42), (0.32, 0.37, 0.42)),
                                   ellipsoid((0.0, 1.06, -0.45), (0.32, 0.36, 0.42))])
    legs = _legs(0.19, (0.55, -0.6), 0.95, 0.085)
    neck = _blob(((0.0, 1.16, 0.7), 0.25), ((0.0, 1.24, 0.98), 0.16))
    head = _blob(((0.0, 1.3, 1.06), 0.16), ((0.0, 1.04, 1.28), 0.12))
    muzzle = ellipsoid((0.0, 1.0, 1.32), (0.14, 0.1, 0.1), 20)
    horns = mirror_x([rod((0.08, 1.4, 1.05), (0.25, 1.55, 1.02), 0.036, 0.014, 12)])
    ears = mirror_x([ellipsoid((0.22, 1.3, 1.0), (0.13, 0.04, 0.07), 16)])
    udder = ball((0.0, 0.74, -0.38), 0.14, 20)
    tail = rod((0.0, 1.25, -0.82), (0.0, 0.72, -0.98), 0.028, 0.02, 12)
    tuft = ellipsoid((0.0, 0.68, -0.98), (0.05, 0.08, 0.05), 16)
    return union([body, *legs, neck, head, muzzle, *horns, *ears, udder, tail, tuft])


def dog_toy() -> mf.Manifold:
    """Toy dog: long low body, short legs, head at +Z with a long snout and upright ears, tail
    raised at the back."""
    body = mf.Manifold.batch_hull([ellipsoid((0.0, 0.28, 0.17), (0.12, 0.13, 0.17)),
                                   ellipsoid((0.0, 0.29, -0.18), (0.11, 0.12, 0.17))])
    legs = _legs(0.075, (0.22, -0.24), 0.24, 0.042)
    paws = mirror_x([ellipsoid((0.075, 0.02, z + 0.025), (0.04, 0.022, 0.055), 16)
                     for z in (0.22, -0.24)])
    neck = _blob(((0.0, 0.35, 0.27), 0.1), ((0.0, 0.47, 0.36), 0.075))
    head = ball((0.0, 0.5, 0.39), 0.09)
    snout = _blob(((0.0, 0.49, 0.44), 0.06), ((0.0, 0.47, 0.57), 0.038))
    nose = ball((0.0, 0.48, 0.6), 0.02, 12)
    ears = mirror_x([_blob(((0.05, 0.57, 0.37), 0.032), ((0.07, 0.68, 0.36), 0.008))])
    tail = rod((0.0, 0.35, -0.32), (0.0, 0.5, -0.43), 0.025, 0.012, 12)
    return union([body, *legs, *paws, neck, head, snout, nose, *ears, tail])

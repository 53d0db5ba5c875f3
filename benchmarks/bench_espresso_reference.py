"""How far the espresso photos' reference cameras are from the truth: their elevations measured
from the placemat under the machine.

The espresso set (``../shared/eval/photos/ners_espresso``) ships one coarse azimuth and
elevation per photo (``metadata.json``: elevations 0, 30 or 90), and the capture benchmark
scores the espresso job against cameras on a sphere at those angles. This area measures each
photo's real elevation from the floor: the machine stands on a rectangular placemat; the two
pairs of opposite mat edges meet at two vanishing points whose rays (through the EXIF focal
length, principal point at the centre) span the floor, so their cross product is the floor's
normal in the camera's frame. The elevation is the angle between the horizontal and the ray
from the camera to the middle of the machine's mask box. A rectangle's two edge directions are
perpendicular, which the measured directions check (``corner``).

The edges were read by hand off the 800 x 600 photos: two points on each edge, the mat's
corners where visible, points along an edge where the machine hides a corner. Clicks carry a
few pixels of error; each figure comes with the 5-95 % range under 3-pixel noise on every
point. The top view (the mat out of frame) keeps its metadata elevation, 90.

The figure that matters: the capture benchmark's own score (median rotation error after
similarity alignment, ``cameras.pose_errors``) between the metadata cameras and the same
cameras at the measured elevations (azimuths unchanged). That is how far perfect cameras could
score from the reference on elevation alone, before the azimuths' own annotation error.

QUICK: the same (a second, no jobs).

Usage: ``python -m benchmarks.bench_espresso_reference``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import ABSENT, PHOTOS, section_head

SET = "ners_espresso"
CLICK_NOISE_PX = 3.0
DRAWS = 400

Point = tuple[float, float]
Edge = tuple[Point, Point]

EDGES: dict[str, tuple[tuple[Edge, Edge], tuple[Edge, Edge]]] = {
    # photo: (one pair of opposite mat edges, the other pair), each edge two points on it.
    "PXL_20210526_021804355.jpg": ((((266, 554), (332, 282)), ((661, 561), (557, 282))),
                                   (((266, 554), (661, 561)), ((332, 282), (557, 282)))),
    "PXL_20210526_021824030.jpg": ((((211, 595), (200, 378)), ((704, 490), (608, 409))),
                                   (((211, 595), (704, 490)), ((200, 378), (302, 367)))),
    "PXL_20210526_021913726.jpg": ((((93, 504), (183, 391)), ((585, 504), (517, 394))),
                                   (((93, 504), (585, 504)), ((183, 391), (517, 394)))),
    "PXL_20210526_021858651.jpg": ((((520, 520), (178, 469)), ((551, 272), (498, 274))),
                                   (((520, 520), (551, 272)), ((178, 469), (249, 334)))),
    "PXL_20210526_021901650.jpg": ((((449, 490), (261, 360)), ((665, 280), (542, 248))),
                                   (((449, 490), (665, 280)), ((261, 360), (331, 321)))),
    "PXL_20210526_021843386.jpg": ((((159, 479), (765, 547)), ((698, 381), (586, 380))),
                                   (((765, 547), (698, 381)), ((159, 479), (249, 413)))),
}


def _line(a: Point, b: Point) -> np.ndarray:
    return np.cross([a[0], a[1], 1.0], [b[0], b[1], 1.0])


def _direction(pair: tuple[Edge, Edge], K_inv: np.ndarray) -> np.ndarray:
    """The 3D direction (camera frame, unit) shared by two edges parallel on the floor."""
    vanishing = np.cross(_line(*pair[0]), _line(*pair[1]))
    ray = K_inv @ vanishing
    return ray / np.linalg.norm(ray)


def floor_elevation(edges: tuple[tuple[Edge, Edge], tuple[Edge, Edge]], K: np.ndarray,
                    target: Point) -> tuple[float, float]:
    """Elevation (degrees) of the camera seen from the floor point's vertical through
    ``target``: the angle between the horizontal and the ray to the pixel ``target``, the floor
    given by two pairs of parallel floor edges; and the angle (degrees) between the two edge
    directions, 90 for a rectangle's."""
    K_inv = np.linalg.inv(K)
    first, second = _direction(edges[0], K_inv), _direction(edges[1], K_inv)
    normal = np.cross(first, second)
    normal /= np.linalg.norm(normal)
    if normal[1] > 0:  # the camera's y axis points down; the floor's normal points up
        normal = -normal
    ray = K_inv @ np.array([target[0], target[1], 1.0])
    ray /= np.linalg.norm(ray)
    elevation = float(np.degrees(np.arcsin(np.clip(-(ray @ normal), -1.0, 1.0))))
    corner = float(np.degrees(np.arccos(np.clip(abs(first @ second), 0.0, 1.0))))
    return elevation, corner


def _jittered(edges: tuple[tuple[Edge, Edge], tuple[Edge, Edge]],
              rng: np.random.Generator) -> tuple[tuple[Edge, Edge], tuple[Edge, Edge]]:
    def move(p: Point) -> Point:
        dx, dy = rng.normal(0.0, CLICK_NOISE_PX, 2)
        return (p[0] + dx, p[1] + dy)
    return tuple(tuple((move(a), move(b)) for a, b in pair)  # type: ignore[return-value]
                 for pair in edges)


def reference_gap(azimuths: list[float], metadata: list[float],
                  measured: list[float]) -> float:
    """Median rotation error (degrees, after similarity alignment) between cameras on a sphere
    at the metadata's angles and at the measured elevations, azimuths unchanged."""
    from cadnerf_core.cameras.conventions import orbit_pose, pose_errors

    def cameras(elevations: list[float]) -> np.ndarray:
        return np.stack([orbit_pose(a, e, 4.0) for a, e in zip(azimuths, elevations,
                                                                strict=True)])
    return float(np.median(pose_errors(cameras(metadata), cameras(measured))[0]))


def measure(folder: Path = PHOTOS / SET) -> dict[str, Any]:
    """Each photo's metadata and measured elevation, and the reference's gap with its range."""
    import cv2

    from cadnerf_core.intake.photos import load_photo

    meta = json.loads((folder / "metadata.json").read_text())
    names = sorted(p.name for p in (folder / "images").iterdir())
    rng = np.random.default_rng(0)
    rows, draws = [], []
    for index, name in enumerate(names):
        row: dict[str, Any] = {"photo": name, "azimuth": float(meta["azimuths"][index]),
                               "metadata": float(meta["elevations"][index])}
        if name in EDGES:
            photo = load_photo(folder / "images" / name, index)
            height, width = photo.rgb.shape[:2]
            focal = photo.focal_pixels
            assert focal, f"{name} has no EXIF focal length"
            K = np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0, 0, 1.0]])
            mask = cv2.imread(str(folder / "masks" / f"{Path(name).stem}.png"),
                              cv2.IMREAD_GRAYSCALE)
            assert mask is not None, f"cannot read the mask of {name}"
            ys, xs = np.nonzero(mask > 127)
            target = ((xs.min() + xs.max()) / 2.0, (ys.min() + ys.max()) / 2.0)
            row["measured"], row["corner"] = floor_elevation(EDGES[name], K, target)
            noisy = [floor_elevation(_jittered(EDGES[name], rng), K, target)[0]
                     for _ in range(DRAWS)]
            row["range"] = tuple(float(v) for v in np.percentile(noisy, [5, 95]))
            draws.append(noisy)
        rows.append(row)
    azimuths = [r["azimuth"] for r in rows]
    metadata = [r["metadata"] for r in rows]
    gap = reference_gap(azimuths, metadata, [r.get("measured", r["metadata"]) for r in rows])
    spread = []
    for k in range(DRAWS):
        values = iter(d[k] for d in draws)
        spread.append(reference_gap(azimuths, metadata,
                                    [next(values) if "measured" in r else r["metadata"]
                                     for r in rows]))
    return {"rows": rows, "gap": gap,
            "gap_range": tuple(float(v) for v in np.percentile(spread, [5, 95]))}


def section(result: dict[str, Any], quick: bool) -> str:
    """The area's markdown section."""
    lines = [*section_head("The espresso photos' reference cameras against the floor",
                           "bench_espresso_reference", quick,
                           ": elevations measured from the placemat's edges (read by hand "
                           "off the photos, EXIF focal length), the range under "
                           f"{CLICK_NOISE_PX:g}-pixel click noise."),
             "| photo | metadata azimuth | metadata elevation | measured elevation (5-95 %) "
             "| mat corner (90 for a rectangle) |", "|---|---:|---:|---:|---:|"]
    for row in result["rows"]:
        if "measured" in row:
            low, high = row["range"]
            lines.append(f"| {row['photo']} | {row['azimuth']:.0f} | {row['metadata']:.0f} | "
                         f"{row['measured']:.1f} ({low:.1f}-{high:.1f}) | "
                         f"{row['corner']:.1f} |")
        else:
            lines.append(f"| {row['photo']} | {row['azimuth']:.0f} | {row['metadata']:.0f} | "
                         "mat out of frame: metadata kept | |")
    low, high = result["gap_range"]
    measured = [abs(r["measured"] - r["metadata"]) for r in result["rows"] if "measured" in r]
    lines += ["", f"- Elevation off the metadata's by a median **{np.median(measured):.1f} deg** "
              f"over the {len(measured)} photos that show the mat (at most "
              f"{max(measured):.1f}).",
              f"- The metadata cameras against the same cameras at the measured elevations, "
              f"scored as the capture benchmark scores a job (median rotation error after "
              f"similarity alignment): **{result['gap']:.1f} deg** ({low:.1f}-{high:.1f} under "
              "click noise). Cameras right in elevation would score about that against the "
              "reference before the azimuths' own error, so a score under it on this set "
              "cannot be told from one at it.", ""]
    return "\n".join(lines)


def run(quick: bool) -> str:
    """Run the benchmark. Returns its markdown section."""
    if not (PHOTOS / SET / "metadata.json").is_file():
        return "\n".join([*section_head("The espresso photos' reference cameras against the "
                                        "floor", "bench_espresso_reference", quick),
                          ABSENT, ""])
    return section(measure(), quick)


def main(argv: list[str] | None = None) -> int:
    """Print the section."""
    from benchmarks.run import area_main

    return area_main(run, __doc__.splitlines()[0] if __doc__ else "", argv, library=False)


if __name__ == "__main__":
    sys.exit(main())

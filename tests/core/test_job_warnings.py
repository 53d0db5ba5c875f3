"""A job's warnings, made once in the core: which ones a retrieval gives, in what order, and
that each is one sentence saying what happened and what to do."""

from __future__ import annotations

import re

from cadnerf_core.job_warnings import (
    FOCAL_UNKNOWN_WARNING,
    MATCHES_FEW_WARNING,
    MATCHES_SET_ASIDE_WARNING,
    direction_guess_hint,
    job_warnings,
    order_guess_warning,
    reorder_warning,
    too_small_warning,
)

NAMES = ["a.jpg", "b.jpg", "c.jpg"]


def test_a_clean_retrieval_gives_no_warning() -> None:
    clean = {"order": [0, 1, 2], "focal_known": True, "fusion": {"photos": [0, 1, 2]}}
    assert job_warnings(clean, NAMES) == []


def test_warnings_come_masks_first_then_order_direction_focal_and_matches() -> None:
    retrieval = {"order": [2, 0, 1], "order_ambiguous": True, "direction_ambiguous": True,
                 "direction": -1, "focal_known": False, "fusion": {"photos": []}}
    warnings = job_warnings(retrieval, NAMES, ["c.jpg: the mask touches the frame"])
    assert warnings == ["c.jpg: the mask touches the frame",
                        order_guess_warning(["c.jpg", "a.jpg", "b.jpg"]),
                        direction_guess_hint(-1), FOCAL_UNKNOWN_WARNING, MATCHES_FEW_WARNING]
    assert 'retrieval.walk to "ccw"' in warnings[2] and "--walk ccw" in warnings[2]


def test_a_reorder_is_warned_only_where_the_order_was_left_to_the_job() -> None:
    found = {"order": [1, 2, 0], "reordered": True}
    assert job_warnings({**found, "order_mode": "auto"}, NAMES) == [
        reorder_warning(["b.jpg", "c.jpg", "a.jpg"])]
    assert job_warnings({**found, "order_mode": "any"}, NAMES) == []


def test_the_mapper_measures_the_focal_length_so_none_is_guessed() -> None:
    mapped = {"focal_known": False, "fusion": {"start": "mapper", "photos": [0, 1, 2]}}
    assert job_warnings(mapped, NAMES) == []
    assert job_warnings({**mapped, "fusion": {"photos": [0, 1]}}, NAMES) == [
        FOCAL_UNKNOWN_WARNING]


def test_matching_off_is_not_warned_as_photos_sharing_too_little() -> None:
    assert MATCHES_FEW_WARNING not in job_warnings({"focal_known": True}, NAMES)


def test_matches_the_start_set_aside_are_warned_as_such_not_as_too_few() -> None:
    from cadnerf_core.cameras.fusion import SET_ASIDE

    assert job_warnings({"focal_known": True, "fusion": dict(SET_ASIDE)}, NAMES) == [
        MATCHES_SET_ASIDE_WARNING]


def test_photos_too_small_to_match_are_named_and_replace_the_few_matches_warning() -> None:
    few = {"focal_known": True, "fusion": {"photos": []}}
    assert job_warnings({**few, "too_small": [0, 2]}, NAMES) == [
        too_small_warning(["a.jpg", "c.jpg"]), MATCHES_FEW_WARNING]
    # Every photo too small: the cause is known, so only it is warned.
    assert job_warnings({**few, "too_small": [0, 1, 2]}, NAMES) == [too_small_warning(NAMES)]
    assert "a.jpg, b.jpg, c.jpg" in too_small_warning(NAMES)


def test_each_warning_is_one_sentence_with_an_action_and_no_figures() -> None:
    texts = [FOCAL_UNKNOWN_WARNING, MATCHES_FEW_WARNING, MATCHES_SET_ASIDE_WARNING,
             direction_guess_hint(1),
             reorder_warning(NAMES), order_guess_warning(NAMES), too_small_warning(NAMES)]
    for text in texts:
        assert text[0].isupper() and text.endswith(".") and text.count(". ") == 0, text
        assert ";" in text or ": " in text  # what happened; what to do
        assert not re.search(r"\bdB\b|docs/|bench|measured|on average", text), text

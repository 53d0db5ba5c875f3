"""What a job tells its user went less well than it could: made once here, from the job's
retrieval and its masks, written to the job folder (``warnings.json``) by the pipeline and read
by the API and the CLI. Each warning is one sentence: what happened, then what to do.

Torch-free: the API imports this module.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from cadnerf_core.config_matches import MIN_SEARCH_SIDE

MATCHES_FEW_WARNING = (
    "The photos share too few points to place the cameras, so they come from silhouettes "
    "alone; take the photos closer together (about 30 degrees apart), in sharp light, of an "
    "object with some print, grain or texture.")
"""The photos' matches placed no camera (``fusion`` with no photos)."""

MATCHES_SET_ASIDE_WARNING = (
    "The points the photos share disagreed with their outlines, so the cameras come from the "
    "outlines alone; photos taken closer together (about 30 degrees apart) let the shared "
    "points decide.")
"""The start chose the retrieval left unfused (``fusion`` set aside): the pairs' rotations
pulled every hypothesis away from the silhouettes."""

FOCAL_UNKNOWN_WARNING = (
    "No photo carried its focal length (EXIF) and the photos' matches could not measure it, "
    "so the field of view was estimated from silhouettes; upload the files your phone wrote, "
    "or give retrieval.focal_35mm (a phone's main lens is about 26; CLI --focal-35mm).")
"""No photo's focal length was known and the mapper did not measure it (``focal_guessed``)."""


def outlines_alone_warning(names: Sequence[str]) -> str:
    """Some photos' cameras rest on their outlines alone while the others share points."""
    listed = ", ".join(names)
    return (f"The cameras of {listed} rest on their outlines alone (the other photos share "
            "points): retake those from between their neighbours, about 30 degrees from each, "
            "with the object's print or grain in view.")


def direction_guess_hint(direction: int) -> str:
    """The walking direction was a guess (``RetrievalResult.direction_ambiguous``): the way
    round it was taken (``direction`` +1 counter-clockwise seen from above, -1 clockwise) and
    the ``walk`` value that gives the other."""
    taken, side, other = (("counter-clockwise", "left", "cw") if direction >= 0
                          else ("clockwise", "right", "ccw"))
    return (f"The walking direction is a guess (the photos look alike walked either way "
            f"round): it was taken {taken}, the object on your {side}; if you walked the other "
            f"way, set retrieval.walk to \"{other}\" (CLI --walk {other}).")


def reorder_warning(names: Sequence[str]) -> str:
    """Photos given with ``order`` "auto" did not look like a walk and were reordered."""
    return ("The photos did not look like a walk in the order given, so they were walked in "
            f"this order: {', '.join(names)}; if you took them in the order given, set "
            "retrieval.order to \"walk\" (CLI --order walk).")


def order_guess_warning(names: Sequence[str]) -> str:
    """The walking order is a guess (``RetrievalResult.order_ambiguous``)."""
    return ("The walking order is a guess (another order of these photos fits almost as "
            f"well): they were walked as {', '.join(names)}; put the photos in the order you "
            "took them and set retrieval.order to \"walk\" (CLI --order walk).")


def too_small_warning(names: Sequence[str]) -> str:
    """Matching skipped these photos (``retrieval.json``'s ``too_small``): their object spans
    fewer than ``MIN_SEARCH_SIDE`` pixels."""
    return (f"The object spans fewer than {MIN_SEARCH_SIDE} pixels in {', '.join(names)}, "
            "too few for points shared with the other photos, so their cameras come from "
            "silhouettes alone; upload the photos at the size your camera took them.")


def focal_guessed(retrieval: dict[str, Any]) -> bool:
    """Whether a job's ``retrieval.json`` says its focal length is a guess: no photo carried
    it and the cameras did not start from the mapper, which measures it."""
    fusion = retrieval.get("fusion")
    mapped = isinstance(fusion, dict) and fusion.get("start") == "mapper"
    return retrieval.get("focal_known") is False and not mapped


def walk_order(retrieval: dict[str, Any], count: int) -> list[int]:
    """The walking order in ``retrieval.json`` (photo indices), or the given one where it names
    none or an unusable one."""
    order = retrieval.get("order")
    if isinstance(order, list) and sorted(order) == list(range(count)):
        return [int(i) for i in order]
    return list(range(count))


def job_warnings(retrieval: dict[str, Any], names: Sequence[str],
                 mask_warnings: Sequence[str] = ()) -> list[str]:
    """A job's warnings, in the order a user reads them: the masks', then the walking order,
    the walking direction, the focal length and the matches.

    Args:
        retrieval: the job's ``retrieval.json`` (``RetrievalResult.to_json()``).
        names: the photos' names, in upload order.
        mask_warnings: each photo's mask warnings, in upload order.
    """
    warnings = list(mask_warnings)
    order = [names[i] for i in walk_order(retrieval, len(names))]
    if retrieval.get("order_ambiguous"):
        warnings.append(order_guess_warning(order))
    elif retrieval.get("reordered") and retrieval.get("order_mode") == "auto":
        warnings.append(reorder_warning(order))
    if retrieval.get("direction_ambiguous"):
        warnings.append(direction_guess_hint(int(retrieval.get("direction", 1))))
    if focal_guessed(retrieval):
        warnings.append(FOCAL_UNKNOWN_WARNING)
    small = [names[i] for i in retrieval.get("too_small", []) if 0 <= i < len(names)]
    if small:
        warnings.append(too_small_warning(small))
    fusion = retrieval.get("fusion")
    if isinstance(fusion, dict) and fusion.get("set_aside"):
        warnings.append(MATCHES_SET_ASIDE_WARNING)
    elif isinstance(fusion, dict) and not fusion.get("photos") and len(small) < len(names):
        warnings.append(MATCHES_FEW_WARNING)  # not where every photo was too small to match
    elif isinstance(fusion, dict) and fusion.get("photos"):
        from cadnerf_core.cameras.confidence import camera_placements

        alone = [names[p.index] for p in camera_placements(retrieval)
                 if p.placed == "silhouettes" and 0 <= p.index < len(names)
                 and names[p.index] not in small]  # those are named above already
        if alone:
            warnings.append(outlines_alone_warning(alone))
    return warnings

"""The leave-out protocol: which library models were made to resemble each evaluation object.

The shipped library holds, besides its category models (chairs, mugs, cars, an airplane, ...),
models drawn after the evaluation objects were chosen, to look like them. Scored with those in
the library, a benchmark says how the method does on objects the library already holds; the
paper's promise is about objects it does not. So every benchmark that scores retrieval or novel
views runs "leave-out" (the headline: the object's look-alikes excluded from retrieval,
``RetrievalConfig.exclude_models``) and may add "with look-alike" (the whole library).

Category models that predate the evaluation set stay in under both protocols: a mug for the
YCB mug, an airliner for the plane and two cars for the Dodge are what any category library
(the paper's ShapeNet) holds. Siblings made alongside a look-alike but not shaped after an
evaluation object (``kettle``, ``dog_toy``, ``sneaker``) stay in too.
"""

from __future__ import annotations

from typing import Literal

Protocol = Literal["leave-out", "with look-alike"]
PROTOCOLS: tuple[Protocol, ...] = ("leave-out", "with look-alike")

LOOKALIKES: dict[str, dict[str, str]] = {
    "CesiumMilkTruck": {"truck": "box delivery truck drawn after the milk truck"},
    "Duck": {"duck_toy": "rubber duck drawn after the glTF Duck"},
    "YcbMustardBottle": {"squeeze_bottle": "flat-sided nozzle bottle drawn after the YCB "
                                           "mustard bottle"},
    "YcbPowerDrill": {"drill": "pistol-grip drill drawn after the YCB power drill"},
    "armchair": {"armchair": "upholstered armchair drawn after the kaolin armchair"},
    "fsu_big_dodge": {},  # car_sedan and car_suv are category models
    "fsu_kerolamp": {"oil_lamp": "hurricane lantern drawn after the kerosene lamp"},
    "fuze": {"sports_bottle": "waisted bottle with a cap drawn after the fuze bottle"},
    "os_boot": {"boot": "ankle boot drawn after the boot scan"},
    "os_plane": {},  # airplane is a category model
    "spot": {"cow_toy": "toy cow drawn after Keenan Crane's spot"},
    "teapot": {"teapot": "squat teapot drawn after the Utah teapot"},
    "ycb_mug": {},  # mug is a category model
    "ners_espresso": {"espresso_machine": "home espresso machine drawn after the espresso "
                                          "photos"},
    "raydiffusion_robot": {},  # no robot in the library
    # The real captures (``../shared/eval/captures``): nothing in the library was drawn after them.
    "dino_ring": {}, "dtu_scan24": {}, "dtu_scan37": {}, "ethiopian_head": {}, "gold_cape": {},
    "kermit": {}, "temple_ring": {},
    # The captures ``benchmarks.capture_import`` makes (``benchmarks/captures_sources.md``):
    # nothing in the library was drawn after them.
    "beer_can": {}, "cat_toy": {}, "cup": {}, "dino_walk": {}, "figurine": {}, "fruit": {},
    "milk_carton": {}, "mouse": {}, "temple_walk": {},
}
"""Evaluation object -> {library model id: why it is a look-alike}."""


def excluded(name: str, protocol: Protocol = "leave-out") -> tuple[str, ...]:
    """Library model ids to exclude for evaluation object ``name`` under ``protocol``.

    Raises:
        KeyError: an object the list does not cover (a new mesh must be added to it).
    """
    if name not in LOOKALIKES:
        raise KeyError(f"{name!r} has no entry in benchmarks.lookalikes.LOOKALIKES: add one")
    return tuple(LOOKALIKES[name]) if protocol == "leave-out" else ()


def exclude_overrides(name: str, protocol: Protocol = "leave-out") -> dict[str, list[str]]:
    """Config overrides that apply ``protocol`` to object ``name`` (empty: nothing excluded)."""
    ids = excluded(name, protocol)
    return {"retrieval.exclude_models": list(ids)} if ids else {}

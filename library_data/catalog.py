"""The parametric models shipped with the library: id, category, kind and builder of each."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import manifold3d as mf
import trimesh

from library_data import (
    animals,
    apparel,
    basic,
    furniture,
    gadgets,
    household,
    tools,
    vehicles,
)
from library_data.parts import to_trimesh

SOURCE = "parametric:cadnerf"
LICENCE = "MIT (project-generated)"


@dataclass(frozen=True)
class ParametricModel:
    """One parametric model of the shipped library."""

    id: str
    """Unique id, also the model's folder name."""
    category: str
    """Object category (chair, car, ...), or the shape name for basic shapes."""
    kind: str
    """"object" for real-world objects, "basic" for cuboids, cylinder and sphere."""
    build: Callable[[], mf.Manifold]
    """Builds the solid in its own units (+Y up, front toward +Z)."""

    def mesh(self) -> trimesh.Trimesh:
        """The normalised, watertight triangle mesh (bbox centre at 0, max |v| = 1)."""
        return to_trimesh(self.build())


_OBJECTS: list[tuple[str, str, Callable[[], mf.Manifold]]] = [
    ("chair_wood", "chair", furniture.chair_wood),
    ("chair_office", "chair", furniture.chair_office),
    ("table_dining", "table", furniture.table_dining),
    ("table_round", "table", furniture.table_round),
    ("bench", "bench", furniture.bench),
    ("sofa", "sofa", furniture.sofa),
    ("bed", "bed", furniture.bed),
    ("bookshelf", "bookshelf", furniture.bookshelf),
    ("desk", "desk", furniture.desk),
    ("stool", "stool", furniture.stool),
    ("piano", "piano", furniture.piano),
    ("mug", "mug", household.mug),
    ("cup", "cup", household.cup),
    ("bottle", "bottle", household.bottle),
    ("vase", "vase", household.vase),
    ("lamp", "lamp", household.lamp),
    ("bathtub", "bathtub", household.bathtub),
    ("toilet", "toilet", household.toilet),
    ("microwave", "microwave", household.microwave),
    ("monitor", "monitor", gadgets.monitor),
    ("camera", "camera", gadgets.camera),
    ("headphones", "headphones", gadgets.headphones),
    ("handbag", "handbag", gadgets.handbag),
    ("guitar", "guitar", gadgets.guitar),
    ("airplane", "airplane", vehicles.airplane),
    ("car_sedan", "car", vehicles.car_sedan),
    ("car_suv", "car", vehicles.car_suv),
    ("bicycle", "bicycle", vehicles.bicycle),
    ("teapot", "teapot", household.teapot),
    ("kettle", "kettle", household.kettle),
    ("duck_toy", "bird", animals.duck_toy),
    ("cow_toy", "animal", animals.cow_toy),
    ("dog_toy", "animal", animals.dog_toy),
    ("boot", "shoe", apparel.boot),
    ("sneaker", "shoe", apparel.sneaker),
    ("drill", "tool", tools.drill),
    ("oil_lamp", "lamp", household.oil_lamp),
    ("sports_bottle", "bottle", household.sports_bottle),
    ("armchair", "chair", furniture.armchair),
    ("truck", "car", vehicles.truck),
    ("squeeze_bottle", "bottle", household.squeeze_bottle),
    ("espresso_machine", "coffee machine", household.espresso_machine),
]

MODELS: list[ParametricModel] = [
    *(ParametricModel(i, c, "object", b) for i, c, b in _OBJECTS),
    *(ParametricModel(f"cuboid_{name}", "cuboid", "basic", partial(basic.cuboid, name))
      for name in basic.CUBOIDS),
    ParametricModel("cylinder", "cylinder", "basic", basic.cylinder),
    ParametricModel("sphere", "sphere", "basic", basic.sphere),
]
"""Every shipped model, in library order."""


def find_model(model_id: str) -> ParametricModel:
    """The parametric model with id ``model_id``.

    Raises:
        KeyError: if there is none.
    """
    for model in MODELS:
        if model.id == model_id:
            return model
    raise KeyError(model_id)

"""The settings a client may send: a job's ``overrides`` (HTTP) and ``--set`` (CLI).

A preset holds every value of a job (``cadnerf_core.config``); a client changes only the few
listed in ``CLIENT_SETTINGS``, each with a one-line description. ``ClientSettings`` is built from
that list and takes each setting's type and bounds from the pipeline config itself, so the two
never disagree; anything else a client sends is refused, naming it. Torch-free, like the config.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

from cadnerf_core.config import PipelineConfig, nest_dotted

CLIENT_SETTINGS: dict[str, str] = {
    "seed": "Random seed: the same seed on the same device gives the same result.",
    "image_size": "Side in pixels of the photo crops the NeRF is trained on: larger is sharper "
                  "and slower.",
    "scene_mode": "Also model the photos' background after the object.",
    "phase1.steps": "Training steps fitting the density to the retrieved CAD model.",
    "phase2.steps": "Training steps fitting shape and camera poses to the masks.",
    "phase3.steps": "Training steps fitting colour (and poses) to the photos.",
    "phase3.scene_steps": "With scene_mode: training steps of object and background together.",
    "masks.method": "Background removal for photos without a mask: \"auto\" (the learned "
                    "remover where installed, else GrabCut), \"learned\" or \"grabcut\".",
    "retrieval.order": "\"walk\": the photos are in walking order; \"any\": find the order; "
                       "\"auto\": keep the given order unless it is clearly not a walk.",
    "retrieval.walk": "Which way round you walked: \"ccw\" (the object on your left), \"cw\", "
                      "or \"auto\"; give it for objects alike from mirrored sides.",
    "retrieval.focal_35mm": "35 mm equivalent focal length of photos without EXIF (a phone's "
                            "main lens: about 26); EXIF wins.",
    "retrieval.shared_focal": "The photos share one focal length; false when you zoomed "
                              "between photos.",
    "retrieval.perspective": "Library silhouettes to match: \"far\" (a narrow lens), \"near\" "
                             "(a phone's wide lens) or \"auto\" (from the focal length).",
    "retrieval.exclude_models": "Library model ids never retrieved (a leave-out test on "
                                "objects the library has no look-alike of).",
    "retrieval.matches.enabled": "Match points between the photos to place the cameras; false: "
                                 "silhouettes alone.",
    "export.orbit_frames": "Frames of the orbit video and GIF.",
    "export.orbit_fps": "Frames per second of the orbit video and GIF.",
    "export.orbit_elevation": "Elevation of the orbit camera, in degrees above the object's "
                              "equator.",
    "export.orbit_size": "Side in pixels of the orbit frames and the rendered views (even).",
    "export.novel_views": "Views rendered from new poses, after the photos' own.",
    "export.mesh_resolution": "Marching-cubes grid side of the mesh: more is finer and slower.",
    "export.mesh_faces": "Triangles the mesh is simplified to.",
    "export.texture_size": "Side in pixels of the mesh's colour texture.",
    "export.texture_from_photos": "Colour the mesh from the photos themselves; false: from "
                                  "the learned field.",
}
"""Every setting a client may send, by dotted path, with its one-line description."""

MAX_CLIENT_SETTINGS = 30
"""The most settings a client may change: everything else is the preset's, fixed in code."""


class _Settings(BaseModel):
    """Base of the client settings' models: unknown keys refused, dotted keys nested."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _nest(cls, data: Any) -> Any:
        return nest_dotted(data) if isinstance(data, dict) else data


def _drop_default(schema: dict[str, Any]) -> None:
    """A setting absent keeps the preset's value, so the schema names no default."""
    schema.pop("default", None)


def _setting(model: type[BaseModel], path: list[str], description: str) -> Any:
    """The pydantic field of one client setting: the pipeline field's type and bounds."""
    info = model.model_fields[path[0]]
    if len(path) > 1:
        return _setting(info.annotation, path[1:], description)  # type: ignore[arg-type]
    annotation: Any = info.annotation
    if info.metadata:
        annotation = Annotated[(annotation, *info.metadata)]
    return (annotation, Field(None, description=description, json_schema_extra=_drop_default))


def _section(name: str, tree: dict[str, Any], model: type[BaseModel], prefix: str) -> Any:
    """A model for one level of ``tree`` (leaves: descriptions), typed after ``model``."""
    fields: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            inner = model.model_fields[key].annotation
            sub = _section(f"{name}{key.title()}", value, inner, f"{prefix}{key}.")  # type: ignore[arg-type]
            fields[key] = (sub, Field(None, description=f"`{prefix}{key}` settings.",
                                      json_schema_extra=_drop_default))
        else:
            fields[key] = _setting(model, [key], value)
    return create_model(name, __base__=_Settings,
                        __doc__=f"Client settings {prefix or 'of a job'}.", **fields)


def _tree() -> dict[str, Any]:
    tree: dict[str, Any] = {}
    for path, description in CLIENT_SETTINGS.items():
        *sections, leaf = path.split(".")
        node = tree
        for part in sections:
            node = node.setdefault(part, {})
        node[leaf] = description
    return tree


def _build() -> type[BaseModel]:
    model: type[BaseModel] = _section("ClientSettings", _tree(), PipelineConfig, "")
    model.__doc__ = ("The settings a client may change on top of its preset, nested by section "
                     "(dotted keys such as \"phase2.steps\" are accepted too); anything absent "
                     "keeps the preset's value.")
    return model


if TYPE_CHECKING:
    ClientSettings = _Settings
else:
    ClientSettings = _build()
"""The model of a job's ``overrides``: ``CLIENT_SETTINGS``, nested by section."""

REFERENCE_PRESETS = ("standard", "preview", "paper")
"""The presets whose values the settings reference shows, in its column order."""


def client_overrides(overrides: Any) -> dict[str, Any]:
    """A client's overrides, validated, as nested values to apply on top of a preset.

    Args:
        overrides: a dict (nested or dotted keys) or a ``ClientSettings``.
    Returns:
        The settings the client gave, nested (``{"retrieval": {"walk": "cw"}}``).
    Raises:
        pydantic.ValidationError: a setting that is not a client's, or a value out of range.
    """
    settings = overrides if isinstance(overrides, ClientSettings) \
        else ClientSettings.model_validate(overrides)
    return settings.model_dump(mode="json", exclude_unset=True)


def refused_names(loc: tuple[Any, ...], value: Any) -> str:
    """The dotted name of what a client sent that is no setting (a pydantic ``extra_forbidden``
    error's ``loc`` and ``input``): a whole section is named by its leaves."""
    if isinstance(value, dict) and value:
        return ", ".join(refused_names((*loc, key), inner) for key, inner in value.items())
    return ".".join(str(part) for part in loc)


def client_schema() -> dict[str, Any]:
    """The JSON Schema of ``ClientSettings`` with every nested section inlined (no ``$ref``)."""
    return inline_refs(ClientSettings.model_json_schema())


def inline_refs(schema: dict[str, Any]) -> dict[str, Any]:
    """A pydantic JSON Schema with its ``$defs`` substituted for every ``$ref``, so it can sit
    inside another document (the OpenAPI of ``POST /v1/jobs``)."""
    schema = dict(schema)
    defs = schema.pop("$defs", {})

    def inline(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str):
                merged = {**defs[ref.rsplit("/", 1)[-1]], **{k: v for k, v in node.items()
                                                              if k != "$ref"}}
                return inline(merged)
            return {key: inline(value) for key, value in node.items()}
        if isinstance(node, list):
            return [inline(item) for item in node]
        return node

    return inline(schema)  # type: ignore[no-any-return]


def schema_leaves(schema: dict[str, Any], prefix: str = "") -> dict[str, dict[str, Any]]:
    """The settings of an inlined schema by dotted path (sections walked into)."""
    leaves: dict[str, dict[str, Any]] = {}
    for name, prop in schema.get("properties", {}).items():
        if prop.get("type") == "object" and "properties" in prop:
            leaves.update(schema_leaves(prop, f"{prefix}{name}."))
        else:
            leaves[f"{prefix}{name}"] = prop
    return leaves


def _kind(prop: dict[str, Any]) -> str:
    """A setting's type and range in a few words."""
    options = prop.get("anyOf", [prop])
    parts = []
    for option in options:
        if "enum" in option:
            parts.append(" \\| ".join(json.dumps(v) for v in option["enum"]))
        elif option.get("type") == "array":
            parts.append(f"list of {option.get('items', {}).get('type', 'value')}")
        elif option.get("type") in ("integer", "number"):
            low = option.get("minimum", option.get("exclusiveMinimum"))
            high = option.get("maximum", option.get("exclusiveMaximum"))
            span = f" {low} to {high}" if low is not None and high is not None else ""
            parts.append(f"{option['type']}{span}")
        elif "type" in option:
            parts.append(str(option["type"]))
    return " or ".join(parts)


def settings_markdown() -> str:
    """The settings reference of ``docs/guide.md``: one row a setting, with the value of each of
    ``REFERENCE_PRESETS``; a markdown table with a trailing newline."""
    from cadnerf_core.config import PRESETS

    names = list(REFERENCE_PRESETS)
    presets = {name: PRESETS[name] for name in names}
    head = ["setting", "type", *(f"`{name}`" for name in names), "what"]
    rows = ["Generated from `cadnerf_core/config_client.py` by `cadnerf config --write "
            "docs/guide.md`; a preset's column gives its value.", "",
            "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for path, prop in schema_leaves(client_schema()).items():
        values = []
        for name in names:
            value: Any = presets[name].model_dump(mode="json")
            for part in path.split("."):
                value = value[part]
            values.append(f"`{json.dumps(value)}`")
        rows.append(f"| `{path}` | {_kind(prop)} | {' | '.join(values)} | "
                    f"{prop.get('description', '')} |")
    return "\n".join(rows) + "\n"


SETTINGS_START = "<!-- settings:start -->"
SETTINGS_END = "<!-- settings:end -->"


def with_settings_reference(document: str, reference: str) -> str:
    """``document`` with the text between ``SETTINGS_START`` and ``SETTINGS_END`` replaced by
    ``reference``; ValueError when the markers are missing."""
    start, end = document.find(SETTINGS_START), document.find(SETTINGS_END)
    if start < 0 or end < start:
        raise ValueError(f"the document lacks {SETTINGS_START} ... {SETTINGS_END}")
    head = document[:start + len(SETTINGS_START)]
    return f"{head}\n{reference}{document[end:]}"

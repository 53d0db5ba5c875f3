"""Presets and validation of user configurations (what the web service relies on)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from pydantic import ValidationError

from cadnerf_core.config import (
    DEFAULT_PRESET,
    PRESETS,
    PipelineConfig,
    RetrievalConfig,
    internal_config,
    resolve_config,
)
from tests.configs import TINY_PRESET, tiny_config

# The values that decide `preview`'s and `standard`'s results (docs/presets.md): a change to
# the config's shape must leave every one as it is.
PINNED: dict[str, dict[str, object]] = {
    "preview": {
        "image_size": 128, "use_deformation": False, "use_cad_init": True, "seed": 0,
        "field.hidden": 64, "field.n_blocks": 4, "field.pos_freqs": 6, "field.dir_freqs": 0,
        "field.color_hidden": 64, "field.color_layers": 4,
        "render.samples_per_ray": 32, "render.grid_resolution": 32, "render.bound": 1.1,
        "phase1.steps": 200, "phase1.batch_points": 4096, "phase1.lr": 1e-3,
        "phase2.steps": 400, "phase2.rays": 1024, "phase2.pose_window": (0.5, 1.0),
        "phase2.pose_lr": 2e-3, "phase2.train_density": True,
        "phase3.steps": 2000, "phase3.rays": 1024, "phase3.lr": 5e-4,
        "phase3.pose_window": (0.0, 0.75), "phase3.pose_lr": 2e-3, "phase3.pose_blur": 0.0625,
        "phase3.mask_weight": 0.1, "phase3.lambda_offset": 0.1,
        "export.orbit_size": 256, "export.orbit_frames": 36, "export.orbit_fps": 6,
        "export.mesh_resolution": 64,
        "retrieval.solver": "dp", "retrieval.shared_focal": True, "retrieval.perspective": "auto",
        "retrieval.discard_penalty": 0.3, "retrieval.spread_weight": 10.0,
        "retrieval.model_choice": "walk", "retrieval.appearance_weight": 0.2,
        "retrieval.appearance_threshold": 0.25, "retrieval.ambiguity_margin": 0.05,
        "retrieval.ambiguous_walk": "ccw", "retrieval.max_discard": 2,
    },
    "standard": {
        "image_size": 256, "use_deformation": True, "field.hidden": 128, "field.pos_freqs": 8,
        "field.deform_hidden": 64, "field.color_hidden": 96, "render.samples_per_ray": 64,
        "render.grid_update_every": 25, "phase1.steps": 200, "phase1.batch_points": 32768,
        "phase2.steps": 500, "phase2.rays": 8192, "phase3.steps": 1000, "phase3.rays": 8192,
    },
}


def _dotted(config: PipelineConfig, key: str) -> object:
    value: object = config
    for part in key.split("."):
        value = getattr(value, part)
    return value


@pytest.mark.parametrize("name", sorted(PINNED))
def test_preset_values_are_pinned(name: str) -> None:
    config = resolve_config(name, {})
    found = {key: _dotted(config, key) for key in PINNED[name]}
    assert found == PINNED[name]


def test_every_preset_resolves_to_itself() -> None:
    # The test suite's config is its own preset, registered by tests/configs.py only (a fresh
    # interpreter's presets: test_config_module_does_not_import_torch).
    assert set(PRESETS) == {"paper", "standard", "preview", TINY_PRESET}
    for name, preset in PRESETS.items():
        assert resolve_config(name, {}) == preset
        assert preset.preset == name
    assert resolve_config(None, None).preset == DEFAULT_PRESET == "standard"


def test_paper_preset_keeps_the_papers_values() -> None:
    paper = PRESETS["paper"]
    assert paper.field.n_blocks == 4 and paper.field.color_layers == 4
    assert paper.phase3.lambda_offset == 10.0 and paper.phase3.lambda_correction == 0.1
    assert paper.phase3.lr == 5e-4
    start, end = paper.phase2.pose_window
    assert (start * paper.phase2.steps, end * paper.phase2.steps) == (7500, 10000)
    assert paper.phase3.pose_window == (0.0, 0.0) and paper.phase3.mask_weight == 0.0


def test_overrides_nested_and_dotted() -> None:
    cfg = resolve_config("preview", {"phase2": {"steps": 7}, "export.orbit_frames": 12,
                                     "retrieval": {"matches.enabled": False}})
    assert cfg.phase2.steps == 7 and cfg.export.orbit_frames == 12
    assert cfg.retrieval.matches.enabled is False
    assert cfg.phase2.rays == PRESETS["preview"].phase2.rays  # untouched values stay
    assert cfg.retrieval.matches.size == PRESETS["preview"].retrieval.matches.size
    inner = internal_config("preview", {"phase2": {"steps": 7}, "use_deformation": True})
    assert PRESETS["preview"].use_deformation is False and inner.use_deformation is True
    assert inner.phase2.steps == 7


@pytest.mark.parametrize("key", ["use_deformation", "phase2.rays", "field.hidden",
                                 "retrieval.hypotheses", "retrieval.matches.size",
                                 "masks.doubt_weight", "preset"])
def test_a_client_may_not_set_what_the_presets_hold(key: str) -> None:
    """The preset's own values are refused from a client, by name; the internal path takes
    them."""
    value = {"use_deformation": True, "preset": "paper", "retrieval.hypotheses": 3,
             "masks.doubt_weight": 0.5}.get(key, 512)
    with pytest.raises(ValidationError) as caught:
        resolve_config("preview", {key: value})
    from cadnerf_core.config_client import refused_names

    errors = caught.value.errors()
    assert [refused_names(err["loc"], err["input"]) for err in errors] == [key]
    assert errors[0]["type"] == "extra_forbidden"
    if key != "preset":
        internal_config("preview", {key: value})


def test_deleted_settings_are_gone() -> None:
    """Levers no preset or benchmark used are not settings, even internally."""
    for key in ("phase2.prior_weight", "phase3.prior_points", "field.deform_freqs",
                "retrieval.matches.step_weight", "retrieval.matches.step_tolerance_deg"):
        with pytest.raises(ValidationError, match=key.rsplit(".", 1)[1]):
            internal_config("preview", {key: 1})


def test_client_settings_are_few_and_each_documented() -> None:
    from cadnerf_core.config_client import (
        CLIENT_SETTINGS,
        MAX_CLIENT_SETTINGS,
        client_schema,
        schema_leaves,
    )

    leaves = schema_leaves(client_schema())
    assert list(leaves) == list(CLIENT_SETTINGS)
    assert 0 < len(leaves) <= MAX_CLIENT_SETTINGS == 30
    for path, prop in leaves.items():
        description = prop.get("description", "")
        assert description and "\n" not in description, path
        value = PRESETS["preview"].model_dump(mode="json")
        for part in path.split("."):
            value = value[part]  # every setting is a field of the pipeline config
        assert resolve_config("preview", {path: value}) == PRESETS["preview"], path


def test_the_points_budget_bounds_what_a_preset_multiplies() -> None:
    """Each field within its own bound can still multiply past memory: the budget names it."""
    for overrides, field in (({"phase2.rays": 65536, "render.samples_per_ray": 512},
                              "phase2.rays"),
                             ({"phase1.batch_points": 262144, "field.hidden": 512},
                              "phase1.batch_points")):
        with pytest.raises(ValueError, match=field) as caught:
            internal_config("preview", overrides)
        assert "67108864" in str(caught.value)


@pytest.mark.parametrize("overrides", [
    {"phase2": {"stepz": 3}},
    {"nonsense": 1},
    {"phase1.steps": -1},
    {"image_size": 4},
    {"phase2.pose_window": [0.8, 0.2]},
    {"export.orbit_size": 33},
    {"seed": "abc"},
])
@pytest.mark.parametrize("resolve", [resolve_config, internal_config])
def test_invalid_overrides_are_rejected(overrides: dict[str, object], resolve) -> None:
    with pytest.raises(ValidationError):
        resolve("preview", overrides)


def test_unknown_preset_and_malformed_overrides() -> None:
    with pytest.raises(ValueError, match="unknown preset"):
        resolve_config("fastest", {})
    with pytest.raises(ValueError):
        resolve_config("preview", ["steps"])  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        resolve_config("preview", {"phase2": 3, "phase2.steps": 4})


def test_config_is_frozen_and_round_trips_json() -> None:
    cfg = tiny_config(seed=3)
    assert cfg.image_size == 32 and cfg.seed == 3
    with pytest.raises(ValidationError):
        cfg.seed = 4  # type: ignore[misc]
    assert PipelineConfig.model_validate_json(cfg.model_dump_json()) == cfg


def test_every_field_is_documented() -> None:
    from cadnerf_core import config as module

    for cls in (module.PipelineConfig, module.FieldConfig, module.RenderConfig,
                module.Phase1Config, module.Phase2Config, module.Phase3Config,
                module.ExportConfig, module.RetrievalConfig):
        source = __import__("inspect").getsource(cls)
        for name in cls.model_fields:
            after = source.split(f"    {name}:", 1)[1].splitlines()[1].strip()
            assert after.startswith('"""'), f"{cls.__name__}.{name} has no docstring"


def test_config_module_does_not_import_torch() -> None:
    code = ("import sys, cadnerf_core.config, cadnerf_core.config_client; "
            "print('torch' in sys.modules, sorted(cadnerf_core.config.PRESETS))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False ['paper', 'preview', 'standard']"


def test_one_retrieval_config_for_jobs_and_retrieve() -> None:
    """The job's ``retrieval`` section is what ``retrieve`` takes: its internals are settable
    from a job and the bounds are one set."""
    from cadnerf_core.retrieval import search as module

    cfg = internal_config("preview", {"retrieval.spread_weight": 0.0, "retrieval.walk": "cw"})
    assert type(cfg.retrieval) is RetrievalConfig
    assert cfg.retrieval == RetrievalConfig(spread_weight=0.0, walk="cw")
    assert module.RetrievalConfig is RetrievalConfig
    for bad in ({"top_k": 101}, {"max_discard": 6}, {"spread_weight": -1.0}, {"size": 64}):
        with pytest.raises(ValidationError):
            RetrievalConfig(**bad)  # type: ignore[arg-type]
        with pytest.raises(ValidationError):
            internal_config("preview", {"retrieval": bad})


def test_config_modules_carry_no_measurements_or_machines() -> None:
    """Docstrings and comments of the config say what and why; figures live in docs/presets.md."""
    import re
    from pathlib import Path

    import cadnerf_core

    figure = re.compile(r"\d\s?(dB|%|GiB)\b|\d+(\.\d+)? s\b|\b(H100|H200|RTX|A100)\b|"
                        r"\bbench_[a-z_]+|CPU cores|\d+(\.\d+)?[- ]degrees? (off|better|median)")
    for name in ("config", "config_retrieval", "config_matches", "config_bounds",
                 "config_client"):
        text = (Path(cadnerf_core.__file__).parent / f"{name}.py").read_text()
        found = [m.group(0) for m in figure.finditer(text)]
        assert not found, (name, found)

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
    resolve_config,
)
from tests.configs import tiny_config

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
        "phase2.pose_lr": 2e-3, "phase2.train_density": True, "phase2.prior_weight": 0.0,
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
    assert set(PRESETS) == {"paper", "standard", "preview"}  # the test suite's config is its own
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
                                     "use_deformation": True})
    assert cfg.phase2.steps == 7 and cfg.export.orbit_frames == 12
    assert PRESETS["preview"].use_deformation is False and cfg.use_deformation is True
    assert cfg.phase2.rays == PRESETS["preview"].phase2.rays  # untouched values stay


@pytest.mark.parametrize("overrides", [
    {"phase2": {"stepz": 3}},
    {"nonsense": 1},
    {"phase1.steps": -1},
    {"image_size": 4},
    {"phase2.pose_window": [0.8, 0.2]},
    {"export.orbit_size": 33},
    {"seed": "abc"},
])
def test_invalid_overrides_are_rejected(overrides: dict[str, object]) -> None:
    with pytest.raises(ValidationError):
        resolve_config("preview", overrides)


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
    code = "import sys, cadnerf_core.config; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_one_retrieval_config_for_jobs_and_retrieve() -> None:
    """The job's ``retrieval`` section is what ``retrieve`` takes: its internals are settable
    from a job and the bounds are one set."""
    from cadnerf_core.retrieval import retrieve as module

    cfg = resolve_config("preview", {"retrieval.spread_weight": 0.0, "retrieval.walk": "cw"})
    assert type(cfg.retrieval) is RetrievalConfig
    assert cfg.retrieval == RetrievalConfig(spread_weight=0.0, walk="cw")
    assert module.RetrievalConfig is RetrievalConfig
    for bad in ({"top_k": 101}, {"max_discard": 6}, {"spread_weight": -1.0}, {"size": 64}):
        with pytest.raises(ValidationError):
            RetrievalConfig(**bad)  # type: ignore[arg-type]
        with pytest.raises(ValidationError):
            resolve_config("preview", {"retrieval": bad})

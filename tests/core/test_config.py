"""Presets and validation of user configurations (what the web service relies on)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from pydantic import ValidationError

from cadnerf_core.config import DEFAULT_PRESET, PRESETS, PipelineConfig, resolve_config


def test_every_preset_resolves_to_itself() -> None:
    assert {"paper", "standard", "preview", "test"} <= set(PRESETS)
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
        resolve_config("test", overrides)


def test_unknown_preset_and_malformed_overrides() -> None:
    with pytest.raises(ValueError, match="unknown preset"):
        resolve_config("fastest", {})
    with pytest.raises(ValueError):
        resolve_config("test", ["steps"])  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        resolve_config("test", {"phase2": 3, "phase2.steps": 4})


def test_config_is_frozen_and_round_trips_json() -> None:
    cfg = resolve_config("test", {"seed": 3})
    with pytest.raises(ValidationError):
        cfg.seed = 4  # type: ignore[misc]
    assert PipelineConfig.model_validate_json(cfg.model_dump_json()) == cfg


def test_every_field_is_documented() -> None:
    from cadnerf_core import config as module

    for cls in (module.PipelineConfig, module.FieldConfig, module.RenderConfig,
                module.Phase1Config, module.Phase2Config, module.Phase3Config,
                module.ExportConfig, module.RetrievalOptions):
        source = __import__("inspect").getsource(cls)
        for name in cls.model_fields:
            after = source.split(f"    {name}:", 1)[1].splitlines()[1].strip()
            assert after.startswith('"""'), f"{cls.__name__}.{name} has no docstring"


def test_config_module_does_not_import_torch() -> None:
    code = "import sys, cadnerf_core.config; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"

"""How much work a job's configuration asks of each stage, against its preset's own values.

The stage tables and the measured history (``app.state.eta``) hold seconds for a preset as it
is; a job with overrides (ten times the steps, twice the orbit size) scales each stage by the
ratio of what drives its cost: steps x rays x samples in training, pixels x samples in
rendering, grid cells in the mesh export. Widths are left out: on a GPU a step of these small
networks costs about the same whatever their width.
"""

from __future__ import annotations

from collections.abc import Mapping

from app.core import DEFAULT_PRESET, PRESETS, PipelineConfig

MIN_SCALE, MAX_SCALE = 1e-3, 1e6  # a stage of 0 steps still reports; nothing is unbounded
_VIEWS = 6  # photos a job renders views of (only the ratio matters; novel views are added)


def _costs(config: PipelineConfig) -> dict[str, float]:
    """Relative cost of each stage that configuration can change."""
    render, export = config.render, config.export
    samples = render.samples_per_ray
    phase3_steps = config.phase3.steps + (config.phase3.scene_steps if config.scene_mode else 0)
    pixels = ((_VIEWS + export.novel_views) * config.image_size ** 2
              + export.orbit_frames * export.orbit_size ** 2)
    return {
        "phase1": config.phase1.steps * config.phase1.batch_points if config.use_cad_init else 0,
        "phase2": config.phase2.steps * config.phase2.rays * samples,
        "phase3": phase3_steps * config.phase3.rays * samples,
        "render": pixels * samples,
        "export": export.mesh_resolution ** 3,
    }


def stage_work(config: PipelineConfig) -> dict[str, float]:
    """Per stage, the job's work over its preset's (1.0: as the preset); stages no setting
    changes (masks, retrieval) are left out."""
    base = _costs(PRESETS.get(config.preset, PRESETS[DEFAULT_PRESET]))
    own = _costs(config)
    return {stage: round(min(max(own[stage] / base[stage], MIN_SCALE), MAX_SCALE), 4)
            if base[stage] > 0 else 1.0 for stage in own}


def scaled(table: Mapping[str, float], work: Mapping[str, float] | None) -> dict[str, float]:
    """Seconds per stage of a preset, scaled by a job's ``stage_work``."""
    return {stage: seconds * (work or {}).get(stage, 1.0) for stage, seconds in table.items()}


def unscaled(durations: Mapping[str, float], work: Mapping[str, float] | None
             ) -> dict[str, float]:
    """A job's measured seconds per stage brought back to its preset's work (for the history
    of the preset, which a job with ten times the steps must not inflate)."""
    return {stage: seconds / (work or {}).get(stage, 1.0) for stage, seconds in durations.items()}

"""The test suite's own job configuration: a whole job in seconds on the CPU.

Not a public preset: tests send it over HTTP as the ``preview`` preset with these overrides (the
same validation a user's overrides get), and core tests resolve it directly. The numbers only
need to exercise every code path; G is on so phase two's deformation runs too.
"""

from __future__ import annotations

import json
from typing import Any

from cadnerf_core.config import PipelineConfig, resolve_config

TINY_PRESET = "preview"
TINY_OVERRIDES: dict[str, Any] = {
    "image_size": 32,
    "use_deformation": True,
    "field": {"hidden": 16, "pos_freqs": 3, "dir_freqs": 2, "deform_hidden": 16,
              "deform_layers": 1, "color_hidden": 16, "color_layers": 2},
    "render": {"samples_per_ray": 12, "grid_resolution": 8, "grid_update_every": 3,
               "chunk_rays": 512},
    "phase1": {"steps": 4, "batch_points": 256},
    "phase2": {"steps": 6, "rays": 64},
    "phase3": {"steps": 6, "rays": 64, "scene_steps": 3},
    "export": {"orbit_frames": 4, "orbit_size": 32, "novel_views": 1, "mesh_resolution": 16,
               "texture_size": 64},
    # One start hypothesis: fits of a few steps are noise, and tests assert what retrieval
    # found; the tests of the robust start ask for more.
    "retrieval": {"hypotheses": 1, "hypothesis_steps": 4, "hypothesis_size": 16},
}


def tiny_request(**overrides: Any) -> dict[str, Any]:
    """The ``config`` form field of a tiny job (extra overrides merged on top, one level deep)."""
    merged = {k: (dict(v) if isinstance(v, dict) else v) for k, v in TINY_OVERRIDES.items()}
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key].update(value)
        else:
            merged[key] = value
    return {"preset": TINY_PRESET, "overrides": merged}


def tiny_request_json(**overrides: Any) -> str:
    """``tiny_request`` as the JSON text a multipart form carries."""
    return json.dumps(tiny_request(**overrides))


def tiny_config(**overrides: Any) -> PipelineConfig:
    """The tiny configuration, resolved and validated like a job's."""
    request = tiny_request(**overrides)
    return resolve_config(request["preset"], request["overrides"])


def tiny_cli_options(**overrides: Any) -> list[str]:
    """``tiny_request`` as ``cadnerf reconstruct`` options: ``--preset`` and one ``--set`` a key."""
    request = tiny_request(**overrides)
    return ["--preset", request["preset"], *(f"--set={key}={json.dumps(value)}"
                                             for key, value in request["overrides"].items())]

"""The test suite's own job configuration: a whole job in seconds on the CPU.

Not a public preset: importing this module registers it as the preset ``tiny`` in the test
process (``cadnerf_core.config.PRESETS``), so tests send it over HTTP as any client sends a
preset, with only the settings a client may send on top (the same validation a user's get).
Child processes the tests start (an API, a worker, ``cadnerf serve``) run through
``tests/tiny_cli.py``, which imports this module first. Core tests may set any field on top
(``tiny_config``, the internal path). The numbers only need to exercise every code path; G is on
so phase two's deformation runs too.
"""

from __future__ import annotations

import json
from typing import Any

from cadnerf_core.config import PRESETS, PipelineConfig, internal_config, resolve_config

TINY_PRESET = "tiny"
TINY_BASE = "preview"
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
"""The tiny preset's values on top of ``TINY_BASE``."""

PRESETS[TINY_PRESET] = internal_config(TINY_BASE, TINY_OVERRIDES).model_copy(
    update={"preset": TINY_PRESET})


def tiny_request(**overrides: Any) -> dict[str, Any]:
    """The ``config`` form field of a tiny job: the preset and a client's ``overrides``."""
    return {"preset": TINY_PRESET, "overrides": overrides}


def tiny_request_json(**overrides: Any) -> str:
    """``tiny_request`` as the JSON text a multipart form carries."""
    return json.dumps(tiny_request(**overrides))


def tiny_config(**overrides: Any) -> PipelineConfig:
    """The tiny configuration with any fields overridden (the internal path: core tests set
    fields a client may not)."""
    return internal_config(TINY_PRESET, overrides)


def tiny_client_config(**overrides: Any) -> PipelineConfig:
    """The tiny configuration with a client's settings, resolved as the service resolves them."""
    return resolve_config(TINY_PRESET, overrides)


def tiny_cli_options(**overrides: Any) -> list[str]:
    """``tiny_request`` as ``cadnerf reconstruct`` options: ``--preset`` and one ``--set`` a key."""
    request = tiny_request(**overrides)
    return ["--preset", request["preset"], *(f"--set={key}={json.dumps(value)}"
                                             for key, value in request["overrides"].items())]

SIGTERM_LIMIT_S = 10.0
"""What `docker stop` and Kubernetes give a process between SIGTERM and SIGKILL: the one
time limit the stop tests hold."""

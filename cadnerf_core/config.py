"""Pipeline configuration: one frozen schema per section, named presets, validated overrides.

Torch-free on purpose: the web service imports this module to validate a job's configuration
before it is queued. Field docstrings say what a field does and why its default; the measured
reasons for each preset's values are in ``docs/presets.md``. Where the paper ("CAD-NeRF", Wen
et al.) gives a value the ``paper`` preset uses it; everything else is ours.

Two ways in: ``resolve_config`` takes a client's overrides, only the settings of
``cadnerf_core.config_client``; ``internal_config`` takes any field, for the pipeline's own
callers (evaluation, benchmarks, tests) and never for a client's values.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, model_validator

from cadnerf_core.config_bounds import (
    MAX_LR,
    MAX_POINTS,
    MAX_RAYS,
    MAX_SAMPLES,
    MAX_SEED,
    MAX_STEPS,
    MAX_WEIGHT,
    check_point_budget,
)
from cadnerf_core.config_bounds import Frozen as _Frozen
from cadnerf_core.config_retrieval import MatchesConfig as MatchesConfig
from cadnerf_core.config_retrieval import RetrievalConfig as RetrievalConfig


def _check_window(name: str, window: tuple[float, float]) -> None:
    """Raise ValueError unless ``0 <= start <= end <= 1``."""
    start, end = window
    if not 0.0 <= start <= end <= 1.0:
        raise ValueError(f"{name} must satisfy 0 <= start <= end <= 1, got {start, end}")


class FieldConfig(_Frozen):
    """Network sizes."""

    hidden: int = Field(default=64, ge=8, le=1024)
    """Width of the density network D (its ResNetBlockFC blocks) and of its feature vector."""
    n_blocks: int = Field(default=4, ge=1, le=16)
    """Number of ResNetBlockFC blocks in D (the paper: 4)."""
    pos_freqs: int = Field(default=6, ge=0, le=16)
    """Positional-encoding frequencies for 3D points (sin/cos of 2^k * pi * x, k < pos_freqs)."""
    dir_freqs: int = Field(default=0, ge=0, le=8)
    """Positional-encoding frequencies of view directions (0: the raw direction). Ours: 0; with
    3 to 10 photos more let the colour net paint each photo apart, which new views pay for."""
    deform_hidden: int = Field(default=64, ge=8, le=1024)
    """Width of the deformation network G."""
    deform_layers: int = Field(default=3, ge=1, le=12)
    """Hidden layers of G."""
    color_hidden: int = Field(default=64, ge=8, le=1024)
    """Width of the colour network."""
    color_layers: int = Field(default=4, ge=1, le=12)
    """Layers of the colour network (the paper: 4)."""
    color_planes: int = Field(default=0, ge=0, le=8)
    """Levels of multiresolution feature planes the colour network also reads at each point
    (``nerf.fields.ColorPlanes``; 0: none, the paper's colour from D's feature alone)."""
    color_plane_size: int = Field(default=512, ge=16, le=2048)
    """Side in texels of the finest colour plane over [-bound, bound] (levels from 32 up)."""
    color_plane_channels: int = Field(default=4, ge=1, le=32)
    """Feature channels of each colour plane level."""


class RenderConfig(_Frozen):
    """Ray sampling and empty-space skipping."""

    samples_per_ray: int = Field(default=48, ge=4, le=MAX_SAMPLES)
    """Samples along each ray between its entry and exit of the bounding sphere."""
    bound: float = Field(default=1.1, gt=0.5, le=4.0)
    """Radius of the sampling sphere: the object fills the unit sphere, G may grow it."""
    grid_resolution: int = Field(default=32, ge=4, le=128)
    """Cells per side of the empty-space-skipping grid over [-bound, bound]^3."""
    grid_dilation: int = Field(default=2, ge=0, le=16)
    """Cells added around occupied cells, so the deformation can grow the shape into them."""
    grid_threshold: float = Field(default=0.01, ge=0.0, lt=1.0)
    """Occupancy above which a grid cell counts as occupied when updated from the learned field."""
    grid_update_every: int = Field(default=100, ge=1, le=MAX_STEPS)
    """Training steps between two updates of the grid from the learned density."""
    use_grid: bool = True
    """Skip samples in empty grid cells (off: every sample is evaluated)."""
    cull_alpha: float = Field(default=1e-3, ge=0.0, lt=1.0)
    """Phase three leaves out of its differentiable pass the samples whose occupancy, looked
    up first without gradients, is below this or which lie behind opaque matter (as nerfacc's
    ``alpha_thre``): they add next to nothing to a pixel or a gradient. The offset and
    correction regularisers then average over the samples kept. 0: every sample (``paper``,
    whose regularisers average over every sample in the grid)."""
    chunk_rays: int = Field(default=0, ge=0, le=MAX_RAYS)
    """Rays per chunk when rendering images (memory bound, not a quality setting). 0: a large
    chunk on a GPU (fewer, larger launches), a small one on the CPU."""
    train_pass_rays: int = Field(default=0, ge=0, le=MAX_RAYS)
    """Rays per forward and backward pass; a step's passes add their gradients (same loss, less
    memory). 0: one pass on a GPU; on the CPU, where larger passes are slower per ray, smaller
    ones."""


class Phase1Config(_Frozen):
    """Phase one: D pretrained to the retrieved CAD model's occupancy (binary cross entropy)."""

    steps: int = Field(default=400, ge=0, le=MAX_STEPS)
    """Optimisation steps."""
    batch_points: int = Field(default=4096, ge=16, le=MAX_POINTS)
    """Points per step, sampled from the library occupancy grid."""
    near_surface: float = Field(default=0.5, ge=0.0, le=1.0)
    """Fraction of points drawn near the surface (the rest uniformly in the cube)."""
    lr: float = Field(default=1e-3, gt=0.0, le=MAX_LR)
    """Adam learning rate."""


class Phase2Config(_Frozen):
    """Phase two: deformation G and camera poses from silhouettes (accumulated opacity vs mask)."""

    steps: int = Field(default=600, ge=0, le=MAX_STEPS)
    """Optimisation steps."""
    rays: int = Field(default=1024, ge=16, le=MAX_RAYS)
    """Rays per step, drawn from all training photos."""
    lr: float = Field(default=5e-4, gt=0.0, le=MAX_LR)
    """Adam learning rate of G (of D when the deformation is off)."""
    pose_lr: float = Field(default=2e-3, gt=0.0, le=MAX_LR)
    """Adam learning rate of the SE(3) pose corrections."""
    pose_window: tuple[float, float] = (0.5, 1.0)
    """Fractions of phase two's steps in which poses are optimised. Late, as in the paper, once
    G has bent the CAD prior toward the masks; earlier, the poses follow the CAD shape."""
    anneal: tuple[float, float] = (0.0, 0.5)
    """Fractions of phase two over which positional-encoding frequencies are switched on
    coarse-to-fine (BARF); all are on after the second value."""
    train_density: bool = True
    """Train D with G (ours) rather than deform a frozen D (the paper): the poses move closer
    to the truth. Without G, off holds the CAD shape while phase two refines the poses
    against it (its steps outside the pose window skipped)."""
    lambda_offset: float = Field(default=0.1, ge=0.0, le=MAX_WEIGHT)
    """Weight of the mean offset norm ||o||_2 in phase two (ours: the paper's weight on a mean
    pins G at 0)."""
    lambda_correction: float = Field(default=0.01, ge=0.0, le=MAX_WEIGHT)
    """Weight of the mean |c| (logit units) in phase two (ours, as above)."""
    focal_bound: float = Field(default=1.0, ge=1.0, le=4.0)
    """Where no photo's EXIF (nor ``retrieval.focal_35mm``) gives the focal length: the one
    focal length the photos share is refined with the poses, in both phases' pose windows (as
    NeRF-- does), by a factor kept within [1 / bound, bound] (1: fixed at retrieval's
    estimate, which assumes the library's camera)."""
    focal_lr: float = Field(default=1e-2, gt=0.0, le=MAX_LR)
    """Adam learning rate of the focal factor's logit (``focal_bound``), in either phase."""
    lambda_matches: float = Field(default=0.01, ge=0.0, le=MAX_WEIGHT)
    """Weight of the epipolar loss of the photos' matches on the poses in phase two's pose
    window (``nerf.epipolar``: robust Sampson distance in crop pixels, per camera; 0: off).
    Nothing changes for an object with too few matches (a texture-less one)."""

    @model_validator(mode="after")
    def _check_windows(self) -> Phase2Config:
        _check_window("pose_window", self.pose_window)
        _check_window("anneal", self.anneal)
        return self


class Phase3Config(_Frozen):
    """Phase three: colour network; D, G and colour trained on colour re-rendering."""

    steps: int = Field(default=1000, ge=0, le=MAX_STEPS)
    """Optimisation steps."""
    rays: int = Field(default=1024, ge=16, le=MAX_RAYS)
    """Rays per step."""
    lr: float = Field(default=5e-4, gt=0.0, le=MAX_LR)
    """Adam learning rate (the paper: 5e-4)."""
    lambda_offset: float = Field(default=0.1, ge=0.0, le=MAX_WEIGHT)
    """Weight of the mean offset norm ||o||_2 (the paper's lambda_a, kept by ``paper``; ours
    is lower so that phase two's deformation survives phase three)."""
    lambda_correction: float = Field(default=0.01, ge=0.0, le=MAX_WEIGHT)
    """Weight of the mean |c| (the paper's lambda_b in ``paper``; lower in ours, as above)."""
    mask_weight: float = Field(default=0.1, ge=0.0, le=MAX_WEIGHT)
    """Weight of the silhouette loss kept during phase three (ours; the paper uses none)."""
    pose_window: tuple[float, float] = (0.0, 0.75)
    """Fractions of phase three's steps in which the colour loss refines poses ((0, 0): frozen,
    the paper). Ours: three quarters, then the sharp photos are fitted with poses settled."""
    pose_lr: float = Field(default=2e-3, gt=0.0, le=MAX_LR)
    """Adam learning rate of the pose corrections in phase three's window."""
    pose_blur: float = Field(default=0.0625, ge=0.0, le=0.5)
    """Blur (Gaussian sigma, a fraction of the image side) of the colour targets in the pose
    window, halved each third of it (0: never): it widens the loss's basin in pose."""
    lambda_matches: float = Field(default=0.01, ge=0.0, le=MAX_WEIGHT)
    """Weight of the epipolar loss of the photos' matches in phase three's pose window (as
    ``Phase2Config.lambda_matches``; 0: off)."""
    scene_steps: int = Field(default=0, ge=0, le=MAX_STEPS)
    """Scene mode only: steps after the object's, training object and background together."""
    image_size: int = Field(default=0, ge=0, le=1024)
    """Side of the photo crops phase three learns colour from (0: the job's ``image_size``):
    larger shows the colour field the photos' detail at the cost of building the crops (the
    matches' epipolar term then reads that crop's pixels too)."""
    plane_lr: float = Field(default=1e-2, gt=0.0, le=MAX_LR)
    """Adam learning rate of the colour planes (``field.color_planes``): texels, as grid
    fields train them, learn at a larger rate than the networks."""
    lambda_planes: float = Field(default=1e-2, ge=0.0, le=MAX_WEIGHT)
    """Weight of the colour planes' total variation (``ColorPlanes.smoothness``)."""
    object_rays: float = Field(default=0.0, ge=0.0, le=1.0)
    """Share of each step's rays drawn on the photos' objects (their masks and a 2-pixel
    edge; the rest anywhere, for the white around them): where the detail is (0: uniform)."""

    @model_validator(mode="after")
    def _check_windows(self) -> Phase3Config:
        if self.image_size and self.image_size < 16:
            raise ValueError("phase3.image_size must be 0 (the job's) or at least 16")
        _check_window("pose_window", self.pose_window)
        return self


class ExportConfig(_Frozen):
    """What the job writes."""

    orbit_frames: int = Field(default=180, ge=2, le=240)
    """Frames in orbit.mp4 and orbit.gif (with ``orbit_fps``: the orbit's length)."""
    orbit_fps: int = Field(default=30, ge=1, le=120)
    """Frames per second of the video."""
    orbit_elevation: float = Field(default=20.0, ge=-89.0, le=89.0)
    """Elevation of the orbit camera in degrees."""
    orbit_size: int = Field(default=512, ge=16, le=1024)
    """The output size: side in pixels of the orbit frames and of views/ (even, for H.264
    yuv420p), whatever the training resolution."""
    novel_views: int = Field(default=4, ge=0, le=64)
    """Extra views rendered at new poses into views/, after the ones at the photo poses."""
    mesh_resolution: int = Field(default=96, ge=16, le=256)
    """Marching-cubes grid side for mesh.glb."""
    mesh_level: float = Field(default=0.5, gt=0.0, lt=1.0)
    """Occupancy level of the extracted surface."""
    mesh_faces: int = Field(default=20000, ge=100, le=200_000)
    """Triangles mesh.glb is decimated to (fewer when marching cubes gives fewer)."""
    texture_size: int = Field(default=2048, ge=16, le=4096)
    """Side in pixels of the mesh's colour texture."""
    texture_from_photos: bool = True
    """Colour the mesh's texture from the photos themselves (each texel from the photos that
    see it, at their own resolution, exposures matched; ``export.photo_texture``), the field's
    colour only where no photo sees the surface; false: the field's colour everywhere."""

    @model_validator(mode="after")
    def _even(self) -> ExportConfig:
        if self.orbit_size % 2:
            raise ValueError("orbit_size must be even (H.264 yuv420p)")
        return self


class MasksConfig(_Frozen):
    """Background removal for photos that bring no mask of their own."""

    method: Literal["auto", "learned", "grabcut"] = "auto"
    """"auto": the learned remover where its package is installed, else GrabCut."""
    doubt_weight: float = Field(default=1.0, ge=0.0, le=1.0)
    """Weight in the silhouette losses of the pixels where a learned mask is in doubt (its
    refined cut and the network's first look disagree): 0 leaves them to the other views, 1
    counts them as any pixel. 1: on real photos most doubtful pixels are right
    (``docs/presets.md``)."""


class PipelineConfig(_Frozen):
    """Everything that decides a job's result. Runtime objects (device, library) are not here."""

    preset: str = "standard"
    """Name of the preset these values started from (informational)."""
    seed: int = Field(default=0, ge=0, le=MAX_SEED)
    """Random seed: two runs with the same seed on the CPU give the same result."""
    image_size: int = Field(default=128, ge=16, le=1024)
    """Side of the canonical photo crops the NeRF is trained on (and retrieval's ``K_canon``)."""
    use_cad_init: bool = True
    """Phase one on: D starts as the retrieved CAD model's occupancy (off: from scratch)."""
    optimise_poses: bool = True
    """Refine the retrieved camera poses in phase two (off: keep them)."""
    use_deformation: bool = True
    """Train deformation G over D (off: D itself is fitted to the silhouettes in phase two)."""
    scene_mode: bool = False
    """Also model the photos' background (a view-direction background field) after the object."""
    mixed_precision: bool = True
    """torch.autocast (bfloat16) on CUDA; ignored on the CPU."""
    field: FieldConfig = Field(default_factory=FieldConfig)
    """Network sizes."""
    render: RenderConfig = Field(default_factory=RenderConfig)
    """Ray sampling and empty-space skipping."""
    phase1: Phase1Config = Field(default_factory=Phase1Config)
    """Phase one."""
    phase2: Phase2Config = Field(default_factory=Phase2Config)
    """Phase two."""
    phase3: Phase3Config = Field(default_factory=Phase3Config)
    """Phase three."""
    masks: MasksConfig = Field(default_factory=MasksConfig)
    """Background removal."""
    retrieval: RetrievalConfig = Field(default_factory=RetrievalConfig)
    """Model and pose retrieval."""
    export: ExportConfig = Field(default_factory=ExportConfig)
    """Outputs."""

    @model_validator(mode="after")
    def _check_budget(self) -> PipelineConfig:
        check_point_budget(self)
        return self


def _preset(name: str, **sections: Any) -> PipelineConfig:
    return PipelineConfig.model_validate({"preset": name, **sections})


# What each preset is for and the measurements behind its values: docs/presets.md.
PRESETS: dict[str, PipelineConfig] = {
    # The paper's values where it gives them (blocks, layers, lambdas, lr, pose window, no
    # silhouette loss in phase three); sizes and step counts ours. Slow: meant for a GPU.
    "paper": _preset(
        "paper", image_size=256,
        field={"hidden": 256, "pos_freqs": 10, "dir_freqs": 4, "deform_hidden": 128,
               "deform_layers": 4, "color_hidden": 128},
        render={"samples_per_ray": 128, "grid_resolution": 64, "grid_dilation": 3,
                "cull_alpha": 0.0},
        phase1={"steps": 2000, "batch_points": 16384, "lr": 5e-4},
        phase2={"steps": 10000, "rays": 2048, "pose_window": (0.75, 1.0), "anneal": (0.0, 0.5),
                "train_density": False, "lambda_matches": 0.0},
        phase3={"steps": 20000, "rays": 2048, "mask_weight": 0.0, "scene_steps": 5000,
                "lambda_offset": 10.0, "lambda_correction": 0.1, "pose_window": (0.0, 0.0),
                "pose_blur": 0.0, "lambda_matches": 0.0},
        export={"orbit_size": 512, "mesh_resolution": 160}),
    # The default: best quality on a GPU. Few large steps: on a GPU a step of these small
    # networks costs about the same whatever its batch.
    "standard": _preset(
        "standard", image_size=256,
        field={"hidden": 128, "pos_freqs": 8, "deform_hidden": 64, "color_hidden": 96},
        render={"samples_per_ray": 64, "grid_resolution": 48, "grid_update_every": 25},
        phase1={"steps": 200, "batch_points": 32768},
        phase2={"steps": 500, "rays": 8192},
        phase3={"steps": 1000, "rays": 8192, "scene_steps": 250},
        export={"orbit_size": 512, "mesh_resolution": 128}),
    # A useful result in minutes on a CPU. No G: D is fitted to the silhouettes in
    # its place, as good within a seed's spread and faster at this scale.
    "preview": _preset(
        "preview", image_size=128, use_deformation=False,
        field={"hidden": 64, "pos_freqs": 6, "deform_hidden": 48, "color_hidden": 64},
        render={"samples_per_ray": 32, "grid_resolution": 32},
        phase1={"steps": 200, "batch_points": 4096},
        phase2={"steps": 400, "rays": 1024},
        phase3={"steps": 2000, "rays": 1024, "scene_steps": 300},
        export={"orbit_size": 256, "orbit_frames": 36, "orbit_fps": 6, "mesh_resolution": 64}),
}
"""The named presets a job may start from; ``standard`` is the default."""

DEFAULT_PRESET = "standard"


def nest_dotted(overrides: dict[str, Any]) -> dict[str, Any]:
    """Turn dotted keys (``"phase2.steps": 10``) into nested dictionaries."""
    nested: dict[str, Any] = {}
    for key, value in overrides.items():
        if not isinstance(key, str):
            raise ValueError(f"override keys must be strings, got {key!r}")
        parts = key.split(".")
        node = nested
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ValueError(f"override {key!r} conflicts with a value for {part!r}")
            node = child
        if isinstance(value, dict) and isinstance(node.get(parts[-1]), dict):
            node[parts[-1]].update(value)
        else:
            node[parts[-1]] = value
    return nested


def _merge(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """Recursive dictionary merge; ``update`` wins."""
    out = dict(base)
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def resolve_config(preset: str | None = None, overrides: Any = None) -> PipelineConfig:
    """The preset's configuration with a client's overrides applied and validated.

    Args:
        preset: a key of ``PRESETS`` (``None``: the default preset).
        overrides: the client's settings (``cadnerf_core.config_client.CLIENT_SETTINGS``),
            nested (``{"phase2": {"steps": 10}}``) or dotted (``{"phase2.steps": 10}``), or a
            ``ClientSettings``; any other key and out-of-range values are rejected.
    Returns:
        The resolved, frozen configuration.
    Raises:
        ValueError: unknown preset or malformed overrides.
        pydantic.ValidationError: a setting a client may not send, or an invalid value (a
            ValueError subclass), located by its path.
    """
    from cadnerf_core.config_client import client_overrides  # it is built from this module

    if overrides is not None and not isinstance(overrides, dict) \
            and not hasattr(overrides, "model_dump"):
        raise ValueError("overrides must be a JSON object")
    return internal_config(preset, client_overrides(overrides or {}))


def internal_config(preset: str | None = None,
                    overrides: dict[str, Any] | None = None) -> PipelineConfig:
    """The preset's configuration with any of its fields overridden: for the pipeline's own
    callers (evaluation, benchmarks, tests), never for a client's values (``resolve_config``).

    Args:
        preset: a key of ``PRESETS`` (``None``: the default preset).
        overrides: nested or dotted values of any config field; unknown keys and out-of-range
            values are rejected.
    Returns:
        The resolved, frozen configuration.
    Raises:
        ValueError: unknown preset or malformed overrides (pydantic.ValidationError included).
    """
    name = DEFAULT_PRESET if preset is None else preset
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    if overrides is None:
        overrides = {}
    if not isinstance(overrides, dict):
        raise ValueError("overrides must be a JSON object")
    nested = nest_dotted(overrides)
    nested.pop("preset", None)
    data = _merge(PRESETS[name].model_dump(), nested)
    data["preset"] = name
    return PipelineConfig.model_validate(data)


def field_bounds(path: tuple[str | int, ...]) -> str | None:
    """The allowed range of the config field at ``path`` (``("phase3", "steps")``) as text,
    ``"0 <= phase3.steps <= 50000"``; None for a path that is not a bounded field."""
    model: Any = PipelineConfig
    info = None
    for part in path:
        info = getattr(model, "model_fields", {}).get(str(part))
        if info is None:
            return None
        model = info.annotation
    if info is None:
        return None
    limits = {name: getattr(item, name) for item in info.metadata
              for name in ("ge", "gt", "le", "lt") if getattr(item, name, None) is not None}
    if not limits:
        return None
    low = next((f"{limits[k]} {sign} " for k, sign in (("ge", "<="), ("gt", "<"))
                if k in limits), "")
    high = next((f" {sign} {limits[k]}" for k, sign in (("le", "<="), ("lt", "<"))
                 if k in limits), "")
    return f"{low}{'.'.join(str(p) for p in path)}{high}"

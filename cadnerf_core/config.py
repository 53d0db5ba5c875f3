"""Pipeline configuration: one frozen schema, named presets, and validation of user overrides.

Torch-free on purpose: the web service imports this module to validate a job's configuration
before it is queued. Every field documents what it does and, in the presets below, why each
value was chosen. Where the paper ("CAD-NeRF", Wen et al.) gives a value we use it in the
``paper`` preset and say so; everything else is ours, and says so.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class _Frozen(BaseModel):
    """Base: immutable, unknown keys rejected (a typo in an override must fail loudly)."""

    model_config = ConfigDict(frozen=True, extra="forbid")


class FieldConfig(_Frozen):
    """Network sizes."""

    hidden: int = Field(default=64, ge=8, le=1024)
    """Width of the density network D (its 4 ResNetBlockFC blocks) and of its feature vector."""
    n_blocks: int = Field(default=4, ge=1, le=16)
    """Number of ResNetBlockFC blocks in D (the paper: 4)."""
    pos_freqs: int = Field(default=6, ge=0, le=16)
    """Positional-encoding frequencies for 3D points (sin/cos of 2^k * pi * x, k < pos_freqs)."""
    dir_freqs: int = Field(default=0, ge=0, le=8)
    """Positional-encoding frequencies for view directions (colour network input; 0 = the raw
    unit direction only). Ours: 0. With 3 to 10 photos every surface point is seen from two or
    three directions, and higher direction frequencies let the colour network paint each
    photo's view on its own (view-dependent overfitting), which held-out views pay for.
    Measured with `benchmarks/bench_training.py` (preview, CesiumMilkTruck and Duck, 6 views):
    test PSNR with the true cameras (the benchmark's oracle) 19.26 / 21.21 dB at 3 against
    20.76 / 22.66 at 0; with the retrieved cameras (the method) 15.27 / 16.89 against
    16.28 / 18.01 (training PSNR falls from 22.0 / 23.4 to 20.9 / 22.5: less is memorised).
    NeRF's 4 stays in `paper`, which says nothing of its own."""
    deform_freqs: int | None = Field(default=None, ge=0, le=16)
    """Positional-encoding frequencies of the deformation network G's input (None: the same
    as ``pos_freqs``). Fewer bands make G a smooth warp of the CAD shape that cannot carve
    detail, which is D's job. Measured in session 8 with ``benchmarks.bench_training.run_one``
    (preview, CesiumMilkTruck / Duck, test PSNR): seed 0, 2 bands 20.07 / 20.21, 0 bands
    19.83 / 20.09, against 19.68 / 20.17 with None and 20.26 / 19.97 without G; seed 1, 2 bands
    19.43 / 19.22, None 19.33 / 19.64, without G 19.49 / 19.69. Two-seed means: 2 bands 19.73,
    None 19.71, without G 19.85: no gain, so None stays. 2 bands over a frozen D in phase two
    (the paper's phase two): 20.01 / 18.81 (seed 0)."""
    deform_hidden: int = Field(default=64, ge=8, le=1024)
    """Width of the deformation network G."""
    deform_layers: int = Field(default=3, ge=1, le=12)
    """Hidden layers of G."""
    color_hidden: int = Field(default=64, ge=8, le=1024)
    """Width of the colour network."""
    color_layers: int = Field(default=4, ge=1, le=12)
    """Layers of the colour network (the paper: 4)."""


class RenderConfig(_Frozen):
    """Ray sampling and empty-space skipping."""

    samples_per_ray: int = Field(default=48, ge=4, le=1024)
    """Samples along each ray between its entry and exit of the bounding sphere."""
    bound: float = Field(default=1.1, gt=0.5, le=4.0)
    """Radius of the sphere rays are sampled in; the object is normalised into the unit sphere,
    the margin leaves room for the deformation to grow it."""
    grid_resolution: int = Field(default=32, ge=4, le=256)
    """Cells per side of the empty-space-skipping grid over [-bound, bound]^3."""
    grid_dilation: int = Field(default=2, ge=0, le=16)
    """Cells added around occupied cells, so the deformation can grow the shape into them."""
    grid_threshold: float = Field(default=0.01, ge=0.0, lt=1.0)
    """Occupancy above which a grid cell counts as occupied when updated from the learned field."""
    grid_update_every: int = Field(default=100, ge=1)
    """Training steps between two updates of the grid from the learned density."""
    use_grid: bool = True
    """Skip samples in empty grid cells (off: every sample is evaluated)."""
    chunk_rays: int = Field(default=4096, ge=64)
    """Rays per chunk when rendering images (memory bound, not a quality setting)."""
    train_pass_rays: int = Field(default=0, ge=0)
    """Rays per forward and backward pass of a training step: a step's rays are split into
    passes of at most this many whose gradients add up before the one optimiser step (the same
    loss, less memory). 0: one pass on a GPU, 2048 on the CPU, where a pass of 8192 rays takes
    1.4-1.7 times as long per ray as one of 2048 (2 cores, `standard`'s networks, session 14)."""


class Phase1Config(_Frozen):
    """Phase one: D pretrained to the retrieved CAD model's occupancy (binary cross entropy)."""

    steps: int = Field(default=400, ge=0)
    """Optimisation steps."""
    batch_points: int = Field(default=4096, ge=16)
    """Points per step, sampled from the library occupancy grid."""
    near_surface: float = Field(default=0.5, ge=0.0, le=1.0)
    """Fraction of points drawn near the surface (the rest uniformly in the cube)."""
    lr: float = Field(default=1e-3, gt=0.0)
    """Adam learning rate."""


class Phase2Config(_Frozen):
    """Phase two: deformation G and camera poses from silhouettes (accumulated opacity vs mask)."""

    steps: int = Field(default=600, ge=0)
    """Optimisation steps."""
    rays: int = Field(default=1024, ge=16)
    """Rays per step, drawn from all training photos."""
    lr: float = Field(default=5e-4, gt=0.0)
    """Adam learning rate of G (of D when the deformation is off)."""
    pose_lr: float = Field(default=2e-3, gt=0.0)
    """Adam learning rate of the SE(3) pose corrections."""
    pose_window: tuple[float, float] = (0.5, 1.0)
    """Fractions of phase two's steps between which poses are optimised; frozen outside. Late,
    as in the paper (7.5k to 10k of 10k), once G has bent the CAD prior toward the masks:
    measured with `benchmarks/bench_training.py` (preview, CesiumMilkTruck and Duck), a window
    of (0, 0.75) moved the poses away from the truth (rotation error 14.4 -> 20.1 and
    17.4 -> 22.1 degrees), the shape being still the CAD model's; (0.5, 1) brought them closer
    (12.9 and 13.9), and (0.75, 1) less so (13.5 and 16.6)."""
    anneal: tuple[float, float] = (0.0, 0.5)
    """Fractions of phase two over which positional-encoding frequencies are switched on
    coarse-to-fine (BARF); all are on after the second value."""
    train_density: bool = True
    """Train D together with G (ours) rather than deform a frozen D (the paper). With D frozen,
    G has to explain every difference between the CAD model and the photos, pose errors
    included; with D trainable the offsets stay small and the poses move further toward the
    truth. Measured with `benchmarks/bench_training.py` (preview, CesiumMilkTruck and Duck,
    raw view directions): test PSNR 16.28 / 18.01 dB frozen against 16.46 / 18.42 trained,
    rotation error after refinement 12.5 / 16.9 against 11.1 / 13.5 degrees. Again in session 7
    with the current preview (seed 0): 19.22 / 19.03 frozen against 19.68 / 20.17 trained, and
    5.0 / 5.5 against 3.0 / 3.2 degrees (G carries more of the shape then, but the result is
    worse than without G at all: 20.26 / 19.97). Without G, off holds the shape: phase two
    leaves D the CAD model's and only refines the poses against it (its steps outside the pose
    window are skipped), the benchmarks' "no deformation" run."""
    lambda_offset: float = Field(default=0.1, ge=0.0)
    """Weight of the mean offset norm ||o||_2 in phase two (ours: the paper gives weights for
    phase three only; 10 on a mean pins G at zero and the shape cannot move)."""
    lambda_correction: float = Field(default=0.01, ge=0.0)
    """Weight of the mean |c| (logit units) in phase two (ours, as above)."""
    prior_weight: float = Field(default=0.0, ge=0.0)
    """Weight of the CAD prior on D while G deforms it: binary cross entropy of D, at points of
    its own (undeformed) frame, against the retrieved model's occupancy, as in phase one. D
    then stays the CAD template and the photos are explained by G's warp and correction (0 =
    off; ignored without G or without CAD initialisation, where there is no template).
    Measured in session 9 with ``benchmarks.bench_training`` (preview, seed 0, the same
    weight in phases two and three; test PSNR, rotation error after refinement): 1.0 gives
    16.05 dB / 13.4 deg on CesiumMilkTruck and 17.92 / 14.0 on Duck, 0.1 gives 16.85 / 9.0
    on the truck, against 20.17 / 3.0 and 20.04 / 4.0 off: a retrieved model is another
    object, and a D held to it leaves G to bend one shape into another, which it cannot, so
    the poses stay where retrieval put them. Off, as the paper's phase three has D free."""
    prior_points: int = Field(default=1024, ge=16)
    """CAD occupancy points per step for ``prior_weight``."""

    @model_validator(mode="after")
    def _check_windows(self) -> Phase2Config:
        for name in ("pose_window", "anneal"):
            start, end = getattr(self, name)
            if not 0.0 <= start <= end <= 1.0:
                raise ValueError(f"{name} must satisfy 0 <= start <= end <= 1, got {start, end}")
        return self


class Phase3Config(_Frozen):
    """Phase three: colour network; D, G and colour trained on colour re-rendering."""

    steps: int = Field(default=1000, ge=0)
    """Optimisation steps."""
    rays: int = Field(default=1024, ge=16)
    """Rays per step."""
    lr: float = Field(default=5e-4, gt=0.0)
    """Adam learning rate (the paper: 5e-4)."""
    lambda_offset: float = Field(default=0.1, ge=0.0)
    """Weight of the mean offset norm ||o||_2 over evaluated samples (the paper's lambda_a,
    10 there, applied to a sum of unstated normalisation: `paper` keeps 10 on the mean; ours is
    0.1, which lets phase two's deformation survive phase three)."""
    lambda_correction: float = Field(default=0.01, ge=0.0)
    """Weight of the mean |c| (the paper's lambda_b: 0.1 in `paper`, 0.01 in ours)."""
    mask_weight: float = Field(default=0.1, ge=0.0)
    """Weight of the silhouette loss kept during phase three (ours; the paper uses none)."""
    prior_weight: float = Field(default=0.0, ge=0.0)
    """Weight of the CAD prior on D in phase three (as ``Phase2Config.prior_weight``)."""
    prior_points: int = Field(default=1024, ge=16)
    """CAD occupancy points per step for ``prior_weight``."""
    pose_window: tuple[float, float] = (0.0, 0.75)
    """Fractions of phase three's steps in which poses keep being refined, now by the colour
    loss ((0, 0) = frozen, the paper). Ours: the first three quarters, with ``pose_blur``.
    Without the blur, the first half (test-view PSNR 15.80 and 16.93 dB against 15.33 and
    16.78 frozen; preview, CesiumMilkTruck and Duck, an older schedule). With the blur, a
    longer window keeps helping (session 6, same meshes, seed 0, mean test PSNR): (0, 0.5)
    17.99 dB, (0, 0.75) 18.32, (0, 0.9) 18.45; (0, 0.75) also 18.63 with seed 1. The last
    quarter fits the sharp photos with the poses settled."""
    pose_lr: float = Field(default=2e-3, gt=0.0)
    """Adam learning rate of the pose corrections inside phase three's window. Measured in
    session 7 with ``benchmarks.bench_training.run_one`` (preview at 1000 phase-three steps,
    CesiumMilkTruck and Duck, mean test PSNR over both meshes and seeds 0 and 1; median
    rotation error after refinement truck / Duck, seed 0): 5e-4 18.48 dB (8.5 / 12.3 deg),
    1e-3 18.96 (6.3 / 10.6), 2e-3 19.44 (3.8 / 7.5); 4e-3 with seed 0 only 19.45 (3.3 / 5.4)
    against 19.58 for 2e-3 (4e-3 gains on rotation, not on PSNR). At 2000 steps (the
    preview preset now) 2e-3 gives 19.93 dB, seed 0 (3.0 / 3.2 deg)."""
    pose_blur: float = Field(default=0.0625, ge=0.0, le=0.5)
    """Coarse-to-fine photometric alignment: inside the pose window the colour targets are the
    photos blurred by a Gaussian of this standard deviation (a fraction of the image side:
    8 px at 128), halved at each third of the window, sharp after it (0 = never blurred).
    A blurred target widens the colour loss's basin in pose, as the image pyramids of direct
    alignment do, so poses travel further before fine texture pins them where they are; the
    networks then fit the sharp photos. Measured in session 6 with
    ``benchmarks.bench_training.run_one`` (preview, CesiumMilkTruck and Duck, window (0, 0.5),
    mean test PSNR over both meshes): seed 0: none 17.37 dB, 4 px 17.83, 8 px 17.99, 16 px
    17.88; seed 1: none 17.93, 4 px 18.24, 8 px 18.18; rotation error after refinement lower
    on every mesh and seed (truck 11.1 -> 9.5, Duck 13.4 -> 12.5 at 8 px, seed 0). Blurring
    phase two's masks as well (2 px) added nothing (18.29 against 18.32)."""
    scene_steps: int = Field(default=0, ge=0)
    """Scene mode only: steps after the object's, training object and background together on
    the photos with their own background (ignored without scene mode)."""

    @model_validator(mode="after")
    def _check_window(self) -> Phase3Config:
        start, end = self.pose_window
        if not 0.0 <= start <= end <= 1.0:
            raise ValueError(f"pose_window must satisfy 0 <= start <= end <= 1, got {start, end}")
        return self


class ExportConfig(_Frozen):
    """What the job writes."""

    orbit_frames: int = Field(default=60, ge=2, le=720)
    """Frames in orbit.mp4 and orbit.gif."""
    orbit_fps: int = Field(default=30, ge=1, le=120)
    """Frames per second of the video."""
    orbit_elevation: float = Field(default=20.0, ge=-89.0, le=89.0)
    """Elevation of the orbit camera in degrees."""
    orbit_size: int = Field(default=256, ge=16, le=2048)
    """Side of orbit frames in pixels (even, for H.264 yuv420p)."""
    novel_views: int = Field(default=4, ge=0, le=64)
    """Extra views rendered at new poses into views/, after the ones at the photo poses."""
    mesh_resolution: int = Field(default=96, ge=16, le=512)
    """Marching-cubes grid side for mesh.glb."""
    mesh_level: float = Field(default=0.5, gt=0.0, lt=1.0)
    """Occupancy level of the extracted surface."""

    @model_validator(mode="after")
    def _even(self) -> ExportConfig:
        if self.orbit_size % 2:
            raise ValueError("orbit_size must be even (H.264 yuv420p)")
        return self


AMBIGUOUS_HINT = ("the walking direction is a guess: these photos look alike walked either way "
                  "round, so counter-clockwise was assumed (the object on your left as you "
                  "walked); if you walked with it on your right, the poses are those of the "
                  "mirrored walk: give the direction (walk: cw)")
"""What a user is told when ``RetrievalResult.direction_ambiguous``."""


class RetrievalOptions(_Frozen):
    """Options handed to retrieval (its own module owns the search itself)."""

    solver: Literal["dp", "paper"] = "dp"
    """Pose solver: exact cyclic dynamic programme (ours, default) or the paper's Algorithm 1."""
    top_k: int = Field(default=10, ge=1, le=100)
    """Candidate library views per photo (the paper: 10)."""
    max_discard: int = Field(default=2, ge=0, le=5)
    """Photos that may be discarded as inconsistent (the paper: 1-2)."""
    walk: Literal["auto", "ccw", "cw"] = "auto"
    """Which way round the photos were taken: "ccw" (counter-clockwise seen from above, the
    object on your left as you walk), "cw", or "auto" (found from the photos). Give it for
    objects that look alike from mirrored sides (mugs, bottles, lamps): there the silhouettes
    cannot tell: the job then assumes "ccw" and warns that the direction is a guess."""
    shared_focal: bool = True
    """The photos were taken with one camera at one zoom: they share a focal length (their
    EXIF one where they carry it), and each photo's retrieved scale becomes its distance (off:
    each photo keeps the focal length of its own library match; for photos taken at different
    zooms)."""
    focal_35mm: float | None = Field(default=None, ge=8.0, le=1200.0)
    """The camera's focal length in 35 mm film terms, for photos whose EXIF does not say (a
    phone's main lens is about 24-28 mm; messaging apps strip EXIF). A photo's own EXIF value
    wins. Known, it sets the shared focal length and lets ``perspective`` choose."""
    perspective: Literal["auto", "far", "near"] = "auto"
    """Library silhouettes to match: "near" (seen from about half as far, as a phone's wide
    lens frames an object), "far" (a 40-degree camera), or "auto": the set whose perspective
    fits the photos, which needs their focal length (EXIF); without it "far"."""


class PipelineConfig(_Frozen):
    """Everything that decides a job's result. Runtime objects (device, library) are not here."""

    preset: str = "standard"
    """Name of the preset these values started from (informational)."""
    seed: int = Field(default=0, ge=0)
    """Random seed: two runs with the same seed on the CPU give the same result."""
    image_size: int = Field(default=128, ge=16, le=1024)
    """Side of the canonical photo crops the NeRF is trained on."""
    use_cad_init: bool = True
    """Phase one on: D starts as the retrieved CAD model's occupancy (off: from scratch)."""
    optimise_poses: bool = True
    """Refine the retrieved camera poses in phase two (off: keep them)."""
    use_deformation: bool = True
    """Train deformation G over a frozen-in-phase-two D (off: train D directly)."""
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
    retrieval: RetrievalOptions = Field(default_factory=RetrievalOptions)
    """Retrieval options."""
    export: ExportConfig = Field(default_factory=ExportConfig)
    """Outputs."""


def _preset(name: str, **sections: Any) -> PipelineConfig:
    return PipelineConfig.model_validate({"preset": name, **sections})


PRESETS: dict[str, PipelineConfig] = {
    # Paper-faithful where the paper speaks: 4 ResNetBlockFC blocks, colour net of 4 layers,
    # lambda_a = 10, lambda_b = 0.1, Adam 5e-4, poses refined only between iterations 7.5k and
    # 10k (here: the last quarter of a 10k-step phase two), no silhouette loss in phase three.
    # Ours (the paper is silent): widths 256/128, 10 position frequencies, 128 samples, 256 px,
    # 2k/10k/20k steps. Hours on a CPU; for side-by-side comparison on a GPU.
    "paper": _preset(
        "paper", image_size=256,
        field={"hidden": 256, "pos_freqs": 10, "dir_freqs": 4, "deform_hidden": 128,
               "deform_layers": 4, "color_hidden": 128},
        render={"samples_per_ray": 128, "grid_resolution": 64, "grid_dilation": 3},
        phase1={"steps": 2000, "batch_points": 16384, "lr": 5e-4},
        phase2={"steps": 10000, "rays": 2048, "pose_window": (0.75, 1.0), "anneal": (0.0, 0.5),
                "train_density": False},
        phase3={"steps": 20000, "rays": 2048, "mask_weight": 0.0, "scene_steps": 5000,
                "lambda_offset": 10.0, "lambda_correction": 0.1, "pose_window": (0.0, 0.0),
                "pose_blur": 0.0},
        export={"orbit_size": 256, "mesh_resolution": 160}),
    # Default: best quality in about a minute on a GPU at 256 px. Narrower nets than `paper`
    # (128 wide: the benchmark shows small objects do not need more), 64 samples with grid
    # skipping; poses refined in the second half of phase two and the first three quarters of
    # phase three (against blurred photos first), D trained beside G in phase two, raw view
    # directions only (the schema's defaults, measured on `preview`). Few large steps: on an
    # H100 a step of these small networks costs ~20-25 ms whatever its batch (kernel launches,
    # not arithmetic), so 8192 rays a step over a quarter of the steps sees the same samples
    # in a third of the time. `docs/bench_training_gpu.md` (session 14, H100, truck and Duck at
    # 256 px, seed 0): 2048 rays x 800/2000/4000 steps gave 22.29 dB mean test PSNR (21.32 /
    # 23.25) in 180 s a job; these values 22.36 dB (21.79 / 22.94) in 69 s. One seed on two
    # meshes: the two are level within a seed's spread, not shown better. On a CPU, `preview`.
    "standard": _preset(
        "standard", image_size=256,
        field={"hidden": 128, "pos_freqs": 8, "deform_hidden": 64, "color_hidden": 96},
        render={"samples_per_ray": 64, "grid_resolution": 48, "grid_update_every": 25},
        phase1={"steps": 200, "batch_points": 32768},
        phase2={"steps": 500, "rays": 8192},
        phase3={"steps": 1000, "rays": 8192, "scene_steps": 250},
        export={"orbit_size": 256, "mesh_resolution": 128}),
    # A useful result in minutes on 2 CPU cores, on 128 px crops: widths 64, 6 frequencies, 32
    # samples per ray (grid skipping leaves ~5-7 evaluated per ray), step counts sized so the
    # three phases take a few minutes (phase three ~0.05-0.13 s a step on 2 cores). Phase three
    # 2000 steps: against 1000 (both with pose_lr 2e-3, seed 0, CesiumMilkTruck / Duck) test
    # PSNR 19.35 / 19.80 -> 19.68 / 20.17 dB, rotation error 3.8 / 7.5 -> 3.0 / 3.2 deg; with
    # the true cameras 21.06 / 23.08 -> 21.74 / 23.78. No deformation network G: D is fitted to the
    # silhouettes in its place (the benchmarks' "no G" run). At this scale G is measured to add a
    # fifth to a third of the job time and no quality beyond noise; holding the shape in phase two
    # instead (the paper's pipeline without deformation, the benchmarks' "no deformation" run) is
    # clearly worse. `docs/bench_training_preview.md`, CesiumMilkTruck / Duck, mean test PSNR:
    # session 13 (Xeon, seeds 0 and 1) full (with G) 22.46 dB, no G 22.40, no deformation 21.36;
    # sessions 11-12 (AMD EPYC, two seeds) no G 22.68, full 22.48, no deformation about
    # 22.0, jobs 175 / 239 s. G's gain or loss is within a seed's spread either way. Earlier
    # (session 9, before the frame fit) on the drill and the cow: 14.18 / 16.85 without G against
    # 13.95 / 16.87, 191 s against 284 s (`docs/bench_training_focal.md`). `standard` and `paper`
    # keep G: nothing here measured them.
    "preview": _preset(
        "preview", image_size=128, use_deformation=False,
        field={"hidden": 64, "pos_freqs": 6, "deform_hidden": 48, "color_hidden": 64},
        render={"samples_per_ray": 32, "grid_resolution": 32},
        phase1={"steps": 200, "batch_points": 4096},
        phase2={"steps": 400, "rays": 1024},
        phase3={"steps": 2000, "rays": 1024, "scene_steps": 300},
        export={"orbit_size": 128, "mesh_resolution": 64}),
    # The test suite's preset: a whole job in seconds; the numbers only need to exercise code.
    "test": _preset(
        "test", image_size=32,
        field={"hidden": 16, "pos_freqs": 3, "dir_freqs": 2, "deform_hidden": 16,
               "deform_layers": 1, "color_hidden": 16, "color_layers": 2},
        render={"samples_per_ray": 12, "grid_resolution": 8, "grid_update_every": 3,
                "chunk_rays": 512},
        phase1={"steps": 4, "batch_points": 256},
        phase2={"steps": 6, "rays": 64},
        phase3={"steps": 6, "rays": 64, "scene_steps": 3},
        export={"orbit_frames": 4, "orbit_size": 32, "novel_views": 1, "mesh_resolution": 16}),
}
"""The named presets; `standard` is the default."""

DEFAULT_PRESET = "standard"


def _nest(overrides: dict[str, Any]) -> dict[str, Any]:
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


def resolve_config(preset: str | None = None,
                   overrides: dict[str, Any] | None = None) -> PipelineConfig:
    """The preset's configuration with user overrides applied and validated.

    Args:
        preset: a key of ``PRESETS`` (``None``: the default preset).
        overrides: nested (``{"phase2": {"steps": 10}}``) or dotted (``{"phase2.steps": 10}``)
            values; unknown keys and out-of-range values are rejected.
    Returns:
        The resolved, frozen configuration.
    Raises:
        ValueError: unknown preset or malformed overrides.
        pydantic.ValidationError: unknown keys or invalid values (a ValueError subclass).
    """
    name = DEFAULT_PRESET if preset is None else preset
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    if overrides is None:
        overrides = {}
    if not isinstance(overrides, dict):
        raise ValueError("overrides must be a JSON object")
    nested = _nest(overrides)
    nested.pop("preset", None)
    data = _merge(PRESETS[name].model_dump(), nested)
    data["preset"] = name
    return PipelineConfig.model_validate(data)

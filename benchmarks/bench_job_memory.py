"""Peak memory of a worker running one job of large photos (ten 40 MP JPEGs at ``preview``).

A real API (uvicorn) and ``cadnerf worker`` process on 127.0.0.1 (Redis as in
``bench_reliability``: database 13 of the local server, else an embedded one), the built library
(``library_data/build``, else a small one). The photos are a chair rendered from ten azimuths,
put on a light grey background with a little noise and scaled up to the size asked for, saved
as JPEG (quality 90): no alpha, so background removal runs as for phone photos. The figure is
the worker process's peak resident memory (``VmHWM`` in ``/proc/<pid>/status``), read after the
job, minus nothing: start-up and the loaded library included.

Run: ``.venv/bin/python -m benchmarks.bench_job_memory [--megapixels 40] [--quick]``;
``--quick`` keeps the preset's sizes but runs a tenth of its steps and frames (the peak comes
from intake and from one training step, not from their number). ``--largest-pass WIDTH``
measures instead one training step at the configuration's bound on points x network width.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from benchmarks.bench_reliability import _library, _redis_url
from tests.reliability import jobs
from tests.reliability.support import start_live, stop_live

COMMAND = ".venv/bin/python -m benchmarks.bench_job_memory"
QUICK = {"phase1.steps": 20, "phase2.steps": 40, "phase3.steps": 200, "phase3.scene_steps": 0,
         "export.orbit_frames": 6}


def make_photos(folder: Path, n: int, megapixels: float) -> list[Path]:
    """``n`` JPEG photos of a chair walked around, ``megapixels`` each (4:3)."""
    from cadnerf_cli.demo_photos import demo_mesh
    from cadnerf_core.evaluation.dataset import render_dataset

    dataset = render_dataset(demo_mesh(folder / "chair.ply"), folder / "dataset", n_views=n,
                             size=384, seed=0)
    height = int(math.sqrt(megapixels * 1e6 * 3 / 4))
    width = height * 4 // 3
    rng = np.random.default_rng(0)
    out = []
    for i, path in enumerate(sorted((dataset / "images").glob("*.png"))):
        with Image.open(path) as rgba:
            square = rgba.convert("RGBA")
        canvas = Image.new("RGBA", (square.width * 4 // 3, square.height), (225, 225, 220, 255))
        canvas.alpha_composite(square, ((canvas.width - square.width) // 2, 0))
        noise = rng.normal(0, 3, (canvas.height, canvas.width, 1))
        small = np.clip(np.asarray(canvas.convert("RGB"), np.float32) + noise, 0, 255)
        big = Image.fromarray(small.astype(np.uint8)).resize((width, height),
                                                             Image.Resampling.BICUBIC)
        out.append(folder / f"photo_{i:02d}.jpg")
        big.save(out[-1], format="JPEG", quality=90)
    return out


def peak_rss_mib(pid: int) -> float:
    """A process's peak resident memory (VmHWM) in MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc status")


def measure(megapixels: float, n: int, quick: bool) -> dict[str, Any]:
    """Start the service, run one job of ``n`` photos, return the worker's peak memory."""
    with tempfile.TemporaryDirectory(prefix="bench-memory-") as tmp:
        folder = Path(tmp)
        photos = make_photos(folder, n, megapixels)
        sizes = [Image.open(p).size for p in photos]
        url, server = _redis_url(folder)
        live = start_live(folder, url, _library(folder), max_file_mb="25",
                          max_total_mb="250")
        try:
            assert live.worker is not None
            idle = peak_rss_mib(live.worker.pid)
            config = {"preset": "preview", "overrides": QUICK if quick else {}}
            started = time.monotonic()
            job = jobs.submit(live.url, photos, config)
            final, _ = jobs.wait_state(live.url, job["id"], 3600, every_s=1.0)
            seconds = time.monotonic() - started
            peak = peak_rss_mib(live.worker.pid)
        finally:
            stop_live(live)
            if server is not None:
                server.stop()
    return {"photos": n, "megapixels": round(sizes[0][0] * sizes[0][1] / 1e6, 1),
            "size": f"{sizes[0][0]}x{sizes[0][1]}", "preset": "preview",
            "quick": quick, "state": final["state"], "error": final.get("error"),
            "worker_idle_peak_mib": round(idle), "worker_peak_mib": round(peak),
            "job_s": round(seconds, 1)}


LARGEST_PASS = """
import sys, numpy as np, torch
from cadnerf_core.cameras.conventions import intrinsics_from_fov, orbit_pose
from cadnerf_core.config import internal_config
from cadnerf_core.config_bounds import MAX_POINT_WIDTH
from cadnerf_core.nerf import phases
from cadnerf_core.nerf.device import adam
from cadnerf_core.nerf.state import TrainData, TrainState
def hwm():
    status = open('/proc/self/status').read()
    return int(status.split('VmHWM:')[1].split()[0]) / 1024
phase, width = sys.argv[1], int(sys.argv[2])
c2w = np.stack([orbit_pose(a, 20.0, 4.0) for a in (0.0, 120.0, 240.0)])
if phase == 'phase1':
    points = MAX_POINT_WIDTH // width
    config = internal_config('preview', {'field.hidden': width, 'phase1.batch_points': points})
else:
    rays = MAX_POINT_WIDTH // width // 64
    points = rays * 64
    config = internal_config('preview', {
        'use_deformation': True, 'field.hidden': width, 'field.deform_hidden': width,
        'field.color_hidden': width, 'render.samples_per_ray': 64, 'render.use_grid': False,
        'render.train_pass_rays': rays, 'phase3.rays': rays, 'phase3.steps': 1,
        'phase3.scene_steps': 0})
state = TrainState.create(config, c2w, torch.device('cpu'), None)
before = hwm()
if phase == 'phase1':
    optimizer = adam(state.fields.density.parameters(), 1e-3, state.device)
    phases.phase1_step(state, optimizer, torch.rand(points, 3) * 2 - 1, torch.zeros(points))
else:
    K = np.repeat(intrinsics_from_fov(40.0, 64)[None], 3, 0)
    masks = np.zeros((3, 64, 64), bool)
    masks[:, 16:48, 16:48] = True
    data = TrainData.from_numpy(np.random.rand(3, 64, 64, 3), masks, K, state.device)
    phases.run_phase3(state, data)
print(points, before, hwm())
"""


def largest_pass(phase: str, width: int) -> dict[str, Any]:
    """Peak memory of one training step of ``phase`` ("phase1": occupancy points; "phase3":
    rays x 64 samples through D, G and the colour net, every sample evaluated) at the bound
    points x ``width`` = MAX_POINT_WIDTH, in a fresh process: what one pass at the bound adds."""
    import subprocess
    import sys

    from tests.reliability.support import ROOT

    done = subprocess.run([sys.executable, "-c", LARGEST_PASS, phase, str(width)], cwd=ROOT,
                          capture_output=True, text=True, check=True,
                          env={"PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "2",
                               "PATH": "/usr/bin:/bin"})
    points, before, after = done.stdout.split()[-3:]
    return {"phase": phase, "width": width, "points": int(points),
            "process_before_mib": round(float(before)), "step_peak_mib": round(float(after)),
            "added_mib": round(float(after) - float(before))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--megapixels", type=float, default=40.0)
    parser.add_argument("--photos", type=int, default=10)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--largest-pass", type=int, metavar="WIDTH", default=0,
                        help="only the peak of one training step of phases one and three at "
                             "the points x width bound, networks WIDTH wide")
    args = parser.parse_args()
    if args.largest_pass:
        for phase in ("phase1", "phase3"):
            print(json.dumps(largest_pass(phase, args.largest_pass)))
        print(f"command: {COMMAND} --largest-pass {args.largest_pass}")
        return
    result = measure(args.megapixels, args.photos, args.quick)
    print(json.dumps(result))
    print(_row(result))
    print(f"command: {COMMAND} --megapixels {args.megapixels:g} --photos {args.photos}"
          f"{' --quick' if args.quick else ''}")


def _row(result: dict[str, Any]) -> str:
    return (f"| {result['photos']} photos of {result['size']} ({result['megapixels']} MP), "
            f"{result['preset']}{' (quick)' if result['quick'] else ''} | {result['state']} in "
            f"{result['job_s']} s | {result['worker_peak_mib']} MiB "
            f"(idle {result['worker_idle_peak_mib']} MiB) |")


def run(quick: bool) -> str:
    """``make bench``'s section: ten 40-megapixel photos through a live service at preview
    (``quick``: the cut-down schedule, which keeps the photo work and drops training steps)."""
    result = measure(40.0, 10, quick)
    return "\n".join([
        "## Job memory", "",
        f"Command: `python -m benchmarks.bench_job_memory --megapixels 40 --photos 10"
        f"{' --quick' if quick else ''}` (a live service and worker; the worker's peak "
        "resident memory, VmHWM). Goal: under 2 GB.", "",
        "| job | result | worker peak |", "| --- | --- | ---: |", _row(result), ""])


if __name__ == "__main__":
    main()

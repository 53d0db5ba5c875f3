"""A whole job on real phone photos: the espresso set of ``../shared/eval/photos``.

The photos (7, a Pixel phone's, 27 mm EXIF) are taken in the order of their metadata azimuths,
with their shipped masks, and run through the pipeline as ``cadnerf reconstruct`` runs them.
The picture ``docs/espresso_reconstruction.png`` shows, a column per photo: the photo's
canonical crop, the NeRF rendered at that photo's refined pose, and an orbit frame (the
orbit's seven evenly spaced frames, so the last row is views no photo saw from those angles).

Usage: ``python -m benchmarks.real_reconstruction [--preset preview] [--out DIR]``; prints
the model, the silhouette set, the training PSNR and the job's time.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.harness import DOCS, LIBRARY_DIR, PHOTOS, ROOT, run_job
from benchmarks.retrieval_real import real_set_photos

PICTURE = DOCS / "espresso_reconstruction.png"
SET = "ners_espresso"
TILE = 128


def picture(job: Path, photos: list[Path], masks: list[Path], out: Path) -> None:
    """Three rows of tiles: canonical crops, renders at the photos' poses, orbit frames."""
    import imageio_ffmpeg
    from PIL import Image

    from cadnerf_core.intake.photos import canonical_views, load_photos
    from cadnerf_core.jobfolder import ORBIT_VIDEO, VIEWS, JobFolder

    loaded = load_photos(photos, masks)
    found = [p.mask for p in loaded if p.mask is not None]  # every photo has its shipped mask
    rgb, crops, _ = canonical_views(loaded, found, TILE, 0.1)
    row1 = [(np.where(c[..., None], im, 1.0) * 255).astype(np.uint8)
            for im, c in zip(rgb, crops, strict=True)]
    folder = JobFolder(job)
    views = sorted(folder.file(VIEWS).glob("*.png"))[:len(photos)]
    row2 = [np.asarray(Image.open(v).convert("RGB").resize((TILE, TILE))) for v in views]
    reader = imageio_ffmpeg.read_frames(str(folder.file(ORBIT_VIDEO)))
    meta = next(reader)
    frames = list(reader)
    width, height = meta["size"]
    row3 = [np.asarray(Image.fromarray(np.frombuffer(
        frames[i * len(frames) // len(photos)], np.uint8).reshape(height, width, 3)).resize(
        (TILE, TILE))) for i in range(len(photos))]
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate([np.concatenate(r, 1) for r in (row1, row2, row3)], 0)).save(
        out)


def run(preset: str, job: Path) -> str:
    """Run the job into ``job`` (an empty or absent folder) and write the picture."""
    from cadnerf_core.config import resolve_config
    from cadnerf_core.library.format import load_library

    photos, masks, _ = real_set_photos(SET)
    run = run_job(job, load_library(LIBRARY_DIR), photos=photos, masks=masks,
                  config=resolve_config(preset))
    picture(job, photos, masks, PICTURE)
    retrieval, metrics, seconds = run.retrieval, run.metrics, run.seconds
    return (f"{SET}, preset {preset}: model {retrieval['model_id']} ({retrieval['category']}), "
            f"silhouette set {retrieval['perspective']}, {len(photos)} photos, "
            f"{len(retrieval['discarded'])} discarded; training PSNR {metrics['mean_psnr']:.2f} "
            f"dB; job {seconds:.0f} s on the CPU; picture {PICTURE.relative_to(ROOT)}\n")


def main(argv: list[str] | None = None) -> int:
    """Run the job and print its summary line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="preview")
    parser.add_argument("--out", type=Path, default=None, help="job folder (default: temporary)")
    args = parser.parse_args(argv)
    if not (PHOTOS / SET).is_dir():
        sys.stdout.write("Not run: ../shared/eval is absent.\n")
        return 0
    job = args.out or Path(tempfile.mkdtemp(prefix="cadnerf-real-"))
    sys.stdout.write(run(args.preset, job))
    return 0


if __name__ == "__main__":
    sys.exit(main())

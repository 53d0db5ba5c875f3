"""Synthetic and real datasets with true cameras, image and pose metrics, the evaluation protocol.

The names below are the package's public face; each loads its module on first use, so
importing the package costs nothing (torch loads only with what needs it).
"""

from typing import TYPE_CHECKING

from cadnerf_core.facade import lazy_exports

EXPORTS = {
    "dataset": ("Dataset", "load_dataset", "render_dataset"),
    "evaluate": ("EvalReport", "evaluate_dataset"),
    "metrics": ("psnr", "ssim"),
    "jobio": ("read_job_cameras",),
    "frame": ("fit_frame",),
}
"""Module -> the public names it holds."""
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
__all__ = ["Dataset", "EvalReport", "evaluate_dataset", "fit_frame", "load_dataset", "psnr",
    "read_job_cameras", "render_dataset", "ssim"]

if TYPE_CHECKING:
    from cadnerf_core.evaluation.dataset import Dataset, load_dataset, render_dataset
    from cadnerf_core.evaluation.evaluate import EvalReport, evaluate_dataset
    from cadnerf_core.evaluation.frame import fit_frame
    from cadnerf_core.evaluation.jobio import read_job_cameras
    from cadnerf_core.evaluation.metrics import psnr, ssim

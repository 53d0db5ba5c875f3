"""Stage 4: retrieval of a similar CAD model and every photo's library pose from its silhouette.

The names below are the package's public face; each loads its module on first use, so
importing the package costs nothing (torch loads only with what needs it).
"""

from typing import TYPE_CHECKING

from cadnerf_core.facade import lazy_exports

EXPORTS = {
    "search": ("retrieve",),
    "result": ("PhotoMatch", "RetrievalResult"),
    "scoring": ("iou_table", "vote_models"),
    "posesearch": ("cyclic_dp", "paper_algorithm1"),
    "ordering": ("choose_order",),
}
"""Module -> the public names it holds."""
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
__all__ = ["PhotoMatch", "RetrievalResult", "choose_order", "cyclic_dp", "iou_table",
    "paper_algorithm1", "retrieve", "vote_models"]

if TYPE_CHECKING:
    from cadnerf_core.retrieval.ordering import choose_order
    from cadnerf_core.retrieval.posesearch import cyclic_dp, paper_algorithm1
    from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult
    from cadnerf_core.retrieval.scoring import iou_table, vote_models
    from cadnerf_core.retrieval.search import retrieve

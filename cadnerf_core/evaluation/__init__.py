"""Evaluation: synthetic datasets with true cameras (``dataset``), image and pose metrics
(``metrics``), the evaluation job's folder (``jobio``), the mapping of true cameras into the
NeRF's frame (``frame``) and the protocol itself (``evaluate``)."""

"""CAD-NeRF: the method. Imports nothing of the service (no HTTP, Celery, Redis, env).

One subpackage per stage of the method, in the order a job runs them:

- ``intake``: photos (EXIF, HEIC, orientation), background removal, the canonical crop;
- ``library``: the mini CAD library (format, occupancy grids);
- ``retrieval``: silhouette IoU against the library, voting, multi-view pose search;
- ``cameras``: every photo's camera from the photos' matches (mapper, fusion, placement into
  the CAD frame) and the start's choice; also the camera conventions every stage shares;
- ``nerf``: the fields and the three training phases;
- ``export``: poses, views, orbit, mesh and the results bundle;
- ``evaluation``: synthetic datasets with true cameras, metrics, the evaluation protocol.

Shared by all stages: ``cameras.conventions``, ``config`` (presets), ``errors``, ``progress``,
``mesh`` (mesh loading and ray casting), ``jobfolder`` (the job folder's layout) and
``pipeline`` (one job end to end).
"""

__version__ = "0.1.0"

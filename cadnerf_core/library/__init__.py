"""Stage 3: the mini CAD library: its on-disk format, pre-rendered silhouettes, occupancy grids."""

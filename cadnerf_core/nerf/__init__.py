"""The NeRF of CAD-NeRF: fields, volume rendering, empty-space skipping, poses, the three phases."""

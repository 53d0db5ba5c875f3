"""Stages 5 to 8: the NeRF: fields, volume rendering, empty-space skipping, poses, three phases."""

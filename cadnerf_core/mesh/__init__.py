"""Meshes: loading and normalising CAD files, and ray casting them (silhouettes, colour, depth)."""

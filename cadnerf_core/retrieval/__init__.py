"""Stage 4: retrieval of a similar CAD model and every photo's pose from the library."""

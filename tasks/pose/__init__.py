"""Stage 2, pose: detect, track and pick the fighters, estimate and refine 2D pose."""

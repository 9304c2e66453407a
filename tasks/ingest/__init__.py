"""Stage 1, ingest: probe and register videos, find shot cuts, plan chunks."""

"""Where Ringside keeps things: the DuckDB file, the artifact store, stage keys."""

"""Prefect flows: one per stage and the pipeline that chains them. Only the CLI imports these."""

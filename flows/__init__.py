"""Prefect flows: the one flow that runs any stage, the pipeline that chains the stages, the
server and the watched folder; the CLI. Only the CLI imports these."""

"""The work of each stage, as plain functions, with Prefect tasks at the edge."""

"""MAAIP (Younes et al., SCA 2023): the two-fighter arena and its batched environment, the
policy, centralised value and discriminators, the losses and rewards, the settings of all of
them and the demonstrations they learn from. The train stage runs them (`tasks.train`); the
evaluate stage and the exported opponent reuse them. Nothing here knows of DuckDB or Prefect."""

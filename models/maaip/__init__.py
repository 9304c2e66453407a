"""MAAIP (Younes et al., SCA 2023): the policy, centralised value and discriminators, the losses
and rewards, their settings and the demonstrations they learn from, trained in the two-fighter
arena (`models.arena`). The train stage runs them (`tasks.train`); the evaluate stage and the
exported opponent reuse them. Nothing here knows of DuckDB or Prefect."""

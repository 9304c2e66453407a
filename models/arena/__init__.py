"""The two-fighter arena of MAAIP (Younes et al., SCA 2023, §5): its MJCF and index (`mjcf`),
its settings (`config`), the batched environment's step (`env`), contacts into damage and falls
(`contacts`), episode starts (`starts`), the puppet of live sparring (`puppet`) and the physics
backends behind one interface (`stepping`). Nothing here knows of MAAIP's networks, DuckDB or
Prefect."""

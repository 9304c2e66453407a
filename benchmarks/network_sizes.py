"""Which network sizes the CPU can train at: the measurement behind the `cpu` preset.

For each candidate hidden-layer size (policy, value and the three discriminators alike, MAAIP
§4.4) one `Trainer` on the DeepMimic punch clip performed by two facing fighters runs a
warm-up iteration, then `REPEATS` timed iterations with the default config otherwise (64
environments x 32 steps, 5 PPO epochs, 5 discriminator updates of 512 + 512 samples). Printed
per size: parameters of the policy, seconds per iteration spent collecting (policy inference
and environment steps) and learning (rewards, discriminator and PPO updates), and end-to-end
environment steps per second (best repeat).

The `cpu` preset is the size with the highest end-to-end throughput: on 2 cores a one-hour run
is bound by how many transitions it can simulate (whether a larger net learns more per hour is
not measured here). The last line is that size's throughput,
``cpu_preset_steps_per_s: V steps/s``, and the line before names it.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

# As `ringside` sets it (flows/cli/environment.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from models.maaip.config import PRESETS, NetworkConfig  # noqa: E402
from models.maaip.trainer import Trainer  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.train.config import TrainConfig  # noqa: E402
from tasks.train.data import clip_demonstrations  # noqa: E402

REPEATS = 2
SIZES = ((128, 128), (256, 128), (256, 256, 128), (512, 256), (512, 512, 256), PRESETS["paper"])
LEARN = ("rewards_s", "discriminators_s", "ppo_s")


def main() -> None:
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    demos = clip_demonstrations(assets, "punch")
    base = TrainConfig()
    steps = base.ppo.horizon * base.env.num_envs
    rows = []
    for sizes in SIZES:
        hidden = ",".join(str(s) for s in sizes)
        config = replace(base, network=NetworkConfig(hidden=hidden))
        trainer = Trainer(config, demos)
        try:
            trainer.iterate()
            best = None
            for _ in range(REPEATS):
                start = time.perf_counter()
                metrics = trainer.iterate()
                wall = time.perf_counter() - start
                if best is None or wall < best[0]:
                    best = (wall, metrics["collect_s"], sum(metrics[k] for k in LEARN))
            params = sum(p.numel() for p in trainer.nets.policy.parameters())
        finally:
            trainer.close()
        wall, collect, learn = best
        rows.append((sizes, params, collect, learn, steps / wall))
        print(
            f"{hidden:>14}: policy {params / 1e6:5.2f} M parameters, collect {collect:.2f} s, "
            f"learn {learn:.2f} s per iteration, {steps / wall:,.0f} env steps/s",
            flush=True,
        )
    chosen = max(rows, key=lambda row: row[4])
    print(f"cpu preset: {','.join(str(s) for s in chosen[0])} (in use: {PRESETS['cpu']})")
    print(f"cpu_preset_steps_per_s: {chosen[4]:,.0f} steps/s")


if __name__ == "__main__":
    main()

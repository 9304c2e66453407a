"""A fingerprint of what training computes, to hold a refactor to "bit for bit unchanged".

    python benchmarks/training_digest.py

Three iterations of MAAIP (seed 3, DeepMimic's punch performed by two facing fighters, 4 arenas)
and of the tracker (seed 5, DeepMimic's walk and punch), each on every stepping ("rollout",
"threads", "warp" on the CPU), with one torch thread. For each run it prints the SHA-256 of
the networks' weights (every state dict's tensors, in name order) and of the curves (every
iteration's metrics but the wall-clock ones: a name ending in `_s` or `_per_s`). Run it on two
commits: equal lines mean the same arithmetic. Last line: ``training_digest: <first 16 hex>
sha256``, over every run's two digests.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

# As `ringside` sets it (flows/cli/environment.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

from models.arena.config import STEPPINGS, EnvConfig  # noqa: E402
from models.humanoid.boxer import BoneLengths  # noqa: E402
from models.maaip.config import DiscriminatorConfig, NetworkConfig, PPOConfig  # noqa: E402
from models.maaip.trainer import Trainer  # noqa: E402
from models.tracking.clips import tracking_data  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.deepmimic import clip_path, load_deepmimic, retarget  # noqa: E402
from tasks.train.config import TrainConfig  # noqa: E402
from tasks.train.data import clip_demonstrations  # noqa: E402

ITERATIONS = 3
BONES = (BoneLengths(), BoneLengths())


def _weights(trainer: Trainer) -> str:
    digest = hashlib.sha256()
    for name, nets in sorted(trainer.state().networks.items()):
        for net in nets if isinstance(nets, list) else [nets]:
            for key in sorted(net):
                digest.update(f"{name}.{key}".encode())
                digest.update(net[key].detach().cpu().numpy().tobytes())
    return digest.hexdigest()


def _curves(curves: list[dict[str, float]]) -> str:
    kept = [
        {k: v for k, v in sorted(c.items()) if not (k.endswith("_s") or k.endswith("_per_s"))}
        for c in curves
    ]
    return hashlib.sha256(json.dumps(kept).encode()).hexdigest()


def main() -> None:
    torch.set_num_threads(1)
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    demos = clip_demonstrations(assets, "punch", BONES)
    clips = {n: retarget(load_deepmimic(clip_path(assets, n))) for n in ("walk", "punch")}
    clips_data = tracking_data((clips, clips), BONES, fps=30.0, key="clips:walk,punch")
    total = hashlib.sha256()
    for stepping in STEPPINGS:
        env = EnvConfig(num_envs=4, threads=2, stepping=stepping)
        ppo = PPOConfig(horizon=8, minibatch_size=32, epochs=2)
        runs = {
            "maaip": (
                TrainConfig(
                    seed=3,
                    network=NetworkConfig(hidden="32,32"),
                    discriminator=DiscriminatorConfig(
                        samples_per_update=32, updates_per_iteration=2
                    ),
                    ppo=ppo,
                    env=env,
                ),
                demos,
            ),
            "track": (
                TrainConfig(
                    objective="track",
                    seed=5,
                    network=NetworkConfig(hidden="32,32"),
                    ppo=ppo,
                    env=env,
                ),
                clips_data,
            ),
        }
        for name, (config, data) in runs.items():
            trainer = Trainer(config, data)
            try:
                curves = [trainer.iterate() for _ in range(ITERATIONS)]
                weights = _weights(trainer)
            finally:
                trainer.close()
            line = f"{name:6s} {stepping:8s} weights {weights[:16]}  curves {_curves(curves)[:16]}"
            print(line, flush=True)
            total.update(line.encode())
    print(f"training_digest: {total.hexdigest()[:16]} sha256")


if __name__ == "__main__":
    main()

"""Sparring speed: an exported opponent against its exported partner, onnxruntime and MuJoCo.

Both fighters of a `cpu`-preset run on the DeepMimic punch clip performed by two facing
fighters (two training iterations, so the normalisers hold real statistics; speed does not
depend on how well they box) are exported as opponent folders; `tasks.opponent.spar.spar`
then runs 60 simulated seconds on one core (one arena, onnxruntime on one thread), three
times, and renders 5 simulated seconds at 640 x 360 to time the offscreen renderer.

Last line: ``realtime_factor: R x``, simulated over wall seconds of the best bout.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

# As `ringside` sets it (flows/cli/environment.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from models.maaip.trainer import Trainer  # noqa: E402
from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402
from tasks.opponent.export import export_opponent  # noqa: E402
from tasks.opponent.folder import load_opponent  # noqa: E402
from tasks.opponent.spar import spar  # noqa: E402
from tasks.train.config import TrainConfig  # noqa: E402
from tasks.train.data import clip_demonstrations  # noqa: E402

REPEATS = 3
SECONDS = 60.0


def main() -> None:
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    demos = clip_demonstrations(assets, "punch")
    config = TrainConfig()
    trainer = Trainer(config, demos)
    try:
        for _ in range(2):
            trainer.iterate()
    finally:
        trainer.close()
    with tempfile.TemporaryDirectory(prefix="ringside-spar-") as tmp:
        folders = [
            export_opponent(
                Path(tmp) / f"agent{agent}",
                policy=trainer.nets.policy,
                agent=agent,
                bones=demos.bones,
                env=config.env,
                facts={},
            )
            for agent in (0, 1)
        ]
        opponent, partner = (load_opponent(f) for f in folders)
        best = None
        for _ in range(REPEATS):
            result = spar(opponent, partner, seconds=SECONDS)
            if best is None or result.realtime_factor > best.realtime_factor:
                best = result
        rendered = spar(opponent, partner, seconds=5.0, video=Path(tmp) / "bout.mp4")
    spent = best.timings_s
    total = sum(spent.values())
    print(
        f"{SECONDS:.0f} simulated s, network {config.network.hidden_sizes}, best of {REPEATS}: "
        f"{best.wall_s:.2f} s wall (policies {spent['policy'] / total:.0%}, "
        f"physics {spent['physics'] / total:.0%})"
    )
    ms = 1e3 * rendered.timings_s["render"] / rendered.frames_rendered
    print(f"offscreen rendering at 640x360: {ms:.0f} ms per frame (software EGL)")
    print(f"realtime_factor: {best.realtime_factor:.1f} x")


if __name__ == "__main__":
    main()

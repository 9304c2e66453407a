"""How a matched opponent falls: step by step from a standing start against the still partner,
the clip and frame it plays, how far its pelvis is from the motion's (root) and its bodies from
the motion's about the pelvis (body), and both speeds, until its first fall.

    python benchmarks/matched_trace.py FOLDER [--seconds 4]

FOLDER is a matched opponent (`ringside export --run KEY --matched`). Last line:
``matched_first_fall_s: <s> s`` (the bout's length if it did not fall).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.arena.env import ArenaEnv  # noqa: E402
from tasks.opponent.folder import load_opponent  # noqa: E402
from tasks.opponent.spar import env_config, fighters, seen, standing_start  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--seconds", type=float, default=4.0)
    args = parser.parse_args()
    opponent = load_opponent(args.folder, kind="matched")
    (mine, theirs), bones, guards = fighters(opponent, None)
    config, slot = env_config(opponent), opponent.agent
    library = mine.database.library
    first = args.seconds
    with ArenaEnv(config, np.random.default_rng(0), (bones[0], bones[1])) as env:
        obs = env.reset([0], standing_start(env, guards))
        bodies = env.body_states(np.zeros(1, dtype=int))
        mine.reset(seen(obs, bodies, slot))
        theirs.reset(seen(obs, bodies, 1 - slot))
        print("step  clip frame  root_m body_m  motion_m/s body_m/s")
        for step in range(round(args.seconds * config.policy_hz)):
            clip, frame = library.locate(mine.frames(np.zeros(1, dtype=int)))
            ref = mine.reference(np.zeros(1, dtype=int))
            actions = np.empty((1, 2, 28))
            actions[0, slot] = mine.act(seen(obs, bodies, slot))[0]
            actions[0, 1 - slot] = theirs.act(seen(obs, bodies, 1 - slot))[0]
            result = env.step(actions)
            sim = result.body.pos[0, slot]
            root = np.linalg.norm(sim[0] - ref.pos[0, 0])
            body = np.linalg.norm((sim - sim[0]) - (ref.pos[0] - ref.pos[0, 0]), axis=-1).mean()
            speeds = [
                np.linalg.norm(v[0, :2]) for v in (ref.lin_vel[0], result.body.lin_vel[0, slot])
            ]
            print(
                f"{step:4d} {int(clip[0]):5d} {int(frame[0]):5d} {root:7.2f} {body:6.2f} "
                f"{speeds[0]:10.2f} {speeds[1]:8.2f}"
            )
            obs, bodies = result.observation, result.body
            if result.done[0]:
                first = (step + 1) / config.policy_hz
                break
    print(f"matched_first_fall_s: {first:.2f} s")


if __name__ == "__main__":
    main()

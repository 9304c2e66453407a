"""For the live-sparring tests and benchmark: opponent folders and a real server process.

The folders are real exports (`export_opponent`) of an untrained policy whose mean is each
fighter's guard, taken from DeepMimic's punch clip as both fighters perform it. Such an opponent
stands in its guard (tests/test_opponent.py), which is what a live test needs; what a trained
one does is the evaluation's business."""

from __future__ import annotations

import contextlib
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from flows.serve import stop_process
from models.arena.config import EnvConfig
from models.humanoid.boxer import BoneLengths
from models.humanoid.stance import guard_pose
from models.maaip.config import NetworkConfig
from models.maaip.networks import make_networks
from tasks.opponent.export import export_opponent
from tasks.train.config import TrainConfig
from tasks.train.data import clip_demonstrations

BONES = (BoneLengths(), BoneLengths().scaled(0.95))


def untrained_opponents(
    root: Path, bones: tuple[BoneLengths, BoneLengths], stance: np.ndarray, env: EnvConfig
) -> tuple[Path, Path]:
    """Agent 0 and agent 1 of one untrained policy whose mean is ``stance`` (2, 28), exported
    under ``root`` for an arena of ``bones`` stepped as ``env``; returns the folders."""
    config = TrainConfig(network=NetworkConfig(hidden="32,32"), env=env)
    nets = make_networks(config, generator=torch.Generator().manual_seed(0), stance=stance)
    facts = {"dataset_key": "none", "run_key": "untrained", "iteration": 0, "metrics": {}}
    return tuple(
        export_opponent(
            root / f"agent{agent}",
            policy=nets.policy.eval(),
            agent=agent,
            bones=bones,
            env=config.env,
            facts=facts,
        )
        for agent in (0, 1)
    )


def guard_opponents(assets: Path, root: Path) -> tuple[Path, Path]:
    """`untrained_opponents` in the guards of DeepMimic's punch as `BONES` perform it."""
    demos = clip_demonstrations(assets, "punch", BONES)
    stance = np.stack(
        [
            guard_pose(b, q)
            for b, q in zip(BONES, (demos.reference.qpos0, demos.reference.qpos1), strict=True)
        ]
    )
    return untrained_opponents(root, BONES, stance, EnvConfig(num_envs=32))


REPO = Path(__file__).resolve().parent.parent


class Served(NamedTuple):
    url: str  # the WebSocket URL it printed
    viewer: str  # the viewer's URL it printed (with ?token= where it needs one)
    process: subprocess.Popen


@contextlib.contextmanager
def spar_server(
    folder: Path, data: Path, *more: str, env: dict[str, str] | None = None
) -> Iterator[Served]:
    """`ringside --data DATA spar-server FOLDER --port 0 MORE` as a child process, its output in
    files beside ``data`` (a full pipe would stall it). On the way out it must stop on SIGTERM
    within 15 s and have logged no traceback."""
    out, err = data.with_suffix(".out"), data.with_suffix(".err")
    argv = [sys.executable, "-m", "flows.cli", "--data", str(data), "spar-server", str(folder)]
    with out.open("w") as stdout, err.open("w") as stderr:
        server = subprocess.Popen(
            [*argv, "--port", "0", *more],
            cwd=REPO,
            stdout=stdout,
            stderr=stderr,
            env=env,
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 120.0
        while not (
            found := re.search(r"^spar server: (ws://\S+)\s+viewer: (\S+)", out.read_text())
        ):
            if server.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"spar-server did not listen:\n{err.read_text()[-3000:]}")
            time.sleep(0.2)
        yield Served(found[1], found[2], server)
    finally:
        stop_process(server, timeout_s=15)
    said = err.read_text()
    assert server.returncode != -signal.SIGKILL, f"it did not stop on SIGTERM:\n{said[-3000:]}"
    assert "Traceback" not in said, said[-3000:]

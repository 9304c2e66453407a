"""For the live-sparring tests and benchmark: opponent folders and a real server process.

The folders are real exports (`export_opponent`) of an untrained policy whose mean is each
fighter's guard, taken from DeepMimic's punch clip as both fighters perform it. Such an opponent
stands in its guard (tests/test_opponent.py), which is what a live test needs; what a trained
one does is the evaluation's business. For the tracker's kinds: a tiny tracker trained two
iterations (`walk_tracker`); for any kind: broken copies of a folder refused in one line
(`broken_copy`, `refused`), `ringside spar` without torch (`spar_without_torch`) and a served
session's first states (`served_states`)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from websockets.asyncio.client import connect

from flows.serve import stop_process
from models.arena.config import EnvConfig
from models.humanoid.boxer import BoneLengths
from models.humanoid.stance import guard_pose
from models.maaip.config import NetworkConfig, PPOConfig
from models.maaip.networks import Policy, make_networks
from models.maaip.trainer import Trainer
from models.tracking.clips import tracking_data
from models.tracking.matching import MatchConfig
from tasks.deepmimic import clip_path, load_deepmimic, retarget
from tasks.errors import BadInput
from tasks.opponent.export import MatchedFootage, export_matched, export_opponent
from tasks.opponent.folder import load_opponent
from tasks.train.config import TrainConfig
from tasks.train.data import clip_demonstrations

BONES = (BoneLengths(), BoneLengths().scaled(0.95))
REPO = Path(__file__).resolve().parent.parent

# The tiny tracker's run: two iterations of 4 arenas on the default bodies.
TRACK = TrainConfig(
    objective="track",
    seed=5,
    network=NetworkConfig(hidden="32,32"),
    ppo=PPOConfig(horizon=8, minibatch_size=32, epochs=2),
    env=EnvConfig(num_envs=4, threads=1),
)


def walk_tracker(walk: np.ndarray, hidden: str = "32,32") -> Policy:
    """A tracker trained two iterations (`TRACK`, its network ``hidden``) on ``walk`` (T, 35) at
    30 Hz, both agents on the default bones (its normaliser has seen data); in eval mode."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    bones = (BoneLengths(), BoneLengths())
    data = tracking_data(({"walk": walk}, {"walk": walk}), bones, fps=30.0, key="clips:walk")
    trainer = Trainer(replace(TRACK, network=NetworkConfig(hidden=hidden)), data)
    try:
        for _ in range(2):
            trainer.iterate()
    finally:
        trainer.close()
        torch.set_num_threads(before)
    return trainer.nets.policy.eval()


def facing(qpos: np.ndarray, gap_m: float) -> np.ndarray:
    """qpos (T, 35) of a partner holding the first frame of ``qpos``, ``gap_m`` ahead of its
    pelvis along its facing and turned to face it."""
    first = qpos[0].copy()
    turn = Rotation.from_euler("z", np.pi)
    root = Rotation.from_quat(first[3:7], scalar_first=True)
    ahead = root.apply([1.0, 0.0, 0.0]) * [1.0, 1.0, 0.0]
    first[:2] += gap_m * ahead[:2] / np.linalg.norm(ahead[:2])
    first[3:7] = (turn * root).as_quat(scalar_first=True)
    return np.tile(first, (len(qpos), 1))


def walk_punch_footage(assets: Path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """A fighter's footage for the matched opponent: DeepMimic's walk with its partner 4 m ahead
    (out of reach all the clip) and its punch with the partner 0.7 m ahead, on the default
    bones: (name, the fighter's qpos, the partner's) each."""
    walk = retarget(load_deepmimic(clip_path(assets, "walk")))
    punch = retarget(load_deepmimic(clip_path(assets, "punch")))
    return [("walk", walk, facing(walk, 4.0)), ("punch", punch, facing(punch, 0.7))]


def matched_opponent(
    out: Path,
    footage: list[tuple[str, np.ndarray, np.ndarray]],
    policy: Policy,
    matcher: MatchConfig = MatchConfig(),  # noqa: B008 (frozen, so a safe default)
) -> Path:
    """The matched opponent's folder ``out``: tracker ``policy`` (`walk_tracker`) as agent 0
    playing ``footage`` (`walk_punch_footage`) on the default bones, stepped as `TRACK`."""
    facts = {"dataset_key": "none", "run_key": "tracker", "iteration": 2, "metrics": {}}
    return export_matched(
        out,
        policy=policy,
        agent=0,
        bones=(BoneLengths(), BoneLengths()),
        env=TRACK.env,
        footage=MatchedFootage(tuple(footage), ()),
        matcher=matcher,
        facts=facts,
    )


def broken_copy(root: Path, folder: Path, name: str, change) -> Path:
    """A copy of opponent ``folder`` as ``root/name``, ``change(copy, manifest)`` applied and
    the manifest written back."""
    copy = root / name
    shutil.copytree(folder, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    change(copy, manifest)
    (copy / "manifest.json").write_text(json.dumps(manifest))
    return copy


def refused(copy: Path, pattern: str) -> None:
    """Loading ``copy`` raises BadInput matching ``pattern``, in one line."""
    with pytest.raises(BadInput, match=pattern) as caught:
        load_opponent(copy)
    assert "\n" not in str(caught.value)


def spar_without_torch(folder: Path) -> dict:
    """`ringside spar FOLDER --seconds 2 --json` in a fresh interpreter, asserting that nothing
    imported torch; its JSON result."""
    code = (
        "import json, sys; from flows.cli import main; "
        f"rc = main(['spar', '{folder}', '--seconds', '2', '--json']); "
        "assert 'torch' not in sys.modules, 'torch was imported'; sys.exit(rc)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[0])


async def served_states(url: str, count: int) -> list[dict]:
    """The first ``count`` states of a session in commands mode on the server at ``url``."""
    async with connect(url) as ws:
        await ws.send(json.dumps({"type": "hello", "protocol": 1, "mode": "commands"}))
        welcome = json.loads(await ws.recv())
        assert welcome["type"] == "welcome"
        states = []
        while len(states) < count:
            message = json.loads(await asyncio.wait_for(ws.recv(), 10.0))
            if message["type"] == "state":
                states.append(message)
        return states


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

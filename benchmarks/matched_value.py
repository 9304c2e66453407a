# ruff: noqa: E401, E402, E501, E702
"""Does the tracker's value pick better frames than the matcher's distance? A prototype.

    python benchmarks/matched_value.py FOLDER --data D [--partner FOLDER] [--judged 0 8]

At each search the matched opponent takes, of playing on and the K nearest candidates (each
laid as it would be), the one whose next frame its run's value network (read from the run's
checkpoint in data folder D) rates highest; K = 0 is the matcher's own rule. Falls a minute
against the still partner, and both fighters matched as `matched_falls.py --partner` runs them.
Last line: ``matched_value_falls_per_min: <falls> /min`` for the last K.
"""

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))
from matched_falls import both_matched

from models.maaip.networks import CentralValue
from models.maaip.trainer import _load
from models.tracking.matched import MatchedTracker
from models.tracking.task import TRACK_OBSERVATION_DIM
from storage.artifacts import read_bytes
from storage.db import connect
from storage.paths import data_paths
from tasks.config import build
from tasks.opponent.folder import load_opponent
from tasks.opponent.matched import MOTION
from tasks.opponent.spar import spar
from tasks.train.config import TrainConfig
from tasks.train.store import finished_run

p = argparse.ArgumentParser()
p.add_argument("folder", type=Path)
p.add_argument("--partner", type=Path)
p.add_argument("--data", type=Path, required=True)
p.add_argument("--judged", type=int, nargs="+", default=[0, 4, 8, 16])
p.add_argument("--seconds", type=float, default=60.0)
p.add_argument("--bouts", type=int, default=10)
a = p.parse_args()
paths = data_paths(a.data)
base = load_opponent(a.folder, kind="matched")
run = base.manifest["run_key"]
with connect(paths.db, read_only=True) as con:
    info = finished_run(con, run, "--run")
config = build(TrainConfig, info.config, section="train")
state = _load(read_bytes(paths.artifacts, info.artifact))


def critic(agent):
    v = CentralValue(
        hidden=config.network.hidden_sizes,
        obs_dim=TRACK_OBSERVATION_DIM,
        observation_clip=config.network.observation_clip,
        sees_other=config.track.value_sees_partner,
    )
    v.load_state_dict(state["networks"]["value"])
    v.eval()
    assert not config.track.value_sees_partner

    def judge(obs):
        with torch.no_grad():
            x = torch.as_tensor(obs, dtype=torch.float32)
            return v(x, x, agent).double().numpy()

    return judge


with np.load(a.folder / MOTION) as stored:
    arrays = {n: stored[n] for n in stored.files}
partner = load_opponent(a.partner) if a.partner else None
for k in a.judged:
    judge = critic(base.agent) if k else None
    m = MatchedTracker(
        base.controller.policy, base.controller.database, judge=judge, judged=max(k, 1)
    )
    opp = dataclasses.replace(base, controller=m)
    r = spar(opp, None, seconds=a.seconds)
    print(
        f"judged {k}: still partner {r.falls[0] / (a.seconds / 60):.1f} falls/min; {m.counts.switches} of {m.counts.searches} switched",
        flush=True,
    )
    if partner is not None:
        pj = critic(partner.agent) if k else None
        pm = MatchedTracker(
            partner.controller.policy, partner.controller.database, judge=pj, judged=max(k, 1)
        )
        both_matched(
            opp,
            dataclasses.replace(partner, controller=pm),
            arrays,
            bouts=a.bouts,
            seconds=a.seconds,
        )
print(f"matched_value_falls_per_min: {r.falls[0] / (a.seconds / 60):.1f} /min")

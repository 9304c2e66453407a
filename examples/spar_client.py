"""Spar against a live opponent with a recorded motion: a client of `ringside spar-server`.

    .venv/bin/python examples/spar_client.py MOTION.bvh [--url ws://127.0.0.1:8765/spar]
        [--token T] [--loop N] [--offset X Y] [--yaw DEG] [--answer ANSWER.bvh]
        [--summary SUMMARY.json] [--bones BONES.json] [--opponent-folder FOLDER]
        [--orbit DEG_PER_S] [--approach NEAR FAR SPEED]

It opens a session in "poses" mode (docs/spar-protocol.md) and plays a Ringside BVH file
(`ringside export-motion`: a video's lifted motion of either fighter, or a bout's) as the
partner, one `pose` a frame at the file's frame rate, paced in real time, `--loop` times over.
Every `state` the server sends is recorded; the opponent's answer, its pose in each state from
the first one that used our motion to the one that used its last frame, is written as BVH
(`--answer`), and a JSON summary (`--summary`): states received, round trip (each pose's `seq`
to the first state whose `ack` reached it) p50/p99, the share of late states, falls, and how
squarely the opponent faced the partner over time (its heading against the bearing from its
pelvis to the partner's).

Placing the motion: the file's motion is turned about the vertical and shifted on the floor as
one rigid piece (`place_motion`) so that its first frame's pelvis stands at `--offset X Y`
(metres, the arena's world) facing `--yaw` degrees (0 along +x, counter-clockwise). Without
`--offset` it starts where the server put the partner (read from the first state), without
`--yaw` it faces the opponent's pelvis from there. Heights and the joints' motion are kept.
The server takes a pose more than 0.5 m from the last as a jump and then puts the opponent back
in its guard 1.2 m in front of the partner (docs/spar-protocol.md, `reset`): a first frame put
further than that from the partner's start moves the opponent with it, and so does each
`--loop` restart of a motion that travels.

The bones: the partner has the server's default bones unless `--bones` gives a JSON object of
`models.humanoid.boxer.BoneLengths` (sent in `hello`). The answer is written on the opponent's
bones: the welcome's fighter entry's `bones` if the server sends them, else the opponent
folder's manifest (`--opponent-folder`), else the default bones (with a warning on stderr).

`--orbit` carries the placed motion round the opponent's start as it plays, and `--approach`
then steps it in to NEAR and out to FAR metres from there (`orbit_motion`, `approach_motion`).

The pure parts (`place_motion`, `orbit_motion`, `approach_motion`, `facing_errors`,
`facing_summary`, `round_trips`, `percentiles_ms`) take no network and are what the tests
import.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from models.humanoid.boxer import BoneLengths
from models.humanoid.bvh import bvh_text, read_bvh
from models.humanoid.kinematics import ROOT_QUAT, heading_yaw, wrap_angle

DEFAULT_URL = "ws://127.0.0.1:8765/spar"
PROTOCOL = 1
# How long to wait, after the last pose went out, for the state that used it.
TAIL_S = 2.0

# --------------------------------------------------------------------------
# Pure parts
# --------------------------------------------------------------------------


def place_motion(
    qpos: np.ndarray, offset: Sequence[float] | None = None, yaw: float | None = None
) -> np.ndarray:
    """One humanoid's motion turned about z and shifted on the floor as one rigid piece.

    Args:
        qpos: (T, 35) the motion.
        offset: (x, y) in metres where the first frame's pelvis is put; None leaves it where it
            is.
        yaw: the first frame's heading afterwards (`heading_yaw` of the pelvis), radians; None
            keeps the motion's own. The turn is about the first frame's pelvis.

    Returns:
        (T, 35) the placed motion: heights and hinge angles as they were.
    """
    q = np.array(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 35 or not len(q):
        raise ValueError(f"qpos must have shape (T >= 1, 35), got {q.shape}")
    start = q[0, :2].copy()
    target = start if offset is None else np.asarray(offset, dtype=np.float64)
    turn = 0.0 if yaw is None else float(yaw - heading_yaw(q[0, ROOT_QUAT]))
    c, s = math.cos(turn), math.sin(turn)
    q[:, :2] = (q[:, :2] - start) @ np.array([[c, -s], [s, c]]).T + target
    spin = Rotation.from_euler("z", turn)
    root = Rotation.from_quat(q[:, ROOT_QUAT], scalar_first=True)
    q[:, ROOT_QUAT] = (spin * root).as_quat(canonical=True, scalar_first=True)
    return q


def orbit_motion(qpos: np.ndarray, centre: Sequence[float], rate: float, fps: float) -> np.ndarray:
    """The motion carried round ``centre`` (x, y) at ``rate`` radians per second as it plays:
    frame i turned by rate * i / fps about the vertical through the centre (the partner circles
    the opponent, so that an opponent that follows it must turn)."""
    q = np.array(qpos, dtype=np.float64)
    angles = rate * np.arange(len(q)) / fps
    spin = Rotation.from_euler("z", angles[:, None])
    offsets = np.c_[q[:, :2] - np.asarray(centre, dtype=np.float64), np.zeros(len(q))]
    q[:, :2] = spin.apply(offsets)[:, :2] + np.asarray(centre, dtype=np.float64)
    root = Rotation.from_quat(q[:, ROOT_QUAT], scalar_first=True)
    q[:, ROOT_QUAT] = (spin * root).as_quat(canonical=True, scalar_first=True)
    return q


def approach_motion(
    qpos: np.ndarray,
    centre: Sequence[float],
    near_m: float,
    far_m: float,
    speed_m_s: float,
    fps: float,
) -> np.ndarray:
    """The motion stepping in towards ``centre`` (x, y) and out again: each frame's pelvis put on
    its own bearing from the centre at a distance that goes from the first frame's, in to
    ``near_m`` and out to ``far_m`` and back, at ``speed_m_s`` (a partner that steps into reach
    and out of it, so that an opponent that keeps its distance must step). Its orientation and
    everything else as it was."""
    if not 0 < near_m < far_m or not speed_m_s > 0 or not fps > 0:
        raise ValueError(
            f"need 0 < near < far, speed > 0 and fps > 0, got {near_m}, {far_m}, {speed_m_s}, {fps}"
        )
    q = np.array(qpos, dtype=np.float64)
    centre = np.asarray(centre, dtype=np.float64)
    away = q[:, :2] - centre
    bearing = np.arctan2(away[:, 1], away[:, 0])
    # A triangle wave between near and far over the path walked, starting at the first frame's
    # distance on its way in.
    span, walked = far_m - near_m, speed_m_s * np.arange(len(q)) / fps
    phase = (far_m - np.clip(np.linalg.norm(away[0]), near_m, far_m) + walked) % (2 * span)
    distance = far_m - np.where(phase < span, phase, 2 * span - phase)
    q[:, :2] = centre + distance[:, None] * np.c_[np.cos(bearing), np.sin(bearing)]
    return q


def facing_errors(
    opponent_xy: np.ndarray, opponent_heading: np.ndarray, partner_xy: np.ndarray
) -> np.ndarray:
    """How far the opponent's heading is turned from the partner: heading minus the bearing from
    its pelvis to the partner's, radians in [-pi, pi) (0: facing the partner squarely, positive:
    turned counter-clockwise past it).

    Args:
        opponent_xy: (T, 2) the opponent's pelvis on the floor.
        opponent_heading: (T,) its heading, a world yaw.
        partner_xy: (T, 2) the partner's pelvis on the floor.
    """
    towards = np.asarray(partner_xy, dtype=np.float64) - np.asarray(opponent_xy, dtype=np.float64)
    bearing = np.arctan2(towards[:, 1], towards[:, 0])
    return wrap_angle(np.asarray(opponent_heading, dtype=np.float64) - bearing)


def facing_summary(
    t: np.ndarray, errors: np.ndarray, still: np.ndarray, window_s: float = 1.0
) -> dict:
    """`facing_errors` over a session: mean, median and p90 of |error| in degrees, the share of
    states within 30 deg, and the mean |error| per `window_s` window (from the first state);
    beside them the mean |error| an opponent that never turned would have had (``still``: the
    errors of its first heading, the baseline a reacting opponent must beat)."""
    t = np.asarray(t, dtype=np.float64)
    off = np.degrees(np.abs(np.asarray(errors, dtype=np.float64)))
    if not len(off):
        return {"states": 0}
    bins = np.floor((t - t[0]) / window_s).astype(int)
    series = [
        {
            "t_s": round(float(b * window_s), 3),
            "mean_abs_deg": round(float(off[bins == b].mean()), 2),
        }
        for b in np.unique(bins)
    ]
    return {
        "states": len(off),
        "mean_abs_deg": round(float(off.mean()), 2),
        "p50_abs_deg": round(float(np.percentile(off, 50)), 2),
        "p90_abs_deg": round(float(np.percentile(off, 90)), 2),
        "within_30_deg": round(float(np.mean(off <= 30.0)), 4),
        "still_mean_abs_deg": round(float(np.degrees(np.abs(still)).mean()), 2),
        "per_window": series,
        "window_s": window_s,
    }


def moved_through(angles: np.ndarray, restarted: np.ndarray) -> float:
    """How far an angle (T,) went round in all, radians, leaving out each step that follows a
    restart (``restarted`` (T,): the state after which the opponent was put back)."""
    steps = wrap_angle(np.diff(np.asarray(angles, dtype=np.float64)))
    return float(np.sum(steps[~np.asarray(restarted, dtype=bool)[:-1]]))


def round_trips(
    sent: Mapping[int, float], received: Sequence[tuple[float, int | None]]
) -> np.ndarray:
    """Each sent message's round trip: seconds from its sending to the first state received with
    an `ack` at or past its `seq` (the server echoes the latest seq it used). Messages never
    acknowledged are left out.

    Args:
        sent: seq -> the clock when it was sent.
        received: (the clock when it arrived, its ack or None) of every state, in arrival order.

    Returns:
        (n,) seconds, in seq order.
    """
    seqs = sorted(sent)
    out, pending = [], 0
    for arrived, ack in received:
        if ack is None:
            continue
        while pending < len(seqs) and seqs[pending] <= ack and sent[seqs[pending]] <= arrived:
            out.append(arrived - sent[seqs[pending]])
            pending += 1
    return np.asarray(out, dtype=np.float64)


def percentiles_ms(seconds: np.ndarray) -> dict:
    """p50, p99 and max of durations in seconds, as milliseconds; n the count."""
    s = np.asarray(seconds, dtype=np.float64)
    if not len(s):
        return {"n": 0, "p50": None, "p99": None, "max": None}
    p50, p99 = np.percentile(s, [50, 99]) * 1e3
    return {"n": len(s), "p50": round(p50, 3), "p99": round(p99, 3), "max": round(s.max() * 1e3, 3)}


# --------------------------------------------------------------------------
# The session
# --------------------------------------------------------------------------


class SparError(RuntimeError):
    """The server refused the session (an `error` message) or broke the protocol."""


def fighter(state: dict, role: str) -> dict:
    for entry in state["fighters"]:
        if entry["role"] == role:
            return entry
    raise SparError(f"state {state.get('step')} has no {role!r} fighter")


@dataclass
class Recording:
    """What one session sent and received."""

    welcome: dict = field(default_factory=dict)
    placement: dict = field(default_factory=dict)
    sent: dict[int, float] = field(default_factory=dict)
    states: list[dict] = field(default_factory=list)
    arrived: list[float] = field(default_factory=list)
    errors: list[dict] = field(default_factory=list)


async def _read_until_state(ws, recording: Recording) -> dict:
    while True:
        message = json.loads(await ws.recv())
        if message.get("type") == "state":
            recording.arrived.append(time.perf_counter())
            recording.states.append(message)
            return message
        if message.get("type") == "error":
            recording.errors.append(message)


async def spar_session(
    url: str,
    motion: np.ndarray,
    fps: float,
    *,
    token: str | None = None,
    loops: int = 1,
    offset: Sequence[float] | None = None,
    yaw_deg: float | None = None,
    bones: BoneLengths | None = None,
    orbit_deg_s: float = 0.0,
    approach: tuple[float, float, float] | None = None,
) -> Recording:
    """Stream ``motion`` (T, 35) as the partner at ``fps``, ``loops`` times; record the session.
    ``approach`` (near, far, speed): stepping in to near and out to far metres from the
    opponent's start at speed m/s (`approach_motion`), after the orbit."""
    recording = Recording()
    hello = {"type": "hello", "protocol": PROTOCOL, "mode": "poses"}
    if token:
        hello["token"] = token
    if bones is not None:
        hello["bones"] = {k: float(v) for k, v in vars(bones).items()}
    async with connect(url, open_timeout=10, max_size=2**22) as ws:
        await ws.send(json.dumps(hello))
        welcome = json.loads(await asyncio.wait_for(ws.recv(), 10))
        if welcome.get("type") == "error":
            raise SparError(
                f"server refused the session: {welcome.get('code')}: {welcome.get('message')}"
            )
        if welcome.get("type") != "welcome":
            raise SparError(f"expected a welcome, got {welcome.get('type')!r}")
        recording.welcome = welcome
        first = await asyncio.wait_for(_read_until_state(ws, recording), 10)
        opponent_xy = np.array(fighter(first, "opponent")["bodies"]["pelvis"][:2])
        start = (
            np.array(fighter(first, "partner")["bodies"]["pelvis"][:2])
            if offset is None
            else np.asarray(offset, dtype=np.float64)
        )
        if yaw_deg is None:
            towards = opponent_xy - start
            yaw = math.atan2(towards[1], towards[0])
        else:
            yaw = math.radians(yaw_deg)
        placed = place_motion(np.tile(motion, (loops, 1)), start, yaw)
        if orbit_deg_s:
            placed = orbit_motion(placed, opponent_xy, math.radians(orbit_deg_s), fps)
        if approach is not None:
            placed = approach_motion(placed, opponent_xy, *approach, fps)
        recording.placement = {
            "offset": start.round(4).tolist(),
            "yaw_deg": round(math.degrees(yaw), 3),
        }
        total = len(placed)
        sending_done = asyncio.Event()

        # Poses go out half a server step after its states arrive: one sent just as a state
        # arrives lands as the server reads its input, and jitter then makes it miss a step and
        # double up the next.
        policy_hz = float(welcome.get("policy_hz", 30))

        async def send() -> None:
            begin = recording.arrived[-1] + 0.5 / policy_hz
            for i in range(total):
                delay = begin + i / fps - time.perf_counter()
                if delay > 0:
                    await asyncio.sleep(delay)
                pose = {"type": "pose", "seq": i, "qpos": placed[i].tolist()}
                recording.sent[i] = time.perf_counter()
                await ws.send(json.dumps(pose))
            sending_done.set()

        async def receive() -> None:
            while True:
                message = json.loads(await ws.recv())
                kind = message.get("type")
                if kind == "state":
                    recording.arrived.append(time.perf_counter())
                    recording.states.append(message)
                    ack = message.get("ack")
                    if sending_done.is_set() and ack is not None and ack >= total - 1:
                        return
                elif kind == "error":
                    recording.errors.append(message)
                    print(
                        f"server: {message.get('code')}: {message.get('message')}", file=sys.stderr
                    )

        receiver = asyncio.create_task(receive())
        try:
            await send()
            await asyncio.wait_for(asyncio.shield(receiver), TAIL_S + 2.0 / fps)
        except TimeoutError:
            print(f"no state acknowledged the last pose within {TAIL_S} s", file=sys.stderr)
        finally:
            receiver.cancel()
        await ws.send(json.dumps({"type": "bye"}))
        try:
            while True:  # drain until the server closes (1000)
                await asyncio.wait_for(ws.recv(), 2.0)
        except (ConnectionClosed, TimeoutError):
            pass
    return recording


def answer_states(recording: Recording) -> list[dict]:
    """The states that answered the motion: from the first that used a pose of ours (an ack) to
    the first that used the last one."""
    last = max(recording.sent, default=-1)
    out = []
    for state in recording.states:
        ack = state.get("ack")
        if ack is None:
            continue
        out.append(state)
        if ack >= last:
            break
    return out


def opponent_bones(welcome: dict, folder: Path | None) -> tuple[BoneLengths, str]:
    """The opponent's bones and where they came from (module docstring)."""
    entry = next((f for f in welcome.get("fighters", []) if f.get("role") == "opponent"), {})
    if isinstance(entry.get("bones"), dict):
        return BoneLengths(**entry["bones"]), "welcome"
    if folder is not None:
        manifest = json.loads((folder / "manifest.json").read_text())
        return BoneLengths(**manifest["bones"][int(manifest["agent"])]), str(folder)
    print(
        "the welcome carries no bones and no --opponent-folder was given: the answer is written "
        "on the default bones",
        file=sys.stderr,
    )
    return BoneLengths(), "default"


def summary(
    recording: Recording,
    *,
    motion: str,
    fps: float,
    loops: int,
    bones_from: str,
    orbit_deg_s: float = 0.0,
) -> dict:
    """The session's JSON summary (module docstring)."""
    states = recording.states
    answer = answer_states(recording)
    t = np.array([s.get("t", 0.0) for s in states])
    opp = [fighter(s, "opponent") for s in states]
    par = [fighter(s, "partner") for s in states]
    opponent_xy = np.array([o["bodies"]["pelvis"][:2] for o in opp]).reshape(-1, 2)
    partner_xy = np.array([p["bodies"]["pelvis"][:2] for p in par]).reshape(-1, 2)
    heading = np.array([o["heading"] for o in opp])
    errors = facing_errors(opponent_xy, heading, partner_xy)
    still = facing_errors(opponent_xy, np.full(len(heading), heading[:1].mean()), partner_xy)
    towards = partner_xy - opponent_xy
    restarted = np.array([bool(s.get("reset")) for s in states])
    bearing = moved_through(np.arctan2(towards[:, 1], towards[:, 0]), restarted)
    turned = moved_through(heading, restarted)
    received = [(a, s.get("ack")) for a, s in zip(recording.arrived, states, strict=True)]
    step_ms = np.array([s.get("step_ms", np.nan) for s in states], dtype=np.float64) / 1e3
    return {
        "motion": motion,
        "fps": round(fps, 6),
        "loops": loops,
        "session": recording.welcome.get("session"),
        "placement": recording.placement,
        "poses_sent": len(recording.sent),
        "states_received": len(states),
        "answer_frames": len(answer),
        "answer_bones_from": bones_from,
        "round_trip_ms": percentiles_ms(round_trips(recording.sent, received)),
        "step_ms": percentiles_ms(step_ms[np.isfinite(step_ms)]),
        "late_states": sum(bool(s.get("late")) for s in states),
        "late_share": round(float(np.mean([bool(s.get("late")) for s in states])), 4)
        if states
        else None,
        "falls": {"opponent": opp[-1]["falls"], "partner": par[-1]["falls"]} if states else {},
        "resets": sum(bool(s.get("reset")) for s in states),
        "contact_share": round(float(np.mean([bool(s.get("contacts")) for s in states])), 4)
        if states
        else None,
        "damage_n": {
            "opponent": round(sum(o.get("damage_n", 0.0) for o in opp), 2),
            "partner": round(sum(p.get("damage_n", 0.0) for p in par), 2),
        },
        "facing": facing_summary(t, errors, still),
        # How far the bearing to the partner went round, and how far the opponent turned with
        # it, leaving out the jumps of its restarts.
        "bearing_moved_deg": round(float(np.degrees(bearing)), 1),
        "opponent_turned_deg": round(float(np.degrees(turned)), 1),
        "orbit_deg_s": orbit_deg_s,
        "errors": recording.errors,
    }


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Stream a Ringside BVH as the partner to `ringside spar-server` and record "
        "the opponent's answer.",
    )
    parser.add_argument("motion", type=Path, help="a BVH file Ringside wrote (export-motion)")
    parser.add_argument("--url", default=DEFAULT_URL, help=f"the server (default {DEFAULT_URL})")
    parser.add_argument("--token", help="the token the server printed (non-loopback servers)")
    parser.add_argument("--loop", type=int, default=1, metavar="N", help="play the motion N times")
    parser.add_argument(
        "--offset",
        type=float,
        nargs=2,
        metavar=("X", "Y"),
        help="where the motion's first pelvis stands, metres (default: the partner's start)",
    )
    parser.add_argument(
        "--yaw",
        type=float,
        metavar="DEG",
        help="the motion's first heading, degrees from +x (default: facing the opponent)",
    )
    parser.add_argument(
        "--answer",
        type=Path,
        default=Path("spar-answer.bvh"),
        help="the opponent's answer as BVH (default spar-answer.bvh)",
    )
    parser.add_argument(
        "--summary",
        type=Path,
        default=Path("spar-summary.json"),
        help="the session's summary (default spar-summary.json)",
    )
    parser.add_argument("--bones", type=Path, help="the partner's bones, JSON (BoneLengths keys)")
    parser.add_argument(
        "--opponent-folder",
        type=Path,
        help="the server's opponent folder, for its bones if the welcome has none",
    )
    parser.add_argument(
        "--orbit",
        type=float,
        default=0.0,
        metavar="DEG_PER_S",
        help="carry the motion round the opponent's start at this rate (default 0: in place)",
    )
    parser.add_argument(
        "--approach",
        type=float,
        nargs=3,
        metavar=("NEAR", "FAR", "SPEED"),
        help="step the motion in to NEAR and out to FAR metres from the opponent's start at "
        "SPEED m/s (after --orbit; default: its own distance)",
    )
    args = parser.parse_args(argv)
    if args.loop < 1:
        parser.error("--loop must be at least 1")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        fps, motion = read_bvh(args.motion.read_text())
        bones = BoneLengths(**json.loads(args.bones.read_text())) if args.bones else None
    except (OSError, ValueError, TypeError) as error:
        print(f"spar client: {error}", file=sys.stderr)
        return 1
    try:
        recording = asyncio.run(
            spar_session(
                args.url,
                motion,
                fps,
                token=args.token,
                loops=args.loop,
                offset=args.offset,
                yaw_deg=args.yaw,
                bones=bones,
                orbit_deg_s=args.orbit,
                approach=args.approach,
            )
        )
    except (SparError, OSError, ConnectionClosed, TimeoutError) as error:
        print(f"spar client: {error}", file=sys.stderr)
        return 1
    answer = answer_states(recording)
    if not answer:
        print("spar client: no state answered the motion", file=sys.stderr)
        return 1
    answer_bones, bones_from = opponent_bones(recording.welcome, args.opponent_folder)
    qpos = np.array([fighter(s, "opponent")["qpos"] for s in answer], dtype=np.float64)
    args.answer.write_text(
        bvh_text(answer_bones, qpos, float(recording.welcome.get("policy_hz", 30)))
    )
    facts = summary(
        recording,
        motion=str(args.motion),
        fps=fps,
        loops=args.loop,
        bones_from=bones_from,
        orbit_deg_s=args.orbit,
    )
    args.summary.write_text(json.dumps(facts, indent=2) + "\n")
    trip = facts["round_trip_ms"]
    print(
        f"{facts['states_received']} states, answer {facts['answer_frames']} frames -> "
        f"{args.answer}; round trip p50 {trip['p50']} ms p99 {trip['p99']} ms, "
        f"late {facts['late_share']:.1%}, falls {facts['falls']}, facing off by "
        f"{facts['facing'].get('mean_abs_deg')} deg on average (never turning: "
        f"{facts['facing'].get('still_mean_abs_deg')} deg); summary -> {args.summary}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

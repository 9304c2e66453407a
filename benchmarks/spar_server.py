"""The live sparring server under load: step time, loopback round trip and lateness per session.

    python benchmarks/spar_server.py [--kind maaip|matched]

Starts a real `ringside spar-server` subprocess on a port the system picks (`--port 0`,
`--max-sessions 32`) on an opponent folder made as the tests make theirs (tests/opponents.py).
`--kind maaip` (the default): an untrained policy exported as agent 1, standing in its guard.
`--kind matched`: the matched opponent, a tracker of the stage's default network size trained
two iterations, playing DeepMimic's walk and punch as the motion matcher picks them every 0.1 s
(it falls and restarts often, and each restart is a step of its own: a heavier load than a
trained one's). Speed does not depend on how well either boxes.

Then 1, 4, 8, 16 and 32 concurrent sessions, all in "commands" mode, each a
WebSocket client in this process, on one asyncio loop (the clients take CPU from the server on
this 2-core machine): every step a session sends a `command` (a slowly turning heading at
0.3 m/s, so the partner circles near the opponent) with a fresh `seq`, and takes each pose's
round trip as the time from sending it to the arrival of the first `state` whose `ack` reaches
that `seq` (examples/spar_client.py's `round_trips`). The sessions open together
and start sending once all have their welcome; each sends its command half a step after each
of its states arrives (each session has its own 30 Hz clock on the server, which shifts when it
lets a missed slot go), so that a command waits about half a step to be read rather than
whatever the phase between two clocks made it; the first `WARMUP_S` (the policy's first runs) is
left out and the next `SECONDS` are measured.

Per session count it prints: the server's step time p50/p99 (the states' `step_ms`: the
opponent's policy and the physics, and any wait for one of the server's step threads), the
loopback round trip p50/p99 (half a 30 Hz step, 17 ms, of it is the wait for the next step),
states per second per session (the slowest session's), the share of late states (computed
after their 30 Hz slot had passed), and the longest wait from hello to welcome (the bout's
creation). Then the states' mean size, a step's and its JSON encoding's time measured in this
process, how many sessions hold real time (late share under
1 %), and, last,
``spar_round_trip_p99_1_session: <ms> ms`` (``spar_round_trip_p99_1_session_matched`` for the
matched kind).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
# The tests' opponent folders (tests/opponents.py, free of conftest's set-up) and the example
# client's round-trip measure.
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "examples"))

# As `ringside` sets it (flows/cli/environment.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from opponents import (  # noqa: E402
    guard_opponents,
    matched_opponent,
    spar_server,
    walk_punch_footage,
    walk_tracker,
)
from spar_client import percentiles_ms, round_trips  # noqa: E402
from websockets.asyncio.client import connect  # noqa: E402
from websockets.exceptions import ConnectionClosed  # noqa: E402

from storage.assets import pull  # noqa: E402
from storage.paths import data_paths  # noqa: E402

SESSIONS = (1, 4, 8, 16, 32)
SECONDS = 10.0
WARMUP_S = 1.0
RATE_HZ = 30.0
REAL_TIME_LATE_SHARE = 0.01
SETTLE_S = 2.0


async def session(url: str, number: int, ready: asyncio.Barrier) -> dict:
    """One client: opens its session, waits for the others (``ready``), then sends a command
    every step for WARMUP_S + SECONDS; what it saw."""
    sent: dict[int, float] = {}
    received: list[tuple[float, int | None]] = []
    states: list[dict] = []
    errors: list[dict] = []
    async with connect(url, open_timeout=30) as ws:
        asked = time.perf_counter()
        await ws.send(json.dumps({"type": "hello", "protocol": 1, "mode": "commands"}))
        welcome = json.loads(await ws.recv())
        opened = time.perf_counter() - asked
        if welcome.get("type") != "welcome":
            raise SystemExit(f"session {number} refused: {welcome}")

        async def receive() -> None:  # from the welcome on: a client that stops reading is closed
            while True:
                text = await ws.recv()
                message = json.loads(text)
                if message.get("type") == "state":
                    arrived = time.perf_counter()
                    received.append((arrived, message.get("ack")))
                    states.append(
                        {
                            "arrived": arrived,
                            "step_ms": message["step_ms"],
                            "late": message["late"],
                            "bytes": len(text),
                        }
                    )
                elif message.get("type") == "error":
                    errors.append(message)

        receiver = asyncio.create_task(receive())
        await ready.wait()
        # A command every step, half a step after each state arrives (as examples/spar_client.py
        # starts its poses): it then waits about half a step to be read, whatever the phase
        # between the server's clock (its own per session, shifted whenever it lets a missed
        # slot go) and ours.
        seen = len(states)
        while len(states) == seen:
            await asyncio.sleep(0.001)
        begin = states[-1]["arrived"]
        end = begin + WARMUP_S + SECONDS
        seq = 0
        while (now := time.perf_counter()) < end:
            seen = len(states)
            await asyncio.sleep(max(0.0, states[-1]["arrived"] + 0.5 / RATE_HZ - now))
            heading = 0.5 * (now - begin) + number * 2 * math.pi / 8
            sent[seq] = time.perf_counter()
            await ws.send(
                json.dumps({"type": "command", "seq": seq, "heading": heading, "speed": 0.3})
            )
            seq += 1
            while len(states) == seen or states[-1]["arrived"] < sent[seq - 1]:
                await asyncio.sleep(0.0005)  # the next state
        await asyncio.sleep(0.2)  # the last commands' states
        receiver.cancel()
        await ws.send(json.dumps({"type": "bye"}))
        try:
            while True:
                await asyncio.wait_for(ws.recv(), 2.0)
        except (ConnectionClosed, TimeoutError):
            pass
    start = begin + WARMUP_S
    measured = {s: t for s, t in sent.items() if start <= t <= end}
    kept = [s for s in states if start <= s["arrived"] <= end]
    return {
        "opened_s": opened,
        "round_trips": round_trips(measured, received),
        "step_ms": np.array([s["step_ms"] for s in kept]),
        "late": np.array([s["late"] for s in kept], dtype=bool),
        "states_per_s": len(kept) / SECONDS,
        "bytes": np.array([s["bytes"] for s in kept]),
        "errors": errors,
    }


def step_and_encoding_ms(opponent: Path, steps: int = 300) -> tuple[float, float, int]:
    """In this process: a commands-mode step and its state's JSON encoding, mean milliseconds,
    and the state's bytes (is JSON the limit?)."""
    from flows.spar_server import state_message
    from tasks.opponent.folder import load_opponent
    from tasks.opponent.live import LiveBout

    with LiveBout(load_opponent(opponent), "commands") as bout:
        bout.command(1.0, 0.5)
        for _ in range(20):
            bout.step()
        begin = time.perf_counter()
        for _ in range(steps):
            step = bout.step()
        stepped = time.perf_counter()
        for _ in range(steps):
            text = json.dumps(state_message(step, 1, False, 1.0))
        encoded = time.perf_counter()
    return (stepped - begin) / steps * 1e3, (encoded - stepped) / steps * 1e3, len(text)


async def load(url: str, count: int) -> list[dict]:
    ready = asyncio.Barrier(count)
    return await asyncio.gather(*(session(url, n, ready) for n in range(count)))


def opponent_folder(kind: str, assets: Path, root: Path) -> Path:
    """The served opponent of ``kind`` (module docstring), made under ``root``."""
    if kind == "maaip":
        return guard_opponents(assets, root)[1]
    from models.maaip.config import NetworkConfig

    footage = walk_punch_footage(assets)
    policy = walk_tracker(footage[0][1], hidden=",".join(map(str, NetworkConfig().hidden_sizes)))
    return matched_opponent(root / "matched", footage, policy)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=("maaip", "matched"), default="maaip")
    kind = parser.parse_args().kind
    assets = data_paths().assets
    pull(assets, dev=True, log=lambda _line: None)
    rows = {}
    sizes: list[int] = []
    with tempfile.TemporaryDirectory(prefix="ringside-spar-server-") as tmp:
        opponent = opponent_folder(kind, assets, Path(tmp))
        step_ms, encode_ms, size = step_and_encoding_ms(opponent)
        most = str(max(SESSIONS))
        with spar_server(opponent, Path(tmp) / "data", "--max-sessions", most) as (url, _, _):
            for count in SESSIONS:
                # A session closed a moment ago still counts towards --max-sessions while the
                # server tidies it away (8 opened at once right after 4 closed got a too_many).
                time.sleep(SETTLE_S)
                results = asyncio.run(load(url, count))
                errors = [e for r in results for e in r["errors"]]
                if errors:
                    print(f"{count} sessions: the server sent errors: {errors[:3]}")
                rows[count] = {
                    "step": percentiles_ms(np.concatenate([r["step_ms"] for r in results]) / 1e3),
                    "trip": percentiles_ms(np.concatenate([r["round_trips"] for r in results])),
                    "late": float(np.concatenate([r["late"] for r in results]).mean()),
                    "rate": min(r["states_per_s"] for r in results),
                    "opened": max(r["opened_s"] for r in results),
                }
                sizes.extend(b for r in results for b in r["bytes"])
    print(
        f"ringside spar-server, the {kind} opponent, commands mode at {RATE_HZ:.0f} Hz, "
        f"{SECONDS:.0f} s measured per "
        f"session count after {WARMUP_S:.0f} s of warm-up, {os.cpu_count()} CPUs, loopback"
    )
    print(
        "sessions  step p50  step p99  round trip p50  round trip p99  states/s (min)  late"
        "   opening (max)"
    )
    for count, row in rows.items():
        print(
            f"{count:8d}  {row['step']['p50']:5.2f} ms  {row['step']['p99']:5.2f} ms  "
            f"{row['trip']['p50']:11.2f} ms  {row['trip']['p99']:11.2f} ms  "
            f"{row['rate']:14.1f}  {row['late']:5.1%}  {row['opened']:11.2f} s"
        )
    print(f"a state message: {np.mean(sizes) / 1024:.1f} KiB of JSON on average")
    print(
        f"in one process: a step {step_ms:.2f} ms, its state encoded as JSON {encode_ms:.2f} ms "
        f"({size / 1024:.1f} KiB)"
    )
    holding = [c for c, row in rows.items() if row["late"] < REAL_TIME_LATE_SHARE]
    most = max(holding, default=0)
    print(
        f"real time (late share under {REAL_TIME_LATE_SHARE:.0%}) held with up to {most} "
        f"concurrent session{'s' * (most != 1)} of {', '.join(map(str, SESSIONS))} tried"
        + ("" if holding == [c for c in SESSIONS if c <= most] else f" (held at: {holding})")
    )
    name = "spar_round_trip_p99_1_session" + ("_matched" if kind == "matched" else "")
    print(f"{name}: {rows[1]['trip']['p99']:.1f} ms")


if __name__ == "__main__":
    main()

"""The live sparring server: one `LiveBout` per WebSocket connection, stepped in real time.

The protocol is docs/spar-protocol.md. Built on the `websockets` library's asyncio server
(Prefect brings it): one event loop reads and writes every connection, and the steps run on a
small thread pool (onnxruntime and MuJoCo's mj_step release the GIL), so a session that
misbehaves or a client that stops reading holds up no other. Each session keeps its own 30 Hz
clock and never waits for its client: input is taken when it comes, the latest wins, and states
go out through a queue of one second; a client that lets it fill is dropped (its socket is full:
no error frame could reach it).
The same port serves the viewer (flows/spar_viewer/) and three.js from the data directory's
assets (`ringside assets pull`), never from a CDN.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import mimetypes
import socket
import time
import uuid
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, fields
from http import HTTPStatus
from pathlib import Path

from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from models.humanoid.boxer import BoneLengths
from models.humanoid.kinematics import BODY_NAMES, PARENTS
from tasks.opponent.folder import Opponent
from tasks.opponent.live import MAX_TURN_RATE, MODES, BadPose, LiveBout, LiveStep, WrongMode

PROTOCOL = 1
PATH = "/spar"
MAX_FRAME_BYTES = 64 * 1024
HELLO_S = 5.0
MAX_SEQ = 2**53  # the largest integer a JavaScript client holds exactly
QUEUE_S = 1.0  # states a client may fall behind by before it is closed
# A small kernel send buffer: a real-time client wants the newest state, not seconds of stale
# ones queued on the way; with it a client that stops reading is found within about 2 s.
SEND_BUFFER_BYTES = 64 * 1024
VIEWER = Path(__file__).resolve().parent / "spar_viewer"
LOOPBACK = ("127.0.0.1", "localhost", "::1")


class ProtocolError(Exception):
    """A bad message: `code` and a one-line message, as the error frame carries them."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Hello:
    mode: str
    token: str | None
    bones: BoneLengths | None


def needs_token(host: str) -> bool:
    """Whether clients must send a token: any address but the loopback one."""
    return host not in LOOPBACK


def _object(text: str | bytes) -> dict:
    if isinstance(text, bytes):
        raise ProtocolError("bad_json", "frames are JSON text, got a binary frame")
    try:
        message = json.loads(text)
    except json.JSONDecodeError as error:
        raise ProtocolError("bad_json", f"not JSON ({error})") from None
    if not isinstance(message, dict):
        raise ProtocolError("bad_json", f"a message is a JSON object, got {type(message).__name__}")
    return message


def parse_hello(text: str | bytes) -> Hello:
    """The client's first message (docs/spar-protocol.md); ProtocolError otherwise."""
    try:
        message = _object(text)
    except ProtocolError as error:
        raise ProtocolError("bad_hello", str(error)) from None
    if message.get("type") != "hello":
        raise ProtocolError("bad_hello", f"the first message must be a hello, got {message!r:.80}")
    if message.get("protocol") != PROTOCOL:
        raise ProtocolError(
            "bad_version",
            f"protocol {message.get('protocol')!r} is not spoken here; this server speaks "
            f"{PROTOCOL}",
        )
    mode = message.get("mode")
    if mode not in MODES:
        raise ProtocolError("bad_hello", f"mode must be one of {list(MODES)}, got {mode!r}")
    token = message.get("token")
    if token is not None and not isinstance(token, str):
        raise ProtocolError("bad_hello", "token must be a string")
    bones = message.get("bones")
    if bones is not None:
        known = {f.name for f in fields(BoneLengths)}
        if not isinstance(bones, dict) or not set(bones) <= known:
            raise ProtocolError(
                "bad_hello", f"bones must be an object with keys of {sorted(known)}"
            )
        try:
            bones = BoneLengths(**{k: float(v) for k, v in bones.items()})
        except (TypeError, ValueError) as error:
            raise ProtocolError("bad_hello", f"bones: {error}") from None
    return Hello(mode, token, bones)


def _number(message: dict, key: str) -> float:
    value = message.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ProtocolError("bad_message", f"{key} must be a number, got {value!r:.40}")
    return float(value)


def apply_message(bout: LiveBout, text: str | bytes) -> int | None:
    """Apply one client message after the hello to the bout; returns its `seq` (or None), and
    raises ProtocolError for a bad one (the bout is then as it was). "bye" raises EOFError."""
    message = _object(text)
    seq = message.get("seq")
    if seq is not None and (
        isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq <= MAX_SEQ
    ):
        raise ProtocolError("bad_message", f"seq must be an integer in [0, 2^53], got {seq!r:.40}")
    kind = message.get("type")
    try:
        if kind == "command":
            bout.command(_number(message, "heading"), _number(message, "speed"))
        elif kind == "pose":
            qpos = message.get("qpos")
            if not isinstance(qpos, list):
                raise ProtocolError("bad_message", f"qpos must be a list, got {qpos!r:.40}")
            bout.pose(qpos)
        elif kind == "bye":
            raise EOFError
        else:
            raise ProtocolError("bad_message", f"unknown message type {kind!r:.40}")
    except WrongMode as error:
        raise ProtocolError("bad_message", str(error)) from None
    except BadPose as error:
        raise ProtocolError("bad_pose" if kind == "pose" else "bad_command", str(error)) from None
    return seq


def welcome(bout: LiveBout, session: str) -> dict:
    roles = {bout.slot: "opponent", bout.partner_slot: "partner"}
    return {
        "type": "welcome",
        "protocol": PROTOCOL,
        "session": session,
        "mode": bout.mode,
        "policy_hz": bout.config.policy_hz,
        "physics_hz": bout.config.policy_hz * bout.config.substeps,
        "max_turn_rate": MAX_TURN_RATE,
        # The policy driving the partner's limbs in commands mode (None: it holds its guard).
        "partner_policy": None if bout.partner is None else str(bout.partner.folder),
        "bodies": list(BODY_NAMES),
        "parents": list(PARENTS),
        "fighters": [
            {
                "role": roles[slot],
                "slot": slot,
                "bones": asdict(bout.bones[slot]),
                "geoms": bout.geoms(slot),
            }
            for slot in (bout.slot, bout.partner_slot)
        ],
    }


def _rounded(values, digits: int) -> list[float]:
    return [round(float(v), digits) for v in values]


def state_message(step: LiveStep, ack: int | None, late: bool, step_ms: float) -> dict:
    fighters = []
    for f in step.fighters:
        bodies = {
            name: _rounded(p, 4) + _rounded(q, 5)
            for name, p, q in zip(BODY_NAMES, f.positions, f.quaternions, strict=True)
        }
        fighters.append(
            {
                "role": f.role,
                "slot": f.slot,
                "bodies": bodies,
                "qpos": _rounded(f.qpos, 6),
                "heading": round(f.heading, 5),
                "damage_n": round(f.damage_n, 2),
                "fell": f.fell,
                "falls": f.falls,
            }
        )
    return {
        "type": "state",
        "step": step.step,
        "t": round(step.t, 4),
        "ack": ack,
        "late": late,
        "step_ms": round(step_ms, 3),
        "fighters": fighters,
        "contacts": [[a, b, round(force, 1)] for a, b, force in step.contacts],
        "reset": step.reset,
    }


def _timed_step(bout: LiveBout) -> tuple[LiveStep, float]:
    """A step and its milliseconds, timed on the worker thread (not the wait for one)."""
    begin = time.perf_counter()
    step = bout.step()
    return step, (time.perf_counter() - begin) * 1000.0


def warm_up(opponent: Opponent, partner: Opponent | None = None) -> None:
    """A few steps of a throwaway bout: the first steps after a start (onnxruntime's first
    runs, MuJoCo's first model) take 45-90 ms, which would make a first client's states late."""
    for mode in MODES:
        with LiveBout(opponent, mode, partner=partner) as bout:
            for _ in range(5):
                bout.step()


def error_message(error: ProtocolError) -> str:
    return json.dumps({"type": "error", "code": error.code, "message": str(error)})


class SparServer:
    """The server's state across connections: the opponent, the token, the step pool."""

    def __init__(
        self,
        opponent: Opponent,
        *,
        assets: Path,
        token: str | None,
        partner: Opponent | None = None,
        max_sessions: int = 8,
        threads: int = 2,
    ):
        self.opponent = opponent
        self.partner = partner
        self.assets = assets
        self.token = token
        self.max_sessions = max_sessions
        self.sessions = 0
        self.pool = ThreadPoolExecutor(threads, thread_name_prefix="spar-step")

    # ---------------------------------------------------------------- HTTP

    def http(self, connection: ServerConnection, request: Request) -> Response | None:
        """Serve the viewer and its three.js files; None lets the WebSocket handshake go on."""
        path = request.path.split("?", 1)[0]
        if path == PATH:
            return None
        if path == "/":
            file = VIEWER / "index.html"
        elif path.startswith("/three/"):
            file = self.assets / "three" / path.removeprefix("/three/")
        else:
            file = VIEWER / path.lstrip("/")
        root = self.assets / "three" if path.startswith("/three/") else VIEWER
        file = file.resolve()
        if not file.is_relative_to(root.resolve()) or not file.is_file():
            missing = "run `ringside assets pull` for three.js" if "three" in path else ""
            return connection.respond(HTTPStatus.NOT_FOUND, f"not found: {path} {missing}\n")
        body = file.read_bytes()
        kind = mimetypes.guess_type(file.name)[0] or "application/octet-stream"
        if file.suffix == ".js":
            kind = "text/javascript"
        headers = Headers(
            [
                ("Content-Type", kind),
                ("Content-Length", str(len(body))),
                ("Cache-Control", "no-cache"),
                # One request per connection, as websockets' own responses: a browser keeping it
                # open for the next file held the handshake's timeout open with it (a traceback).
                ("Connection", "close"),
            ]
        )
        return Response(HTTPStatus.OK.value, HTTPStatus.OK.phrase, headers, body)

    # ---------------------------------------------------------------- sessions

    async def handle(self, connection: ServerConnection) -> None:
        sock = connection.transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        if self.sessions >= self.max_sessions:
            await self._refuse(
                connection,
                ProtocolError("too_many", f"this server runs {self.max_sessions} sessions already"),
                1013,
            )
            return
        self.sessions += 1
        try:
            await self._session(connection)
        finally:
            self.sessions -= 1

    async def _refuse(self, connection: ServerConnection, error: ProtocolError, code=1008) -> None:
        with contextlib.suppress(ConnectionClosed):
            await connection.send(error_message(error))
            await connection.close(code, error.code)

    async def _session(self, connection: ServerConnection) -> None:
        loop = asyncio.get_running_loop()
        try:
            first = await asyncio.wait_for(connection.recv(), HELLO_S)
            hello = parse_hello(first)
        except TimeoutError:
            await self._refuse(connection, ProtocolError("bad_hello", f"no hello in {HELLO_S} s"))
            return
        except ProtocolError as error:
            await self._refuse(connection, error)
            return
        except ConnectionClosed:
            return
        if self.token is not None and not hmac.compare_digest(
            (hello.token or "").encode(), self.token.encode()
        ):
            await self._refuse(
                connection, ProtocolError("unauthorized", "a missing or wrong token")
            )
            return
        bout = await loop.run_in_executor(
            self.pool, lambda: LiveBout(self.opponent, hello.mode, hello.bones, self.partner)
        )
        session = uuid.uuid4().hex[:12]
        outbox: asyncio.Queue[str] = asyncio.Queue(maxsize=round(QUEUE_S * bout.config.policy_hz))
        acked: list[int | None] = [None]
        tasks = []
        try:
            await connection.send(json.dumps(welcome(bout, session)))
            reader = asyncio.create_task(self._read(connection, bout, outbox, acked))
            writer = asyncio.create_task(self._write(connection, outbox))
            tasks = [reader, writer]
            await self._tick(connection, bout, outbox, acked, tasks)
        except ConnectionClosed:
            pass
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await loop.run_in_executor(self.pool, bout.close)

    async def _read(self, connection, bout: LiveBout, outbox: asyncio.Queue, acked: list) -> None:
        """Apply the client's messages as they come; one error frame per bad one."""
        async for text in connection:
            try:
                seq = apply_message(bout, text)
            except EOFError:
                await connection.close(1000, "bye")
                return
            except ProtocolError as error:
                with contextlib.suppress(asyncio.QueueFull):
                    outbox.put_nowait(error_message(error))
                continue
            if seq is not None:
                acked[0] = seq

    async def _write(self, connection: ServerConnection, outbox: asyncio.Queue) -> None:
        while True:
            await connection.send(await outbox.get())

    async def _tick(
        self,
        connection: ServerConnection,
        bout: LiveBout,
        outbox: asyncio.Queue,
        acked: list,
        tasks: list[asyncio.Task],
    ) -> None:
        """Step the bout on its clock until the client goes or falls a second behind."""
        loop = asyncio.get_running_loop()
        period = 1.0 / bout.config.policy_hz
        slot = loop.time()
        while not any(task.done() for task in tasks):
            ack = acked[0]
            step, step_ms = await loop.run_in_executor(self.pool, _timed_step, bout)
            late = loop.time() > slot + period
            try:
                outbox.put_nowait(json.dumps(state_message(step, ack, late, step_ms)))
            except asyncio.QueueFull:
                # Its writer is stuck on a full socket: the error frame could not reach it.
                connection.transport.abort()
                return
            slot += period
            # A slot missed is let go, not made up in a burst: real time, not a backlog.
            slot = max(slot, loop.time() - period)
            await asyncio.sleep(max(0.0, slot - loop.time()))
        for task in tasks:
            failed = task.done() and not task.cancelled() and task.exception()
            if failed and not isinstance(failed, ConnectionClosed):
                raise failed


async def run_server(
    server: SparServer,
    host: str,
    port: int,
    ready: Callable[[int], None],
    stop: asyncio.Event,
) -> None:
    """Serve until `stop` is set; `ready` gets the bound port."""
    async with serve(
        server.handle,
        host,
        port,
        process_request=server.http,
        max_size=MAX_FRAME_BYTES,
        compression=None,  # deflate costs CPU on every state for little on a LAN
        close_timeout=2,
    ) as ws_server:
        bound = next(iter(ws_server.sockets)).getsockname()[1]
        ready(bound)
        await stop.wait()
    server.pool.shutdown(wait=True)

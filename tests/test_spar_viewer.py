"""The live-sparring viewer (flows/spar_viewer) in headless Chromium against a real
`ringside spar-server` on an untrained guard opponent (tests/opponents.py): the page draws
both fighters from the server's states and steers the partner with the keyboard.

It saves a screenshot to ``data/test-artifacts/spar/viewer.png`` (git-ignored), to be looked at
by eye.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import REPO
from opponents import (
    guard_opponents,
    matched_opponent,
    spar_server,
    walk_punch_footage,
    walk_tracker,
)

CHROMIUM = Path("/usr/bin/chromium")
SCREENSHOT = REPO / "data" / "test-artifacts" / "spar" / "viewer.png"
TOKEN = "test-token"
TURN = math.pi / 2  # the viewer's TURN_STEP: one press of an arrow
# The partner turns kinematically at `max_turn_rate` (pi rad/s, 0.105 rad a 30 Hz step) and
# stops on the commanded heading, so 0.1 rad (6 degrees), under one step's turn, is reached
# with the turn's last step; a turn missed, doubled or the wrong way is 1.5 rad off or more.
HEADING_TOLERANCE = 0.1
# The turn itself takes 0.5 s of the server's clock (checked on the states' `t`); the rest is
# the command's way to the server and the states' way back through a page drawing in software:
# 0.49 to 0.72 s in 20 runs here, over 1 s once on CI's machine beside another test worker.
TURN_WITHIN_S = 2.0
WALK_S = 1.0  # seconds of the partner's walk drawn before its distance is checked
PARTNER = "() => window.spar.last.fighters.find(f => f.role === 'partner')"
TIMED_PELVIS = """() => [window.spar.last.t,
  ...window.spar.last.fighters.find(f => f.role === 'partner').bodies.pelvis.slice(0, 2)]"""
TIMED_HEADING = """() => [window.spar.last.t,
  window.spar.last.fighters.find(f => f.role === 'partner').heading]"""
REFUSED = "() => window.spar && document.getElementById('status').className === 'closed'"
FELL = "() => window.spar.last.fighters.find(f => f.role === 'opponent').falls > 0"
# Each fighter's damage summed and falls, as the page has them and as its table shows them.
NUMBERS = """() => Object.fromEntries(window.spar.last.fighters.map(f => {
  const row = document.getElementById(`fighter-${f.role}`);
  const shown = [row.querySelector('.total').textContent, row.querySelector('.falls').textContent];
  const total = window.spar.totals[f.role];
  return [f.role, {total, falls: f.falls, shown, flashed: row.className}];
}))"""
SEEN = """() => [window.spar.states, window.spar.totals, window.spar.last.contacts,
  window.spar.last.fighters.map(f => [f.role, f.bodies.pelvis, f.heading, f.falls])]"""


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


@contextlib.contextmanager
def served_viewer(folder: Path, assets: Path, root: Path, *more: str) -> Iterator:
    """`ringside spar-server FOLDER MORE` (`spar_server`) on a data directory ``root/data`` of
    its own whose assets hold only three.js (linked from the pulled ones)."""
    data = root / "data"
    (data / "assets").mkdir(parents=True)
    (data / "assets" / "three").symlink_to(assets / "three", target_is_directory=True)
    # The suite shares its assets through RINGSIDE_ASSETS: the server must find three.js under
    # --data instead.
    env = {k: v for k, v in os.environ.items() if k != "RINGSIDE_ASSETS"}
    with spar_server(folder, data, *more, env=env) as served:
        yield served


@contextlib.contextmanager
def viewer_page() -> Iterator:
    """A page of headless Chromium and the list its console errors and page errors go to."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=str(CHROMIUM), args=["--no-sandbox", "--enable-unsafe-swiftshader"]
        )
        try:
            # Small: Chromium draws WebGL in software here, and a large canvas slows the page's
            # handling of states and keys (at 1280x800 a command's round trip took 0.26 s).
            page = browser.new_page(viewport={"width": 960, "height": 600})
            problems: list[str] = []
            page.on("console", lambda m: m.type == "error" and problems.append(m.text))
            page.on("pageerror", lambda error: problems.append(str(error)))
            yield page, problems
        finally:
            browser.close()


@pytest.fixture
def viewer_url(assets: Path, tmp_path: Path) -> str:
    """The viewer's URL as `ringside spar-server` on agent 0 prints it, with a token."""
    agent0, _ = guard_opponents(assets, tmp_path / "opponents")
    # With a token, so that the viewer's way of sending it is tested.
    with served_viewer(agent0, assets, tmp_path, "--token", TOKEN) as served:
        port = served.url.split(":")[2].split("/")[0]
        assert served.viewer == f"http://127.0.0.1:{port}/?token={TOKEN}", served
        yield served.viewer


def _off(walked: list[list[float]], t: float, heading: float) -> tuple[float, float]:
    """How far the partner's pelvis had gone by server time ``t`` from where it was first
    drawn, along ``heading`` and across it; ``walked`` holds (server time, x, y) rows."""
    at = next(np.array(xy) for time_, *xy in walked if time_ == t) - walked[0][1:]
    return float(at @ [math.cos(heading), math.sin(heading)]), float(
        at @ [-math.sin(heading), math.cos(heading)]
    )


def _bodies(state: dict, role: str) -> np.ndarray:
    fighter = next(f for f in state["fighters"] if f["role"] == role)
    return np.array([pose[:3] for pose in fighter["bodies"].values()])


# The viewer's camera (flows/spar_viewer/viewer.js): a 45-degree vertical field of view from
# CAMERA_OFFSET (three.js's y-up frame, metres) off the point 0.3 m above the fighters' pelvis
# midpoint, looking at it; the page moves it with that point and nothing else moves it here.
CAMERA_FOV_DEG = 45.0
CAMERA_OFFSET = np.array([1.6, 1.4, 4.6])


def _pixel(point: np.ndarray, pelvises: np.ndarray, size: tuple[int, int]) -> tuple[int, int]:
    """Where the viewer draws MuJoCo's world point ``point`` (3,) with the pelvises (2, 3) as
    they are, on a canvas ``size`` (width, height): (column, row)."""

    def three(p: np.ndarray) -> np.ndarray:  # MuJoCo's z-up to three.js's y-up
        return np.array([p[0], p[2], -p[1]])

    target = three(pelvises.mean(axis=0)) + [0.0, 0.3, 0.0]
    eye = target + CAMERA_OFFSET
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    seen = three(point) - eye
    width, height = size
    half = math.tan(math.radians(CAMERA_FOV_DEG) / 2) * (seen @ forward)
    x, y = (seen @ right) / (half * width / height), (seen @ up) / half
    return round((x + 1) / 2 * width), round((1 - y) / 2 * height)


def _share(pixels: np.ndarray, colour: tuple[float, ...]) -> float:
    """The share of ``pixels`` (n, 3 RGB) whose strongest channel is ``colour``'s (RGB), 1.5
    times any other (the background, the floor and the skin are greys and a pale pink)."""
    strongest = int(np.argmax(colour))
    others = np.delete(pixels, strongest, axis=1).max(axis=1)
    return float(np.mean(pixels[:, strongest] > 1.5 * others))


def _opponent_moved_m(page) -> float:
    """Once the page has drawn 5 states: how far the opponent's bodies moved, at most, over the
    next second of states, which must be about 30."""
    page.wait_for_function("() => window.spar && window.spar.states >= 5", timeout=60_000)
    first = page.evaluate("() => window.spar.last")
    page.wait_for_timeout(1000)
    later = page.evaluate("() => window.spar.last")
    assert later["step"] - first["step"] >= 20, "about 30 states a second"
    return float(
        np.linalg.norm(_bodies(later, "opponent") - _bodies(first, "opponent"), axis=1).max()
    )


def drive_viewer(url: str, screenshot: Path) -> dict[str, float]:
    """Open the viewer at ``url`` (its ``?token=`` included), check it draws and steers;
    what it measured."""
    measured = {}
    origin = url.split("?")[0]
    with viewer_page() as (page, problems):
        # Everything the page loads comes from the server: no CDN.
        elsewhere: list[str] = []

        def only_the_server(route):
            if route.request.url.startswith(origin):
                return route.continue_()
            elsewhere.append(route.request.url)
            return route.abort()

        page.route("**/*", only_the_server)
        # Without the token: refused, and the page says so.
        page.goto(origin)
        page.wait_for_function(REFUSED, timeout=30_000)
        assert page.evaluate("() => window.spar.errors")[0].startswith("unauthorized: ")
        assert "1008" in page.inner_text("#status")
        page.goto(url)
        # The opponent is simulated: its bodies move from step to step, if only a little.
        measured["opponent_moved_m"] = _opponent_moved_m(page)
        assert measured["opponent_moved_m"] > 1e-3, "the opponent's bodies stood still"

        # Two presses up: 0.5 m/s straight at the opponent, 1.2 m ahead, into it.
        heading = page.evaluate(PARTNER)["heading"]
        commanded = page.evaluate("() => window.spar.heading")
        assert abs(_wrap(heading - commanded)) < HEADING_TOLERANCE, "starts where it faces"
        walked = [page.evaluate(TIMED_PELVIS)]  # (server time, pelvis x, y)
        page.keyboard.press("ArrowUp")
        page.keyboard.press("ArrowUp")
        pressed = time.monotonic()
        assert page.evaluate("() => window.spar.speed") == 0.5
        # Polled until the page has drawn WALK_S of walking on the server's clock: the
        # distance is checked against the server's time, not the page's (whose waits ran
        # long on CI's loaded machine: 1.04 m walked in what the page took for 1.5 s).
        while True:
            page.wait_for_timeout(20)
            walked.append(page.evaluate(TIMED_PELVIS))
            moving = [t for t, *_ in walked if _off(walked, t, commanded)[0] > 1e-3]
            if moving and walked[-1][0] - moving[0] >= WALK_S:
                break
            if time.monotonic() - pressed > TURN_WITHIN_S + WALK_S:
                raise AssertionError(f"the partner did not walk: {walked[-1]} {walked[0]}")
        along, across = _off(walked, walked[-1][0], commanded)
        measured |= {"partner_along_m": along, "partner_across_m": across}
        # 0.5 m/s from some time between the last state drawn before it moved and the
        # first drawn moving; the partner is kinematic: the opponent in its way does not
        # hold it up.
        before = max(t for t, *_ in walked if t < moving[0])
        least, most = (0.5 * (walked[-1][0] - t) for t in (moving[0], before))
        assert least - 0.02 <= along <= most + 0.02 and abs(across) < 0.1, walked
        # Walked into, the opponent is shoved over (within 2 to 3 s here). Whether it
        # takes damage on the way is up to where the two first touch (legs, gloves and
        # arms are not hit), so the damage is checked against the states, not for being
        # there.
        try:
            page.wait_for_function(FELL, timeout=5_000)
        except Exception as error:  # Playwright's TimeoutError
            raise AssertionError(f"the opponent never fell: {page.evaluate(SEEN)}") from error
        page.keyboard.press("s")
        assert page.evaluate("() => window.spar.speed") == 0
        # It stops: over 0.5 s of the server's clock it stays put, within the wall ceiling.
        stopping, pressed = [page.evaluate(TIMED_PELVIS)], time.monotonic()
        while True:
            page.wait_for_timeout(20)
            stopping.append(page.evaluate(TIMED_PELVIS))
            t = stopping[-1][0]
            since = [row[1:] for row in stopping if row[0] >= t - 0.5]
            if t - stopping[0][0] >= 0.5 and np.ptp(since, axis=0).max() < 0.02:
                break
            assert time.monotonic() - pressed < TURN_WITHIN_S + 0.5, f"no stop: {stopping}"

        # The numbers: each fighter's damage summed and its falls as the server counts
        # them, and the opponent's row flashed for its fall (and any damage).
        numbers = page.evaluate(NUMBERS)  # at once: a state may come in between calls
        for role, seen in numbers.items():
            measured |= {f"{role}_damage_n": seen["total"], f"{role}_falls": seen["falls"]}
            assert seen["shown"] == [f"{seen['total']:.0f}", str(seen["falls"])], seen
        flashed = numbers["opponent"]["flashed"]
        assert "fell" in flashed, flashed
        assert ("hit" in flashed) == (numbers["opponent"]["total"] > 0), flashed

        # A quarter turn to the right: the partner's own heading gets there, turning at the
        # welcome's `max_turn_rate` on the server's clock.
        heading = page.evaluate(PARTNER)["heading"]
        target = _wrap(commanded - TURN)
        pressed = time.monotonic()
        page.keyboard.press("ArrowRight")
        assert page.evaluate("() => window.spar.heading") == pytest.approx(target, abs=1e-9)
        drawn = [page.evaluate(TIMED_HEADING)]  # (server time, heading) as the page polls
        while abs(_wrap(drawn[-1][1] - target)) >= HEADING_TOLERANCE:
            if time.monotonic() - pressed > TURN_WITHIN_S:
                raise AssertionError(
                    f"the partner's heading was {drawn[-1][1]:.3f} rad {TURN_WITHIN_S} s "
                    f"after the key press, not {target:.3f} (from {heading:.3f})"
                )
            page.wait_for_timeout(5)
            drawn.append(page.evaluate(TIMED_HEADING))
        measured["turn_s"] = time.monotonic() - pressed
        # From the last state drawn on the old heading to the first on the new one: the
        # quarter turn's 0.5 s, give or take a gap between the states the page drew (0.1 s
        # apart here: it draws in software).
        turning = [t for t, h in drawn if abs(_wrap(h - heading)) < 1e-3]
        rate = page.evaluate("() => window.spar.welcome.max_turn_rate")
        gap = max(np.diff([t for t, _ in drawn]), default=0.0)
        measured["turn_server_s"] = drawn[-1][0] - (turning[-1] if turning else drawn[0][0])
        least = (TURN - HEADING_TOLERANCE) / rate if turning else 0.0  # not a jump
        assert least <= measured["turn_server_s"] <= TURN / rate + 2 * gap + 1e-6, drawn
        page.wait_for_timeout(300)
        settled = page.evaluate(PARTNER)["heading"]
        assert abs(_wrap(settled - target)) < HEADING_TOLERANCE, f"overshot to {settled}"
        assert abs(_wrap(settled - heading + TURN)) < HEADING_TOLERANCE, "turned by 90 deg"

        screenshot.parent.mkdir(parents=True, exist_ok=True)
        # The picture is of a state the page drew while the screenshot was taken, not
        # necessarily the one read before it: taken when both fighters stood (pelvises over
        # 0.6 m) and moved under 10 cm from before the screenshot to after it, so that the
        # pelvises read are where they were drawn (a fallen opponent may lie with its trunks
        # hidden, and a restart after a fall moves it a metre between two states).
        for _ in range(50):
            before = page.evaluate("() => window.spar.last")
            png = page.screenshot(path=str(screenshot))
            shown = page.evaluate("() => window.spar.last")
            pelvises = [
                [np.array(f["bodies"]["pelvis"][:3]) for f in state["fighters"]]
                for state in (before, shown)
            ]
            upright = min(p[2] for state in pelvises for p in state) > 0.6
            moved = max(np.linalg.norm(a - b) for a, b in zip(*pelvises, strict=True))
            if upright and moved < 0.1:
                break
            page.wait_for_timeout(100)
        else:
            raise AssertionError(f"no moment with both fighters standing still: {pelvises}")
        picture = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
        # Each fighter's colour (its trunks', its pelvis's geoms') round where its pelvis
        # projects, and none of the other's: in the 15 x 15 pixels there, measured 32 % for
        # the opponent, its forearm across its trunks, and 100 % for the partner.
        welcome = page.evaluate("() => window.spar.welcome")
        pelvis = welcome["bodies"].index("pelvis")
        colours = {
            f["role"]: {tuple(g["rgba"][:3]) for g in f["geoms"] if g["body"] == pelvis}.pop()
            for f in welcome["fighters"]
        }
        assert len({int(np.argmax(c)) for c in colours.values()}) == 2, colours
        at = {f["role"]: np.array(f["bodies"]["pelvis"][:3]) for f in shown["fighters"]}
        for role, point in at.items():
            column, row = _pixel(point, np.stack(list(at.values())), picture.shape[1::-1])
            patch = picture[row - 7 : row + 8, column - 7 : column + 8].reshape(-1, 3)
            share = {who: _share(patch, colour) for who, colour in colours.items()}
            measured[f"{role}_colour_share"] = share[role]
            others = [s for who, s in share.items() if who != role]
            assert share[role] > 0.2 and max(others) == 0, (role, column, row, share)

        status = page.inner_text("#status")
        assert status.startswith("connected"), status
        assert page.evaluate("() => window.spar.errors") == []
        assert problems == [] and elsewhere == [], (problems, elsewhere)
    return measured


@pytest.mark.skipif(
    not CHROMIUM.exists(), reason=f"Debian's chromium is not installed ({CHROMIUM}): `make setup`"
)
def test_the_viewer_draws_both_fighters_and_steers_the_partner(viewer_url: str):
    measured = drive_viewer(viewer_url, SCREENSHOT)
    print(measured)  # shown with -s, or when it fails
    assert measured["turn_s"] < TURN_WITHIN_S


MATCHED_SCREENSHOT = SCREENSHOT.with_name("viewer-matched.png")


@pytest.mark.skipif(
    not CHROMIUM.exists(), reason=f"Debian's chromium is not installed ({CHROMIUM}): `make setup`"
)
def test_the_viewer_serves_the_matched_opponent(assets: Path, tmp_path: Path):
    """The same page on the matched opponent (a tiny tracker playing DeepMimic's walk and punch
    as the matcher picks them, tests/opponents.py): it draws the opponent's simulated bodies at
    about 30 states a second, the partner turns a quarter on a key press, and nothing errs."""
    footage = walk_punch_footage(assets)
    folder = matched_opponent(tmp_path / "matched", footage, walk_tracker(footage[0][1]))
    with served_viewer(folder, assets, tmp_path) as served, viewer_page() as (page, problems):
        page.goto(served.viewer)
        assert _opponent_moved_m(page) > 0.01, "the matched opponent's bodies stood still"
        target = _wrap(page.evaluate("() => window.spar.heading") - TURN)
        pressed = time.monotonic()
        page.keyboard.press("ArrowRight")
        while abs(_wrap(page.evaluate(PARTNER)["heading"] - target)) >= HEADING_TOLERANCE:
            assert time.monotonic() - pressed < TURN_WITHIN_S, "the partner did not turn"
            page.wait_for_timeout(5)
        MATCHED_SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(MATCHED_SCREENSHOT))
        assert page.inner_text("#status").startswith("connected")
        assert page.evaluate("() => window.spar.errors") == [] and problems == [], problems

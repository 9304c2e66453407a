"""`prefect server start` comes up in the project's environment (the pins keep its web stack
importable), though the pipeline itself uses Prefect's ephemeral server by default."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

FLOW = """
from prefect import flow, task

@task
def answer():
    return 42

@flow
def ask():
    return answer()

print(ask())
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_prefect_server_starts(tmp_path: Path):
    port = free_port()
    prefect = Path(sys.executable).with_name("prefect")
    env = {
        **os.environ,
        "PREFECT_HOME": str(tmp_path),
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "PREFECT_UI_ENABLED": "false",
    }
    log = (tmp_path / "server.log").open("w")
    server = subprocess.Popen(
        [str(prefect), "server", "start", "--host", "127.0.0.1", "--port", str(port)],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 120
        healthy = False
        while time.monotonic() < deadline and server.poll() is None:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/health", timeout=2) as r:
                    healthy = r.status == 200
                    break
            except OSError:
                time.sleep(0.5)
        assert healthy, (tmp_path / "server.log").read_text()[-3000:]
        # A flow with a task run against it, then read back: the reads are what broke under
        # FastAPI versions Prefect does not support.
        api = f"http://127.0.0.1:{port}/api"
        ran = subprocess.run(
            [sys.executable, "-c", FLOW],
            env={**env, "PREFECT_API_URL": api},
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert ran.returncode == 0 and ran.stdout.strip().endswith("42"), ran.stderr[-3000:]
        for kind in ("flow_runs", "task_runs"):
            request = urllib.request.Request(
                f"{api}/{kind}/filter",
                data=b"{}",
                method="POST",
                headers={"Content-Type": "application/json"},
            )
            with urllib.request.urlopen(request, timeout=10) as r:
                runs = json.loads(r.read())
            assert [run["state_type"] for run in runs] == ["COMPLETED"], kind
    finally:
        server.terminate()
        server.wait(timeout=30)
        log.close()

"""`prefect server start` comes up in the project's environment (the pins keep its web stack
importable), though the pipeline itself uses Prefect's ephemeral server by default."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from flows import serve
from flows.launch import answers
from flows.serve import free_port, listens, private_server, stop_private_servers
from storage.paths import data_paths

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


class Healthy(BaseHTTPRequestHandler):
    """Any process answering a health check on the port, as another Prefect server would."""

    def do_GET(self):
        self.send_response(200)
        self.end_headers()

    def log_message(self, *args):
        pass


def test_a_port_taken_before_the_server_binds_it_moves_the_server_to_another(tmp_path, monkeypatch):
    # Between `free_port` and the server's bind (seconds), another process took the port and
    # answers there: the command's flows reported to a server that was not its own, and failed
    # with "connection refused" once that one stopped.
    other = ThreadingHTTPServer(("127.0.0.1", 0), Healthy)
    threading.Thread(target=other.serve_forever, daemon=True).start()
    taken = other.server_address[1]
    ports = iter([taken])
    monkeypatch.setattr(serve, "free_port", lambda: next(ports, None) or free_port())
    try:
        api = private_server(data_paths(tmp_path / "data"))
        port = int(api.rsplit(":", 1)[1].removesuffix("/api"))
        assert port != taken
        assert answers(api) and listens(serve._private[-1], port)
    finally:
        stop_private_servers()
        other.shutdown()
    assert "is already in use" in (tmp_path / "data" / "prefect" / serve.SERVER_LOG).read_text()

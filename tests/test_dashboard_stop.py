"""`ringside dashboard` stops within seconds of a SIGTERM (a service manager's stop), leaving
neither Streamlit nor its port behind, even when Streamlit will not stop by itself."""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import psutil
import pytest

from flows.cli import servers
from flows.cli.servers import DASHBOARD_STOP_S, wait_until_serving
from flows.serve import free_port
from storage.paths import data_paths

# From SIGTERM to the command's exit: Streamlit's own stop takes about 1 s, and a Streamlit that
# takes longer is killed after DASHBOARD_STOP_S.
STOP_BOUND_S = 3.0


def test_the_dashboard_stops_within_3_s_of_sigterm_leaving_no_process_nor_port(tmp_path):
    port = free_port()
    command = ["-m", "flows.cli", "--data", str(tmp_path), "dashboard", "--port", str(port)]
    dashboard = subprocess.Popen(
        [sys.executable, *command, "--no-browser"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        assert wait_until_serving(f"http://127.0.0.1:{port}", dashboard, timeout_s=90), (
            "the dashboard never answered"
        )
        below = psutil.Process(dashboard.pid).children(recursive=True)
        assert below, "Streamlit runs as the command's child"
        dashboard.send_signal(signal.SIGTERM)
        sent = time.monotonic()
        _, err = dashboard.communicate(timeout=30)
        took = time.monotonic() - sent
    finally:
        if dashboard.poll() is None:
            os.killpg(dashboard.pid, signal.SIGKILL)
            dashboard.wait()
    assert took < STOP_BOUND_S, f"stopped {took:.2f} s after SIGTERM"
    # Streamlit logs its start on stderr too; the stop is one line, no traceback.
    assert (dashboard.returncode, err.strip().splitlines()[-1]) == (0, "dashboard stopped"), err
    assert "Traceback" not in err, err
    assert [p.pid for p in below if p.is_running() and p.status() != psutil.STATUS_ZOMBIE] == []
    # Nothing listens there (binding may still fail a while: the health check's TIME_WAIT).
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=2).close()


def test_a_streamlit_deaf_to_signals_is_killed_after_the_stop_wait(tmp_path, monkeypatch, capsys):
    # In place of Streamlit: a process that ignores SIGTERM and SIGINT, and says so in a file.
    ready = tmp_path / "ready"
    deaf = (
        "import os, signal, sys, time\n"
        "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
        "open(sys.argv[1], 'w').write(str(os.getpid()))\n"
        "time.sleep(60)\n"
    )
    monkeypatch.setattr(
        servers, "streamlit_argv", lambda *_, **__: [sys.executable, "-c", deaf, str(ready)]
    )
    sent = {}

    def stop_when_ready() -> None:
        deadline = time.monotonic() + 30
        while not (ready.exists() and ready.read_text()) and time.monotonic() < deadline:
            time.sleep(0.05)
        sent["at"] = time.monotonic()
        os.kill(os.getpid(), signal.SIGTERM)  # dashboard_command runs on the main thread

    args = argparse.Namespace(port=free_port(), host="127.0.0.1", no_browser=True)
    stopper = threading.Thread(target=stop_when_ready)
    stopper.start()
    code = servers.dashboard_command(args, data_paths(tmp_path))
    took = time.monotonic() - sent["at"]
    stopper.join()

    assert code == 0
    assert DASHBOARD_STOP_S <= took < STOP_BOUND_S, f"stopped {took:.2f} s after SIGTERM"
    assert capsys.readouterr().err.splitlines() == ["dashboard stopped"]
    assert not psutil.pid_exists(int(ready.read_text())), "the deaf server was left running"

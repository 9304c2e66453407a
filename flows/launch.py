"""How a client outside the flows starts and follows runs of ``ringside serve``: the one
interface of flows/ the dashboard uses (its reruns and picks), and the CLI's ``schedule``.

``ringside serve`` leaves ``DATA/prefect/served.json`` behind while it runs (`Served`), so the
other commands and the dashboard find its server. Prefect reads its settings when first
imported, so nothing here imports Prefect at module level.
"""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from dataclasses import asdict, dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from storage.files import write_atomic
from storage.paths import DataPaths, data_paths
from storage.records import process_alive
from tasks.errors import BadInput

PIPELINE_FLOW = "video_to_opponent"
DEPLOYMENT = "ringside"
SERVED_FILE = "served.json"
NO_SERVER = "no `ringside serve` is running on this data directory: start `ringside serve` first"


@dataclass(frozen=True)
class Served:
    """Where a running ``ringside serve`` can be reached, as ``served.json`` holds it."""

    api_url: str
    ui_url: str
    pid: int  # the `ringside serve` process, which owns the server and the runner


def served_file(paths: DataPaths) -> Path:
    return paths.prefect_home / SERVED_FILE


def write_served(paths: DataPaths, served: Served) -> None:
    write_atomic(served_file(paths), json.dumps(asdict(served)).encode())


def read_served(paths: DataPaths) -> Served | None:
    """What ``served.json`` says, or None when there is none or it cannot be read."""
    try:
        return Served(**json.loads(served_file(paths).read_text()))
    except (OSError, ValueError, TypeError):
        return None


def clear_served(paths: DataPaths, pid: int) -> None:
    """Remove ``served.json`` if process ``pid`` wrote it (another serve may have replaced it)."""
    served = read_served(paths)
    if served is not None and served.pid == pid:
        served_file(paths).unlink(missing_ok=True)


def answers(api_url: str, timeout_s: float = 2.0) -> bool:
    """Whether the Prefect API at ``api_url`` answers its health check."""
    try:
        with urllib.request.urlopen(f"{api_url}/health", timeout=timeout_s) as answer:
            return answer.status == 200
    except (urllib.error.URLError, OSError, ValueError):
        return False


def served_api(paths: DataPaths) -> str | None:
    """The API URL of the Prefect server ``ringside serve`` runs for ``paths``, if it is up.

    A ``served.json`` left by a killed serve names a dead process (or a port someone else may
    use now), so the process must be alive and the API must answer.
    """
    served = read_served(paths)
    if served is None or not process_alive(served.pid) or not answers(served.api_url):
        return None
    return served.api_url


def pipeline_parameters(
    paths: DataPaths, video_id_prefix: str, *, rerun: list[str] | None
) -> dict[str, Any]:
    """The parameters of a ``video_to_opponent`` run that reruns an ingested video as it was
    declared, with the settings of ``./ringside.toml``; ``rerun`` names stages to recompute
    whether cached or not (None: only what changed, e.g. after a pick)."""
    from flows.config import load_config
    from storage.db import connect
    from tasks.ingest.store import ingested_video

    with connect(paths.db, read_only=True) as con:
        video = ingested_video(con, video_id_prefix)
    return run_parameters(
        paths,
        [video.path],
        video.adversary,
        video.colour,
        video.notes,
        load_config().as_dict(),
        rerun=rerun,
    )


def run_parameters(
    paths: DataPaths,
    videos: list[str],
    adversary: str,
    adversary_colour: str | None,
    notes: str | None,
    config: dict,
    *,
    until: str | None = None,
    rerun: list[str] | None = None,
) -> dict[str, Any]:
    """The parameters of one ``video_to_opponent`` run, by the flow's own names, with the data
    directory and the videos as absolute paths (a run may start in another directory)."""
    return {
        "data_root": str(paths.root),  # a flow parameter: JSON, so a string
        "videos": [str(Path(v).resolve()) for v in videos],
        "adversary": adversary,
        "adversary_colour": adversary_colour,
        "notes": notes,
        "config": config,
        "until": until,
        "rerun": rerun,
    }


def run_name(parameters: dict[str, Any]) -> str:
    """A flow run name for Prefect's UI: the videos' file names and the stages rerun."""
    videos = [Path(v).name for v in parameters.get("videos") or []]
    name = " + ".join(videos[:2]) + (f" + {len(videos) - 2} more" if len(videos) > 2 else "")
    rerun = parameters.get("rerun")
    return f"{name} (rerun {', '.join(rerun)})" if rerun else name or PIPELINE_FLOW


def submit_run(paths: DataPaths, parameters: dict, *, at: datetime | None = None) -> str:
    """Create a run of the served pipeline deployment with ``parameters``, to start now or at
    ``at`` (naive: local time); returns the flow run's id. The runner of ``ringside serve``
    executes it. A ``data_root`` among ``parameters`` must name ``paths``' data directory."""
    api = served_api(paths)
    if api is None:
        raise BadInput(str(paths.root), NO_SERVER)
    root = str(paths.root)
    named = parameters.get("data_root", root)
    # A flow parameter, a string as a caller may have written it: resolved as the flow will.
    if str(data_paths(named).root) != root:
        raise ValueError(f"parameters name data_root {named}, not {root}")
    parameters = {**parameters, "data_root": root}
    if at is not None and at.tzinfo is None:
        at = at.astimezone()
    from prefect.deployments import run_deployment
    from prefect.exceptions import ObjectNotFound
    from prefect.settings import PREFECT_API_URL, temporary_settings

    # The server of this data directory, whatever this process's Prefect settings were at import.
    with temporary_settings(updates={PREFECT_API_URL: api}):
        try:
            run = run_deployment(
                f"{PIPELINE_FLOW}/{DEPLOYMENT}",
                parameters=parameters,
                scheduled_time=at,
                flow_run_name=run_name(parameters),
                timeout=0,
                as_subflow=False,
            )
        except ObjectNotFound:
            raise BadInput(api, f"has no deployment {PIPELINE_FLOW}/{DEPLOYMENT} yet") from None
    return str(run.id)


@dataclass(frozen=True)
class RunProgress:
    """Where a flow run is, as Prefect's API says."""

    state: str  # Prefect's state name: Scheduled, Late, Pending, Running, Completed, Failed...
    finished: bool  # a final state: nothing more will happen
    succeeded: bool
    message: str


def run_progress(paths: DataPaths, flow_run_id: str) -> RunProgress:
    """The state of flow run ``flow_run_id`` on the served server; ``Unreachable`` (not
    finished) while no ``ringside serve`` runs, so a poller can wait for it to come back."""
    from uuid import UUID

    api = served_api(paths)
    if api is None:
        return RunProgress("Unreachable", False, False, NO_SERVER)
    from prefect.client.orchestration import get_client
    from prefect.exceptions import ObjectNotFound
    from prefect.settings import PREFECT_API_URL, temporary_settings

    with temporary_settings(updates={PREFECT_API_URL: api}), get_client(sync_client=True) as client:
        try:
            run = client.read_flow_run(UUID(flow_run_id))
        except ObjectNotFound:
            return RunProgress("Missing", True, False, f"Prefect has no flow run {flow_run_id}")
    state = run.state
    if state is None:
        return RunProgress("Unknown", False, False, "")
    return RunProgress(state.name, state.is_final(), state.is_completed(), state.message or "")

"""Prefect task of the evaluate stage."""

from __future__ import annotations

from collections.abc import Sequence

from prefect.runtime import flow_run

from storage.keys import code_version, stage_key
from storage.paths import data_paths
from tasks.evaluate.config import EvaluateConfig
from tasks.evaluate.stage import STAGE, evaluate, load_inputs
from tasks.runner import StageResult, run_stage
from tasks.stage_task import stage_task


def evaluate_code() -> str:
    return code_version("tasks.evaluate", "tasks.dataset", "models.humanoid", "models.maaip")


def evaluate_upstream(run_key: str, compared: Sequence[str] = ()) -> dict:
    """The run evaluated and, when there are any, the other runs its tables compare it with
    (a new damage or heading run on the dataset changes the tables, so the key)."""
    upstream: dict = {"train": run_key}
    if compared:
        upstream["compared"] = sorted(compared)
    return upstream


def evaluate_key(config: EvaluateConfig, run_key: str, compared: Sequence[str] = ()) -> str:
    return stage_key(STAGE, config, evaluate_code(), evaluate_upstream(run_key, compared))


@stage_task("evaluate", "evaluate-{run_key:.12}")
def evaluate_task(
    data_root: str,
    run_key: str,
    compared: tuple[str, ...],
    config: EvaluateConfig,
    key: str,
) -> StageResult:
    """Evaluate training run ``run_key`` (bouts, tables, export, video) and commit it."""
    paths = data_paths(data_root)
    return run_stage(
        db=paths.db,
        stage=STAGE,
        video_id=run_key,
        key=key,
        config=config,
        code=evaluate_code(),
        upstream=evaluate_upstream(run_key, compared),
        run_id=str(flow_run.id),
        compute=lambda: evaluate(
            load_inputs(paths.db, paths.artifacts, run_key, compared),
            config,
            key=key,
            artifacts=paths.artifacts,
        ),
    )

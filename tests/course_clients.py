"""Course clients as their courses ship them (tests/upstream/, byte for byte), loaded for a test.

`upstream_client` checks a client's hash before it loads it, so a test never runs an edited copy.
"""

from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np

UPSTREAM = Path(__file__).resolve().parent / "upstream"
PIBOT_CLIENT = ("penguinpi_robot/pibot_client.py", "bdf62f48291e6462887b4e3bd73c30f9a0b531b01dc839130bc394e64a9b2f47")
"""qcr/PenguinPi-robot e92d66cd, software/python/client/pibot_client.py (tests/upstream/README.md)."""


def upstream_client(client: tuple[str, str] = PIBOT_CLIENT) -> ModuleType:
    """A course's client module (its path under tests/upstream/, its sha256), loaded afresh."""
    path = UPSTREAM / client[0]
    assert hashlib.sha256(path.read_bytes()).hexdigest() == client[1], f"{path} is not upstream's: do not edit it"
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class NoRobotCamera:
    """Stands in for pibot_client's robot camera stream, whose first frame PiBot's constructor waits
    for: for tests of the localiser, where the robot's camera is not the subject and may not run."""

    def __init__(self, _url: str) -> None:
        self.frame = np.zeros((1, 1, 3), np.uint8)


def localiser_client(host: str, port: int) -> object:
    """``PiBot(ip, port, localiser_ip=host, localiser_port=port)`` of the upstream pibot_client, built by
    its own constructor, without a robot camera (`NoRobotCamera`); its robot endpoint leads nowhere."""
    module = upstream_client()
    module.VideoStreamWidget = NoRobotCamera
    return module.PiBot("127.0.0.1", 9, localiser_ip=host, localiser_port=port)

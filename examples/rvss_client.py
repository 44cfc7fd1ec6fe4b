"""The RVSS workshop's robot client, imported unchanged from the team's own checkout.

The workshop (rvss-australia/RVSS_Need4Speed) drives the robot with the PenguinPi's upstream
client: its scripts put ``PenguinPi-robot/software/python/client/`` (a git submodule of the
workshop) on ``sys.path`` and do ``from pibot_client import PiBot``. These examples do the same
with the file a team already has, so what runs here is what runs on their robot: ``PiBot(ip,
port)``, ``getImage()`` (OpenCV's VideoCapture on ``/camera/get``, the web API's MJPEG stream) and
``setVelocity(left, right)`` (``/robot/set/velocity?value=L,R``, PenguinPi demand units, about
5.3 mm/s each). Nothing of that client is copied into this repository.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

CLIENT_IN_WORKSHOP = Path("PenguinPi-robot/software/python/client/pibot_client.py")
"""Where the workshop's scripts find it (``scripts/collect.py``: ``../PenguinPi-robot/software/python/client/``)."""
CLIENT_IN_PENGUINPI = Path("software/python/client/pibot_client.py")
"""Where it is in a checkout of qcr/PenguinPi-robot itself."""


class ClientNotFound(Exception):
    """No pibot_client.py where the user said: one line that says where we looked."""


def client_file(where: str | Path) -> Path:
    """``pibot_client.py`` given the file itself, a workshop checkout or a PenguinPi-robot checkout."""
    path = Path(where).expanduser()
    if path.is_file():
        return path
    tried = [path / CLIENT_IN_WORKSHOP, path / CLIENT_IN_PENGUINPI, path / "pibot_client.py"]
    for candidate in tried:
        if candidate.is_file():
            return candidate
    hint = " (an empty PenguinPi-robot folder: run `git submodule update --init` in the workshop)" \
        if (path / "PenguinPi-robot").is_dir() else ""
    raise ClientNotFound(f"--client {where}: no pibot_client.py there; looked for "
                         + ", ".join(str(t) for t in tried) + hint)


def load_client(where: str | Path) -> types.ModuleType:
    """Import the team's ``pibot_client`` module, unchanged, as the workshop's scripts do."""
    path = client_file(where)
    spec = importlib.util.spec_from_file_location("pibot_client", path)
    if spec is None or spec.loader is None:
        raise ClientNotFound(f"--client {where}: {path} cannot be imported as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules["pibot_client"] = module  # as `from pibot_client import PiBot` would leave it
    spec.loader.exec_module(module)
    if not hasattr(module, "PiBot"):
        raise ClientNotFound(f"--client {where}: {path} has no class PiBot (not the PenguinPi's pibot_client)")
    return module

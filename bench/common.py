"""What the benchmarks share: a robot config of their own, on a free loopback port."""

from __future__ import annotations

import socket
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def robot_config(folder: Path, name: str, extra_toml: str = "") -> Path:
    """``folder/<name>.toml``: the simulated robot under its own name, run dir and Zenoh port."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    path = folder / f"{name}.toml"
    path.write_text(f'extends = "{ROOT / "deploy/robots/sim.toml"}"\nname = "{name}"\nrun_dir = "{folder}/run"\n'
                    f'{extra_toml}\n[zenoh]\nlisten = ["{endpoint}"]\nconnect = ["{endpoint}"]\n')
    return path


def read_state(shared) -> dict:  # type: ignore[no-untyped-def]
    """hwbridge's cycle state, read again until no write is in progress (`Shared.read_state`)."""
    while (state := shared.read_state()) is None:
        time.sleep(0.001)
    return state

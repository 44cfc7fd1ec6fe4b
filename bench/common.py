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


def cmdline(pid: int) -> list[str]:
    """A process's command line, as words ([] if it is gone). A service the fork server started
    has set its title as one string with spaces between the words."""
    try:
        return (Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().split())
    except OSError:
        return []


def parent_of(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError):
        return 0


def robot_processes(config: Path, runtime_dir: Path | None = None) -> dict[str, list[int]]:
    """Name -> pids of every process of a robot run by `icefloe up` with this config: the launcher,
    each service (by ``-m icefloe.services.<name>``), the router, hwbridge's cycle (its child), and
    the fork server (by its socket in ``runtime_dir``)."""
    out: dict[str, list[int]] = {}
    socket = f"{runtime_dir}/forkserver.sock" if runtime_dir else None
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        words = cmdline(int(entry.name))
        if "-m" not in words:
            continue
        module = words[words.index("-m") + 1]
        if str(config) in words:
            name = "launcher" if module == "icefloe.cli" else module.rsplit(".", 1)[-1]
        elif socket and module == "icefloe.forkserver" and socket in words:
            name = "forkserver"
        elif module == "icefloe.services.hwbridge.rt":
            name = "hwbridge (cycle)"
        else:
            continue
        out.setdefault(name, []).append(int(entry.name))
    bridges = set(out.get("hwbridge", []))
    cycles = [p for p in out.pop("hwbridge (cycle)", []) if parent_of(p) in bridges]  # this robot's only
    if cycles:
        out["hwbridge (cycle)"] = cycles
    return out

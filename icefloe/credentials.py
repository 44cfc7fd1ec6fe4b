"""Per-robot credentials: who may drive which robot.

A robot with ``[zenoh] access_control = true`` accepts commands only from its own
Zenoh user. `make` writes that user and a random password to the robot's
credentials file (mode 0600; never committed, never logged). The same small file
is what a student's laptop uses to drive that robot::

    # icefloe credentials: keep private
    robot = "penguin1"
    user = "penguin1"
    password = "..."
    connect = ["tcp/192.168.1.23:7447"]

Without credentials, icefloe connects to such a robot as the public read-only
user `guest` (password `guest`): it may read everything and command nothing.
Zenoh's user/password authentication has no anonymous mode, so a raw Zenoh
session with no user at all is refused by a robot with access control.
"""

from __future__ import annotations

import os
import secrets
import tomllib
from pathlib import Path

import msgspec

from .errors import ConfigError

GUEST_USER = "guest"
GUEST_PASSWORD = "guest"
TA_ROBOT = "*"
"""The ``robot`` of the lab's TA account in its credentials file: no robot of its own; it may stop
every robot of the lab and use their simulators' handles (deploy/zenoh/acl/ta.json5, docs/lab.md)."""


class Credentials(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    robot: str
    user: str
    password: str
    connect: list[str] = []


def read(path: str | os.PathLike[str]) -> Credentials:
    p = Path(path).expanduser()
    try:
        data = tomllib.loads(p.read_text())
        creds = msgspec.convert(data, Credentials)
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such credentials file") from None
    except (OSError, tomllib.TOMLDecodeError, msgspec.ValidationError) as exc:
        raise ConfigError(f"{p}: bad credentials file: {exc}") from None
    if not creds.user or not creds.password or ":" in creds.user:
        raise ConfigError(f"{p}: user and password must be set (and the user may not contain ':')")
    return creds


def make(path: str | os.PathLike[str], robot: str, connect: list[str] | None = None,
         *, replace: bool = False) -> tuple[Path, bool]:
    """Write new credentials for ``robot`` unless the file exists; returns (path, created)."""
    p = Path(path).expanduser()
    if p.exists() and not replace:
        return p, False
    p.parent.mkdir(parents=True, exist_ok=True)
    password = secrets.token_urlsafe(18)
    lines = [
        "# icefloe credentials: whoever has this file may drive the robot. Keep it private.",
        f'robot = "{robot}"',
        f'user = "{robot}"',
        f'password = "{password}"',
        f"connect = [{', '.join(f'{e!r}'.replace(chr(39), chr(34)) for e in connect or [])}]",
    ]
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write("\n".join(lines) + "\n")
    return p, True

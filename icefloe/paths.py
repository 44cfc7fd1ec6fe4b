"""Where icefloe finds its files: robot configs, worlds and templates, by name or by path.

A *name* (``sim``, ``penguin1``, ``lab``) is looked up in these folders, first match wins::

    $ICEFLOE_CONFIG_DIR, else $XDG_CONFIG_HOME/icefloe (~/.config/icefloe)   your own
    /etc/icefloe                                                            the machine's (a lab's)
    the installed package's data (deploy/ in a checkout)                     shipped with icefloe

each with a ``robots/`` and a ``worlds/`` subfolder, so ``~/.config/icefloe/robots/sim.toml``
overrides the shipped simulated robot. A *path* (it has a ``/``, or ends in ``.toml``) is only
ever that path, relative to the current folder: the robot name ``sim`` never means the ``sim/``
folder of a checkout.

The shipped files live in ``deploy/`` of the repository, which installs as the package
``icefloe.share`` (see pyproject.toml); they are found through `importlib.resources`, so a
wheel installed anywhere has them.
"""

from __future__ import annotations

import os
import re
from importlib import resources
from pathlib import Path

from .errors import ConfigError

NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
"""What a robot or world name looks like (no path separators)."""


def packaged(*parts: str) -> Path:
    """A file shipped with icefloe, e.g. ``packaged("zenoh", "acl", "owner.json5")``."""
    return Path(str(resources.files("icefloe.share").joinpath(*parts)))


def user_dir() -> Path:
    """The user's own icefloe folder (``$ICEFLOE_CONFIG_DIR``, else ``~/.config/icefloe``)."""
    if explicit := os.environ.get("ICEFLOE_CONFIG_DIR"):
        return Path(explicit).expanduser()
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(base) / "icefloe"


SYSTEM_DIR = Path("/etc/icefloe")


def search_dirs(kind: str) -> list[Path]:
    """The folders a name of this kind (``robots``, ``worlds``) is looked up in, first match wins."""
    return [user_dir() / kind, SYSTEM_DIR / kind, packaged(kind)]


def is_path(text: str) -> bool:
    """A path, not a name: it has a folder separator, starts with ``~`` or ends in ``.toml``."""
    return "/" in text or os.sep in text or text.startswith("~") or text.endswith(".toml")


def known(kind: str) -> list[str]:
    """Every name of this kind that `find` would resolve."""
    return sorted({p.stem for d in search_dirs(kind) if d.is_dir() for p in d.glob("*.toml")})


def find(kind: str, name_or_path: str | os.PathLike[str], what: str, *, skip: Path | None = None) -> Path:
    """The file a name or a path means; `ConfigError` naming where it looked if there is none.

    ``kind`` is the subfolder (``robots``, ``worlds``); ``what`` names the thing in messages
    ("robot config", "world file"). ``skip``: a file a name must not resolve to (your own
    ``sim.toml`` that extends ``"sim"`` means the next one, the shipped one).
    """
    text = os.fspath(name_or_path)
    if is_path(text):
        path = Path(text).expanduser()
        if not path.exists():
            hint = ""
            if text.endswith(".toml") and "/" not in text and Path(text).stem in known(kind):
                hint = f" (for the shipped {what} {Path(text).stem!r}, give its name without .toml)"
            raise ConfigError(f"{text}: no such {what}{hint}")
        if path.is_dir():
            raise ConfigError(f"{text}: is a folder, not a {what} (give a .toml file or a name)")
        return path
    if not NAME.fullmatch(text):
        raise ConfigError(f"{text!r}: not a {what} name or a path to a .toml file")
    for folder in search_dirs(kind):
        path = folder / f"{text}.toml"
        if path.is_file() and not (skip and path.resolve() == skip.resolve()):
            return path
    names = ", ".join(known(kind)) or "none"
    raise ConfigError(f"{text}: no {what} of that name (known: {names}; "
                      f"your own go in {user_dir() / kind}/<name>.toml, or give a path)")

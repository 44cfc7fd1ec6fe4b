"""The world map: where the ArUco landmarks are.

A world file is TOML in ``deploy/worlds/`` with one ``[[marker]]`` table per
marker::

    name = "lab"              # optional; defaults to the file name

    [[marker]]
    id = 0                    # ArUco id in the robot's dictionary (camera.dictionary)
    x = 2.0                   # centre of the marker in the world frame, m
    y = -1.2
    z = 0.10                  # height of the centre above the floor, m
    size = 0.15               # side of the black square, m (the white border is extra)
    yaw = 3.14159             # direction the printed face points, rad, CCW from +x

The simulator renders these markers, the camera service takes each marker's
size from here (to measure its distance), and the localizer uses the positions.

World frame: x and y on the floor, z up, angles counter-clockwise from +x.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import ConfigError

WORLDS_DIR = Path(__file__).resolve().parent.parent / "deploy" / "worlds"


@dataclass(frozen=True)
class Marker:
    """One ArUco marker fixed in the world."""

    id: int
    x: float
    """Centre, world frame, m."""
    y: float
    """Centre, world frame, m."""
    z: float
    """Height of the marker's centre above the floor, m."""
    size: float
    """Side of the black square, m."""
    yaw: float
    """Direction the marker's face points, rad, counter-clockwise from +x."""


@dataclass(frozen=True)
class WorldMap:
    """A named set of markers with unique ids."""

    name: str
    markers: tuple[Marker, ...]

    def marker(self, id: int) -> Marker | None:
        """The marker with this ArUco id, or None if the world has none."""
        for m in self.markers:
            if m.id == id:
                return m
        return None


_FIELDS = {"id": int, "x": float, "y": float, "z": float, "size": float, "yaw": float}


def _marker(raw: Any, where: str) -> Marker:
    """One ``[[marker]]`` table → Marker; `ConfigError` names the table and the key."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a table")
    unknown = sorted(set(raw) - set(_FIELDS))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(_FIELDS)})")
    values: dict[str, Any] = {}
    for key, kind in _FIELDS.items():
        if key not in raw:
            raise ConfigError(f"{where}: missing key {key!r}")
        value = raw[key]
        # TOML gives int or float; bool is an int in Python and never what was meant.
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}.{key}: expected a number, got {value!r}")
        if kind is int:
            if not isinstance(value, int) or value < 0:
                raise ConfigError(f"{where}.{key}: expected a whole number >= 0, got {value!r}")
        elif not math.isfinite(value):
            raise ConfigError(f"{where}.{key}: expected a finite number, got {value!r}")
        values[key] = kind(value)
    if values["size"] <= 0:
        raise ConfigError(f"{where}.size: must be > 0 m, got {values['size']}")
    return Marker(**values)


def parse_world(data: dict[str, Any], source: str) -> WorldMap:
    """A WorldMap from a TOML-shaped dict; ``source`` names the file in errors."""
    unknown = sorted(set(data) - {"name", "marker"})
    if unknown:
        raise ConfigError(f"{source}: unknown key {unknown[0]!r} (allowed: name, [[marker]])")
    name = data.get("name", Path(source).stem)
    if not isinstance(name, str):
        raise ConfigError(f"{source}: name: expected a string, got {name!r}")
    raw_markers = data.get("marker", [])
    if not isinstance(raw_markers, list):
        raise ConfigError(f"{source}: marker: expected [[marker]] tables")
    markers: list[Marker] = []
    first_index: dict[int, int] = {}
    for i, raw in enumerate(raw_markers):
        marker = _marker(raw, f"{source}: marker[{i}]")
        if marker.id in first_index:
            raise ConfigError(
                f"{source}: marker[{i}].id: id {marker.id} is already used by marker[{first_index[marker.id]}]"
            )
        first_index[marker.id] = i
        markers.append(marker)
    return WorldMap(name=name, markers=tuple(markers))


def load_world(name_or_path: str) -> WorldMap:
    """Load a world file: a bare name (``"lab"`` or ``"lab.toml"``) is looked up in deploy/worlds/."""
    path = Path(name_or_path)
    if len(path.parts) == 1 and not path.exists():
        path = WORLDS_DIR / (name_or_path if path.suffix else f"{name_or_path}.toml")
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such world file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return parse_world(data, str(path))

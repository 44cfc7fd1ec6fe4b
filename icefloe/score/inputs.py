"""What `icefloe score` reads: landmark maps and pose trajectories, from files, recordings and bus samples.

Landmark maps (``MAP``), told apart by their content:

* ECE4078's ``slam.txt``: JSON ``{"taglist": [id, ...], "map": [[x, ...], [y, ...]], ...}`` (the map
  2 x N, column i the marker taglist[i]; other fields, such as ``covariance``, are not read);
* a world file (``.toml``, `icefloe.worldmap`): the map the localizer uses;
* icefloe's landmark map (`LandmarkMap`), as JSON or MessagePack: ``{"stamp": ns, "landmarks":
  [{"id": 3, "x": 1.2, "y": -0.4, "covariance": [4 numbers, 2x2 row-major, m^2]}, ...]}``
  (``stamp`` and ``covariance`` optional) -- the same map as a bus message or in a recording.

True maps (``--world``): a world file (`icefloe.worldmap`, a name like ``lab`` or a .toml path), or
ECE4078's true map, JSON ``{"aruco1_0": {"x": ..., "y": ...}, ...}`` (keys not ``aruco...`` skipped).

Trajectories: a CSV file with a header row naming the columns ``x``, ``y``, ``theta`` (m, m, rad)
and the time as ``t`` (s) or ``stamp`` or ``log_time`` (ns, as `icefloe export` writes them); or
any message with ``x``, ``y``, ``theta`` and ``stamp`` (ns) on a key (``loc/pose``, ``odom/pose``,
``sim/truth``, an external localizer's), live or in a recording (where a message without a stamp
takes the time it was recorded).
"""

from __future__ import annotations

import csv
import json
import logging
import math
from pathlib import Path
from typing import Any

import msgspec

from ..bag import Bag
from ..bag.reader import MAGIC, Entry
from ..bag.samples import entries_on, find_key, plain
from ..errors import BadRecording, ConfigError, IcefloeError
from ..schemas.messages import LandmarkMap
from ..worldmap import load_world
from .maths import Trajectory

Points = dict[int, tuple[float, float]]
log = logging.getLogger("icefloe.score")
MAX_FILE = 64_000_000
"""Bytes of a map or CSV file read at most (a map of thousands of landmarks is far smaller)."""


class BadInput(IcefloeError):
    """A map or trajectory that cannot be scored; the message names the file or key and what is wrong."""


class SlamTxt(msgspec.Struct, frozen=True):
    """ECE4078's ``slam.txt``."""

    taglist: list[int]
    map: list[list[float]]


# --------------------------------------------------------------------------- maps


def checked(points: list[tuple[int, float, float]], source: str) -> Points:
    """Id -> (x, y); BadInput naming ``source`` for a number that is not finite or an id given twice."""
    out: Points = {}
    for id_, x, y in points:
        if not (math.isfinite(x) and math.isfinite(y)):
            raise BadInput(f"{source}: marker {id_} is at ({x}, {y}): not a finite position")
        if id_ in out:
            raise BadInput(f"{source}: marker {id_} appears twice")
        out[id_] = (x, y)
    return out


def not_finite(landmarks: Any, source: str) -> None:
    """BadInput naming the marker whose position is NaN or infinite (the schema refuses them too)."""
    for p in landmarks if isinstance(landmarks, list) else ():
        if isinstance(p, dict) and all(isinstance(p.get(k), int | float) for k in ("x", "y")):
            checked([(p.get("id"), float(p["x"]), float(p["y"]))], source)


def map_points(data: Any, source: str) -> Points:
    """The landmarks of a decoded map (a slam.txt or a `LandmarkMap`)."""
    try:
        if isinstance(data, dict) and "taglist" in data:
            slam = msgspec.convert(data, SlamTxt)
            if len(slam.map) != 2 or any(len(row) != len(slam.taglist) for row in slam.map):
                shape = f"{len(slam.map)} x {len(slam.map[0]) if slam.map else 0}"
                raise BadInput(f"{source}: `map` must be 2 x {len(slam.taglist)} (a row of x, a row of y, one "
                               f"column per tag of `taglist`), not {shape}")
            return checked(list(zip(slam.taglist, *slam.map, strict=True)), source)
        if isinstance(data, dict) and "landmarks" in data:
            not_finite(data["landmarks"], source)  # before the schema, which would not name the marker
            lm = msgspec.convert(data, LandmarkMap)
            return checked([(p.id, p.x, p.y) for p in lm.landmarks], source)
    except msgspec.ValidationError as exc:
        raise BadInput(f"{source}: {exc}") from None
    what = f"a map with keys {', '.join(map(str, data))}" if isinstance(data, dict) else type(data).__name__
    raise BadInput(f"{source}: not a landmark map ({what}): expected ECE4078's slam.txt (taglist, map) or "
                   "icefloe's (landmarks: [{id, x, y}])")


def read_bytes(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_FILE + 1)
    except OSError as exc:
        raise BadInput(f"{path}: {exc.strerror or exc}") from None
    if len(data) > MAX_FILE:
        raise BadInput(f"{path}: larger than {MAX_FILE // 1_000_000} MB: not a map")
    return data


def decode_file(path: Path, data: bytes) -> Any:
    """A JSON or MessagePack file as plain data."""
    if data.lstrip()[:1] in (b"{", b"["):
        try:
            return msgspec.json.decode(data)
        except msgspec.DecodeError as exc:
            error = exc
        try:  # Python's json writes a NaN as NaN, which JSON has not: read it, to name the marker
            return json.loads(data)
        except (ValueError, RecursionError):
            raise BadInput(f"{path}: not valid JSON: {error}") from None
    try:
        return msgspec.msgpack.decode(data)
    except msgspec.DecodeError:
        raise BadInput(f"{path}: neither JSON nor MessagePack (it starts with {data[:8]!r})") from None


def is_recording(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def looks_like_map(data: Any) -> bool:
    """A slam.txt or a `LandmarkMap` (its landmarks with a position, unlike the camera's)?"""
    if not isinstance(data, dict):
        return False
    marks = data.get("landmarks")
    return "taglist" in data or (isinstance(marks, list) and all(isinstance(p, dict) and "x" in p for p in marks))


def decodes(entry: Entry) -> Any:
    """A message as plain data, or None if it does not decode (a bad sample on another key)."""
    try:
        return plain(entry)
    except BadRecording:
        return None


def last_map_in(path: Path, key: str | None) -> tuple[Points, str]:
    """The last landmark map of a recording, on ``key`` or on the one key that carries maps; a
    message that is no map (a bad sample) is passed over."""
    bag = Bag([path])
    wanted = find_key(bag, key) if key else None
    maps: dict[str, Any] = {}
    others = 0
    for entry in bag.entries() if wanted is None else entries_on(bag, wanted):
        # A map is a raw channel while the key table has no map message, and a typed one once it has.
        kind = entry.channel.type
        if wanted is None and not (entry.channel.form == "raw" or (kind is not None and "Map" in kind.__name__)):
            continue
        data = decodes(entry)
        if looks_like_map(data):
            maps[entry.channel.key] = data
        else:
            others += 1
    if wanted is not None and wanted not in maps:
        raise BadInput(f"{path}: no landmark map on {wanted} ({others} messages, none a map)")
    if len(maps) != 1:
        what = f"maps on several keys ({', '.join(sorted(maps))})" if maps else "no landmark map"
        raise BadInput(f"{path}: {what}: --key KEY names the key")
    (full, data), = maps.items()
    return map_points(data, f"{path}: {full}"), full


def read_map(source: str, key: str | None = None) -> tuple[Points, str]:
    """A landmark map from a file (slam.txt, icefloe's JSON/MessagePack, or a recording, its last
    map on ``key``), and a description of where it came from."""
    path = Path(source).expanduser()
    if is_recording(path):
        points, full = last_map_in(path, key)
        return points, f"{path} ({full}, the last map)"
    if path.suffix == ".toml":  # a world file: the map the localizer uses
        return world_points(str(path))
    return map_points(decode_file(path, read_bytes(path)), str(path)), str(path)


def true_map(world: str) -> tuple[Points, str]:
    """The true markers: a world file (name or .toml path) or ECE4078's true map (a JSON file)."""
    path = Path(world).expanduser()
    if path.suffix != ".toml" and path.is_file():
        data = decode_file(path, read_bytes(path))
        if not isinstance(data, dict):
            raise BadInput(f"{path}: not a true map (expected {{\"aruco1_0\": {{\"x\": ..., \"y\": ...}}, ...}})")
        points = []
        for name, value in data.items():
            if not name.startswith("aruco"):
                continue  # ECE4078's true maps list the fruit too
            try:
                id_ = int(name.removeprefix("aruco").split("_")[0])
                points.append((id_, float(value["x"]), float(value["y"])))
            except (ValueError, TypeError, KeyError):
                raise BadInput(f"{path}: {name}: expected {{\"x\": number, \"y\": number}} and a name "
                               "arucoN_0") from None
        if not points:
            raise BadInput(f"{path}: no arucoN_0 markers in this true map")
        return checked(points, str(path)), str(path)
    return world_points(world)


def world_points(world: str) -> tuple[Points, str]:
    """The markers of a world file (`icefloe.worldmap`: a name or a .toml path)."""
    try:
        w = load_world(world)
    except ConfigError as exc:
        raise BadInput(str(exc)) from None
    if not w.markers:
        raise BadInput(f"world {w.name}: it has no markers")
    return {m.id: (m.x, m.y) for m in w.markers}, f"world {w.name}"


# --------------------------------------------------------------------------- trajectories

TIME_COLUMNS = {"t": 1.0, "stamp": 1e-9, "log_time": 1e-9}
"""CSV time columns and their unit in seconds, in the order they are looked for."""


def pose_row(data: Any, log_time: int, source: str) -> tuple[float, float, float, float]:
    """(t s, x, y, theta) of a pose message (any message with x, y, theta and a stamp in ns)."""
    if not isinstance(data, dict):
        raise BadInput(f"{source}: a message is {type(data).__name__}, not a pose (x, y, theta, stamp)")
    try:
        x, y, theta = (float(data[f]) for f in ("x", "y", "theta"))
        stamp = int(data.get("stamp") or log_time)
    except KeyError as exc:
        raise BadInput(f"{source}: a message has no {exc.args[0]!r}: not a pose (x, y, theta, stamp)") from None
    except (TypeError, ValueError) as exc:
        raise BadInput(f"{source}: a pose field is not a number: {exc}") from None
    return stamp * 1e-9, x, y, theta


def trajectory_of(rows: list[tuple[float, float, float, float]], source: str) -> Trajectory:
    """A trajectory from rows, refusing numbers that are not finite (naming the row) and an empty one."""
    for n, row in enumerate(rows):
        if not all(math.isfinite(v) for v in row):
            raise BadInput(f"{source}: pose {n + 1} is {row}: not finite")
    if not rows:
        raise BadInput(f"{source}: no poses")
    return Trajectory.of(rows)


def read_csv(path: Path) -> Trajectory:
    text = read_bytes(path).decode("utf-8", errors="replace")
    reader = csv.reader(text.splitlines())
    header = [h.strip() for h in next(reader, [])]
    time_col = next((c for c in TIME_COLUMNS if c in header), None)
    missing = [c for c in ("x", "y", "theta") if c not in header]
    if time_col is None or missing:
        need = ", ".join(missing + ([] if time_col else ["t (s) or stamp (ns)"]))
        raise BadInput(f"{path}: the header row has no column {need} (it has: {', '.join(header) or 'nothing'})")
    cols = [header.index(c) for c in (time_col, "x", "y", "theta")]
    rows = []
    for line, cells in enumerate(reader, start=2):
        if not cells:
            continue
        try:
            t, x, y, theta = (float(cells[c]) for c in cols)
        except (ValueError, IndexError):
            raise BadInput(f"{path}: line {line}: expected numbers in {time_col}, x, y, theta: {cells}") from None
        rows.append((t * TIME_COLUMNS[time_col], x, y, theta))
    return trajectory_of(rows, str(path))


def read_trajectory(source: str, key: str) -> tuple[Trajectory, str]:
    """A trajectory from a CSV file or a recording (its messages on ``key``), and where it came from."""
    path = Path(source).expanduser()
    if is_recording(path):
        bag = Bag([path])
        full = find_key(bag, key)
        where = f"{path}: {full}"
        rows, skipped, first = [], 0, ""
        for entry in entries_on(bag, full):
            try:
                rows.append(pose_row(plain(entry), entry.log_time, where))
            except (BadInput, BadRecording) as exc:  # a bad message in a run (a student's) spoils not the rest
                skipped += 1
                first = first or (str(exc) if isinstance(exc, BadInput) else f"{path}: {exc}")
        if skipped:
            log.warning("%s (%d message%s skipped)", first, skipped, "s" if skipped > 1 else "")
        return trajectory_of(rows, where), where
    if not path.is_file():
        raise BadInput(f"{path}: no such file")
    return read_csv(path), str(path)

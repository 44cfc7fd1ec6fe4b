"""A recording as CSV files, one per key, for homework that starts from a file.

    out/odom_pose.csv          log_time,stamp,x,y,theta,v,w
    out/camera_landmarks.csv   log_time,stamp,id,range,bearing,corners,position,rotation   (one row per marker)
    out/camera_image.csv       log_time,stamp,width,height,data,format   (data: the JPEG's file name)
    out/camera_image/<stamp>.jpg

* ``log_time``: when the recorder received the message, ns since the epoch; then the message's
  fields in the order of ``schemas/messages.py`` (units there).
* A list of numbers (``covariance``, ``corners``) is one cell of JSON: ``json.loads`` it.
* A list of records (the markers of a ``camera/landmarks`` frame) gives one row per record, the
  message's other fields repeated; a frame with none gives one row with those cells empty.
* Images are written as files next to the CSV; other bytes (``oled/frame``) as base64.
* A channel of raw bytes (a key outside the key table, a payload that did not decode) goes to
  ``<key>.raw.csv``: log_time, encoding, the payload in base64.
* With several robots in the file, each file name starts with the robot's name.
"""

from __future__ import annotations

import base64
import csv
import json
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import msgspec

from ..schemas import keys
from ..schemas import messages as m
from .channels import ChannelPlan, decode
from .reader import Bag


def record_list(annotation: Any) -> type[msgspec.Struct] | None:
    """The Struct of a ``list[SomeStruct]`` field, else None."""
    if typing.get_origin(annotation) is list:
        (inner,) = typing.get_args(annotation)
        if isinstance(inner, type) and issubclass(inner, msgspec.Struct):
            return inner
    return None


def header(type_: type[msgspec.Struct]) -> list[str]:
    """CSV columns of a message: ``log_time``, then its fields (a list of records: the record's fields)."""
    out = ["log_time"]
    for f in msgspec.structs.fields(type_):
        inner = record_list(f.type)
        out += [g.name for g in msgspec.structs.fields(inner)] if inner else [f.name]
    return out


def cell(value: Any) -> Any:
    if isinstance(value, list):
        return json.dumps(value)
    if isinstance(value, bytes):
        return base64.b64encode(value).decode()
    return value


def rows(message: m.Message, log_time: int, instead: dict[str, Any] | None = None) -> Iterator[list[Any]]:
    """The CSV rows of one message (several when it holds a list of records); ``instead``: cells
    to write in place of some fields' values."""
    row: list[Any] = [log_time]
    exploded: list[list[Any]] | None = None
    width = 0
    for f in msgspec.structs.fields(type(message)):
        if instead and f.name in instead:
            row.append(instead[f.name])
            continue
        value = getattr(message, f.name)
        inner = record_list(f.type)
        if inner is None:
            row.append(cell(value))
            continue
        names = [g.name for g in msgspec.structs.fields(inner)]
        width = len(names)
        exploded = [[cell(getattr(item, n)) for n in names] for item in value]
        row.append(None)  # a placeholder where the record's columns go
    if exploded is None:
        yield row
        return
    at = row.index(None)
    for part in exploded or [[""] * width]:
        yield row[:at] + part + row[at + 1:]


class CsvFiles:
    """The open CSV files of an export, one per (key, form)."""

    def __init__(self, directory: Path, several_robots: bool) -> None:
        self.directory = directory
        self.several_robots = several_robots
        self.written: dict[Path, int] = {}
        self._open: dict[tuple[str, str], tuple[IO[str], Any, Path]] = {}

    def name(self, key: str) -> str:
        try:
            robot, name = keys.split(key)
            base = f"{robot}_{name}" if self.several_robots else name
        except ValueError:
            base = key
        return base.replace("/", "_")

    def writer(self, channel: ChannelPlan) -> tuple[Any, Path]:
        found = self._open.get((channel.key, channel.form))
        if found is None:
            suffix = ".raw.csv" if channel.form == "raw" else ".csv"
            path = self.directory / f"{self.name(channel.key)}{suffix}"
            f = open(path, "w", newline="")  # noqa: SIM115 - closed in close()
            w = csv.writer(f)
            w.writerow(["log_time", "encoding", "payload_base64"] if channel.form == "raw"
                       else header(channel.type))  # type: ignore[arg-type]
            found = self._open[(channel.key, channel.form)] = (f, w, path)
            self.written[path] = 0
        return found[1], found[2]

    def close(self) -> None:
        for f, _, _ in self._open.values():
            f.close()


def to_csv(bag: Bag, directory: str | Path) -> dict[Path, int]:
    """Write ``bag`` as CSV files into ``directory``; returns each file with its number of rows."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    robots = {keys.split(c.key)[0] for c in bag.channels() if c.key.startswith(keys.PREFIX + "/")}
    files = CsvFiles(out, len(robots) > 1)
    try:
        for entry in bag.entries():
            channel = entry.channel
            if channel.refused:
                continue
            w, path = files.writer(channel)
            if channel.form == "raw":
                w.writerow([entry.log_time, channel.encoding, base64.b64encode(entry.data).decode()])
                files.written[path] += 1
                continue
            message = decode(channel, entry.data)
            if isinstance(message, m.Image):
                images = out / files.name(channel.key)
                images.mkdir(exist_ok=True)
                image = images / f"{message.stamp}.{message.format}"
                image.write_bytes(message.data)
                w.writerow(next(rows(message, entry.log_time, {"data": f"{images.name}/{image.name}"})))
                files.written[path] += 1
                continue
            assert message is not None
            for row in rows(message, entry.log_time):
                w.writerow(row)
                files.written[path] += 1
    finally:
        files.close()
    return files.written

"""Reading recordings: the messages of one or more MCAP files, in order, as `Entry`s.

A whole file (it ends with MCAP's magic and has a summary) is read through the `mcap` library's
indexed reader, in log-time order. A file without a summary is read from the start, in file order.
A truncated file (the recorder was killed: no summary, the last chunk cut short) is read the same
way up to its last whole chunk, with one warning naming the file and what was kept; the chunks are
checked against their CRCs, so a half-written one is never taken for data.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Header, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.summary import Summary

from ..errors import BadRecording, IcefloeError
from .channels import ChannelPlan, plan

if TYPE_CHECKING:
    from .ros2 import Ros2Replay

MAGIC = b"\x89MCAP0\r\n"
log = logging.getLogger("icefloe.bag")


@dataclass(frozen=True)
class Entry:
    """One message of a recording."""

    channel: ChannelPlan
    log_time: int
    """When the recorder received it, ns since the epoch."""
    publish_time: int
    """The message's own ``stamp`` where it has one (else the log time), ns."""
    data: bytes
    """As stored in the file (JSON for typed channels)."""


@dataclass
class FileState:
    """What reading a file found out about it."""

    path: Path
    size: int
    whole: bool = True
    """False: truncated; read up to its last whole chunk."""
    compression: str = ""
    profile: str = ""
    """The MCAP header's profile (``ros2``: a ROS 2 recording)."""
    chunks: int = 0
    metadata: dict[str, dict[str, str]] | None = None


class Bag:
    """A recording: one or more MCAP files (a split recording), read in the order given.

    ``robot``: replay under this robot name (see `channels.bus_key`). ``ros2``: which ROS 2 topics
    (``ros2msg`` schemas, CDR) go back onto which icefloe keys; without it they are raw bytes. A
    rosbag2 folder (``metadata.yaml`` beside its ``.mcap`` files) stands for its files, in order.
    """

    def __init__(self, paths: Sequence[str | os.PathLike[str]], robot: str | None = None,
                 ros2: Ros2Replay | None = None) -> None:
        if not paths:
            raise BadRecording("no recording given")
        if robot is not None and (not robot or any(c in robot for c in "/*$#? ")):
            # The name goes into the keys replay publishes on: a wildcard would reach every robot.
            raise IcefloeError(f"--robot {robot!r} is not a robot name (one word, no wildcards)")
        self.files = [FileState(p, 0) for p in _files(paths)]
        self.robot = robot
        self.ros2 = ros2
        self._plans: dict[tuple[Path, int], ChannelPlan] = {}
        self._warned: set[Path] = set()
        for state in self.files:
            state.size, state.whole, state.profile = _check(state.path)

    # ------------------------------------------------------------------ reading

    def entries(self) -> Iterator[Entry]:
        """Every message, file after file, each file in log-time order (file order if it has no summary)."""
        for state in self.files:
            with open(state.path, "rb") as f:
                for schema, channel, message in self._records(state, f):
                    yield Entry(self._plan(state.path, schema, channel), message.log_time, message.publish_time,
                                message.data)

    def channels(self) -> list[ChannelPlan]:
        """Every channel of the recording, in the order first seen: from the summary of whole
        files, by reading through the others."""
        seen: dict[ChannelPlan, None] = {}
        for state in self.files:
            with open(state.path, "rb") as f:
                summary = _summary(state, f) if state.whole else None
                if summary is not None:
                    for channel in summary.channels.values():
                        seen[self._plan(state.path, summary.schemas.get(channel.schema_id), channel)] = None
                else:
                    for schema, channel, _ in self._records(state, f):
                        seen[self._plan(state.path, schema, channel)] = None
        return list(seen)

    def metadata(self, index: int = 0) -> dict[str, dict[str, str]]:
        """The metadata records of a file (``icefloe``: who recorded what, when, in each file;
        ``icefloe.end``: messages and drops, in the last file of a recording that was closed)."""
        state = self.files[index]
        if state.metadata is None:
            with open(state.path, "rb") as f:
                if state.whole:
                    try:
                        state.metadata = {r.name: dict(r.metadata) for r in SeekingReader(f).iter_metadata()}
                    except (McapError, ValueError) as exc:
                        raise BadRecording(f"{state.path}: bad metadata: {exc}") from None
                else:
                    for _ in self._records(state, f):  # sets state.metadata on the way
                        pass
        return state.metadata or {}

    def _plan(self, path: Path, schema: Schema | None, channel: Channel) -> ChannelPlan:
        found = self._plans.get((path, channel.id))
        if found is None:
            if self.ros2 is not None and schema is not None and schema.encoding == "ros2msg" \
                    and channel.message_encoding == "cdr":
                found = self.ros2.plan(channel.topic, schema.name, self.robot)
            if found is None:  # not a ROS 2 topic replay turns back
                found = plan(channel.topic, schema.name if schema else "", schema.encoding if schema else "",
                             channel.message_encoding, dict(channel.metadata), self.robot)
            self._plans[(path, channel.id)] = found
        return found

    def _records(self, state: FileState, f: IO[bytes]) -> Iterator[tuple[Schema | None, Channel, McapMessage]]:
        if state.whole:
            summary = _summary(state, f)
            if summary is not None and summary.chunk_indexes:
                state.chunks = len(summary.chunk_indexes)
                state.compression = summary.chunk_indexes[0].compression
                try:
                    yield from SeekingReader(f, validate_crcs=True).iter_messages(log_time_order=True)
                except (McapError, ValueError) as exc:  # a corrupt chunk (bad CRC, bad compression)
                    raise BadRecording(f"{state.path}: {exc}") from None
                return
            f.seek(0)
        yield from self._stream(state, f)

    def _stream(self, state: FileState, f: IO[bytes]) -> Iterator[tuple[Schema | None, Channel, McapMessage]]:
        """Records from the start of the file; a truncated file ends at its last whole chunk."""
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        metadata: dict[str, dict[str, str]] = {}
        messages = chunks = good = 0
        records = StreamReader(f, validate_crcs=True, emit_chunks=True).records
        while True:
            try:
                record = next(records)
                # A chunk counts whole or not at all: its CRC is checked before any message of it is used.
                inner = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
            except StopIteration:
                break
            except Exception as exc:  # a cut-off tail fails in many ways (EOF, CRC, zstd, struct)
                if state.whole:
                    raise BadRecording(f"{state.path}: unreadable at byte {f.tell()}: {exc}") from None
                self._warn_truncated(state, messages, chunks, good, exc)
                break
            good = f.tell()
            if isinstance(record, Chunk):
                chunks += 1
                state.compression = state.compression or record.compression
            for r in inner:
                if isinstance(r, Schema):
                    schemas[r.id] = r
                elif isinstance(r, Channel):
                    channels[r.id] = r
                elif isinstance(r, Metadata):
                    metadata[r.name] = dict(r.metadata)
                elif isinstance(r, McapMessage):
                    channel = channels.get(r.channel_id)
                    if channel is None:
                        raise BadRecording(f"{state.path}: a message on channel {r.channel_id}, which has no record")
                    messages += 1
                    yield schemas.get(channel.schema_id), channel, r
        state.chunks = chunks
        state.metadata = metadata

    def _warn_truncated(self, state: FileState, messages: int, chunks: int, good: int, exc: BaseException) -> None:
        if state.path in self._warned:
            return
        self._warned.add(state.path)
        cut = f", and skipped {state.size - good} bytes of a chunk cut off" if state.size > good else ""
        log.warning("%s: truncated (no summary: was the recorder killed?): read %d messages from %d whole "
                    "chunks%s (%s)", state.path, messages, chunks, cut, type(exc).__name__)


def _summary(state: FileState, f: IO[bytes]) -> Summary | None:
    """The summary section of a whole file (None if it has none); BadRecording if it is corrupt."""
    try:
        return SeekingReader(f).get_summary()
    except (McapError, ValueError) as exc:
        raise BadRecording(f"{state.path}: bad summary section: {exc}") from None


def _files(paths: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """The files of a recording: a rosbag2 folder (with ``metadata.yaml``) stands for its .mcap files."""
    out = []
    for given in map(Path, paths):
        if given.is_dir() and (given / "metadata.yaml").is_file():
            found = sorted(given.glob("*.mcap"), key=lambda p: (len(p.name), p.name))  # run_2 before run_10
            if not found:
                raise BadRecording(f"{given}: a rosbag2 folder with no .mcap file")
            out += found
        else:
            out.append(given)
    return out


def _check(path: Path) -> tuple[int, bool, str]:
    """(size, whole, profile) of a file; BadRecording if it is missing or not MCAP."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(len(MAGIC))
            if size >= 2 * len(MAGIC):
                f.seek(-len(MAGIC), os.SEEK_END)
                tail = f.read(len(MAGIC))
            else:
                tail = b""
    except OSError as exc:
        raise BadRecording(f"{path}: {exc.strerror or exc}") from None
    if head != MAGIC:
        raise BadRecording(f"{path}: not an MCAP file (it starts with {head!r})")
    return size, tail == MAGIC, _profile(path)


def _profile(path: Path) -> str:
    """The profile of the file's header record; BadRecording if it has none (cut off before it)."""
    with open(path, "rb") as f:
        try:
            header = next(StreamReader(f).records)
        except Exception as exc:  # EOF, a bad length: cut off inside its first record
            raise BadRecording(f"{path}: no MCAP header (truncated after {f.tell()} bytes?): "
                               f"{exc or type(exc).__name__}") from None
    if not isinstance(header, Header):
        raise BadRecording(f"{path}: its first record is not an MCAP header but a {type(header).__name__}")
    return header.profile

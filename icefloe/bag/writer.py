"""Writing recordings: bus samples into MCAP files, chunked and compressed by the `mcap` library.

    writer = BagWriter("run.mcap", metadata={"robot": "sim"})
    writer.write("icefloe/sim/odom/pose", payload, "application/msgpack", log_time_ns)
    writer.close()

A chunk is closed at least every `CHUNK_SECONDS` (and at ``chunk_size`` bytes), and each closed
chunk is handed to the operating system at once: a recorder killed with SIGKILL loses about a
second, and the file reads up to its last whole chunk (`reader.Bag`). ``max_size`` splits a long
recording into numbered files (``run_000.mcap``, ``run_001.mcap``, ...), each a whole MCAP file.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterable
from importlib import metadata as package_metadata
from pathlib import Path
from typing import IO

from mcap.writer import CompressionType, Writer

from .channels import ChannelSpec, Transcoder

CHUNK_SECONDS = 1.0
"""A chunk is closed (compressed and written) at least this often, s."""
CHUNK_SIZE = 4 * 1024 * 1024
"""... and when it holds this many bytes."""
COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def library() -> str:
    """What goes in the file header's ``library`` field: icefloe's and mcap's versions."""
    try:
        ours = package_metadata.version("icefloe")
    except package_metadata.PackageNotFoundError:
        ours = "unknown"
    return f"icefloe {ours}, mcap-python {package_metadata.version('mcap')}"


class BagWriter:
    """Writes bus samples to an MCAP file (or numbered files of at most ``max_size`` bytes).

    A subclass writes another form (`ros2.Ros2BagWriter`: ROS 2's) by overriding `samples` (what a
    bus sample becomes in the file), `part_path`, `profile` and `before_finish`."""

    profile = ""
    """The MCAP header's profile ("": none of the well-known ones)."""

    def __init__(self, path: str | os.PathLike[str], *, compression: str = "zstd", max_size: int = 0,
                 metadata: dict[str, str] | None = None, chunk_seconds: float = CHUNK_SECONDS,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.path = Path(path)
        self.compression = COMPRESSION[compression]
        self.max_size = max_size
        self.metadata = dict(metadata or {})
        self.chunk_seconds = chunk_seconds
        self.messages = 0
        """Messages written, all files."""
        self.files: list[Path] = []
        self._clock = clock
        self._transcoder = Transcoder()
        self._stream: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._schemas: dict[tuple[str, bytes], int] = {}
        self._channels: dict[ChannelSpec, int] = {}
        self._closed_bytes = 0
        self._chunk_started = clock()
        self._open_next()

    @property
    def size(self) -> int:
        """Bytes written so far, all files (the chunk being filled not counted)."""
        return self._closed_bytes + (self._stream.tell() if self._stream else 0)

    def write(self, key: str, payload: bytes, encoding: str, log_time: int) -> None:
        """Record one sample received at ``log_time`` (ns since the epoch)."""
        writer = self._writer
        assert writer is not None, "write after close"
        for spec, data, stamp in self.samples(key, payload, encoding):
            channel_id = self._channels.get(spec)
            if channel_id is None:
                channel_id = self._channels[spec] = self._register(writer, spec)
            writer.add_message(channel_id, log_time=log_time, data=data,
                               publish_time=stamp if stamp is not None else log_time)
            self.messages += 1
        self.flush_if_due()

    def samples(self, key: str, payload: bytes, encoding: str) -> Iterable[tuple[ChannelSpec, bytes, int | None]]:
        """What one bus sample becomes in the file: (channel, message data, its own stamp or None), none
        or several."""
        return (self._transcoder.encode(key, payload, encoding),)

    def part_path(self, index: int) -> Path:
        """The file of part ``index`` of a split recording (``max_size``)."""
        return self.path.with_name(f"{self.path.stem}_{index:03d}{self.path.suffix}")

    def before_finish(self, writer: Writer) -> None:
        """Called before a file's summary is written: records that go at its end."""

    def flush_if_due(self) -> None:
        """`flush` if the chunk being filled is `chunk_seconds` old (call it now and then when idle)."""
        if self._clock() - self._chunk_started >= self.chunk_seconds:
            self.flush()

    def flush(self) -> None:
        """Close the chunk being filled and hand it to the OS; split to the next file if this one is full."""
        assert self._writer is not None and self._stream is not None
        self._writer.flush()  # the mcap library finishes the chunk and flushes our stream
        self._chunk_started = self._clock()
        if self.max_size and self._stream.tell() >= self.max_size:
            self._finish()
            self._open_next()

    def close(self, metadata: dict[str, str] | None = None) -> None:
        """Finish the file: summary, indexes, statistics (and ``metadata`` as the ``icefloe.end`` record)."""
        if self._writer is None:
            return
        if metadata:
            self._writer.add_metadata("icefloe.end", metadata)
        self._finish()

    def _register(self, writer: Writer, spec: ChannelSpec) -> int:
        schema_id = 0
        if spec.schema_encoding:
            schema_id = self._schemas.get((spec.schema_name, spec.schema))
            if schema_id is None:
                schema_id = writer.register_schema(spec.schema_name, spec.schema_encoding, spec.schema)
                self._schemas[(spec.schema_name, spec.schema)] = schema_id
        return writer.register_channel(spec.topic, spec.message_encoding, schema_id, spec.metadata)

    def _open_next(self) -> None:
        path = self.part_path(len(self.files)) if self.max_size else self.path
        self._stream = open(path, "wb")  # noqa: SIM115 - closed in _finish
        self._writer = Writer(self._stream, chunk_size=CHUNK_SIZE, compression=self.compression)
        self._writer.start(profile=self.profile, library=library())
        self._writer.add_metadata("icefloe", {**self.metadata, "part": str(len(self.files))})
        self._stream.flush()  # a file killed in its first second is still an (empty) MCAP file
        self._schemas.clear()
        self._channels.clear()
        self.files.append(path)

    def _finish(self) -> None:
        writer, stream = self._writer, self._stream
        assert writer is not None and stream is not None
        self._writer = self._stream = None  # closed, even if the disk refuses the summary
        try:
            self.before_finish(writer)
            writer.finish()
            self._closed_bytes += stream.tell()
        finally:
            with contextlib.suppress(OSError):
                stream.close()

"""ROS 2 recordings: the robot's ROS 2 topics in an MCAP file as ``ros2 bag record -s mcap`` writes
them (rosbag2_storage_mcap), and read back onto icefloe's keys (docs/ros2.md, "ROS 2 recordings").

    run/metadata.yaml     rosbag2's bag description (rosbags' AnyReader and Humble's ros2 bag read it)
    run/run_0.mcap        profile ``ros2``; one channel per topic (``/<robot>/odom``), message encoding
                          ``cdr``; schema ``nav_msgs/msg/Odometry``, encoding ``ros2msg``: the message
                          definition with its dependencies after ``=====`` lines, as rosbag2 writes it

What goes in, and how, is the ros2 service's own table (`Ros2Output`: icefloe key, ROS 2 topic, type,
conversion); it is passed in (``icefloe record --ros2`` reads it from services/ros2/convert.py), so a
recording holds exactly what the service would publish. Types, definitions, CDR and type hashes come
from rosbags' typestore of the configured distribution; the MCAP records from the `mcap` library.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, Protocol

from mcap.writer import Writer
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2.metadata import dump_qos_v8, dump_qos_v9

from .. import ros2
from ..errors import BadPayload, BadRecording
from ..logs import LimitedLog
from ..schemas import codec, keys
from ..schemas import messages as m
from .channels import ChannelPlan, ChannelSpec
from .reader import Bag
from .writer import BagWriter

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
METADATA_FILE = "metadata.yaml"
BAG_VERSION = {"humble": 5, "jazzy": 9, "kilted": 9, "rolling": 9}
"""rosbag2's bag format version of each distribution's ``ros2 bag`` (9 for Jazzy on: QoS enums as names)."""
INFINITE = QosTime(9223372036, 854775807)
"""RMW_DURATION_INFINITE, what rmw_zenoh reports for an unset deadline, lifespan and lease."""
log = logging.getLogger("icefloe.bag")


class Ros2Output(Protocol):
    """One ROS 2 topic made from one icefloe key (the ros2 service's ``convert.Output``)."""

    @property
    def key(self) -> keys.Topic: ...
    @property
    def topic(self) -> str: ...
    @property
    def ros_type(self) -> str: ...
    @property
    def message(self) -> Callable[[Any], Any | None]: ...


class Ros2Input(Protocol):
    """One ROS 2 topic turned back into an icefloe key (the ros2 service's ``convert.Input``)."""

    @property
    def topic(self) -> str: ...
    @property
    def ros_type(self) -> str: ...
    @property
    def key(self) -> keys.Topic: ...
    @property
    def message(self) -> Callable[[Any], Any]: ...


# --------------------------------------------------------------------------- what rosbag2 writes


def message_definition(ros_type: str, distro: ros2.Distro) -> str:
    """The ``ros2msg`` text of a type: its fields, then each type it uses after a line of 80 ``=`` and
    ``MSG: <type>`` (rosbag2's LocalMessageDefinitionSource), from rosbags' typestore."""
    text, _md5 = ros2.typestore(distro).generate_msgdef(ros_type, ros_version=2)
    return text


def offered_qos(distro: ros2.Distro, depth: int = 10) -> list[Qos]:
    """What the ros2 service's publishers offer, as ROS 2's graph reports it through rmw_zenoh: reliable,
    volatile, keep last ``depth``, automatic liveliness, every duration infinite (rmw_zenoh's defaults)."""
    del distro  # the same on every distribution; how it is written differs (`qos_text`)
    return [Qos(QosHistory.KEEP_LAST, depth, QosReliability.RELIABLE, QosDurability.VOLATILE, INFINITE, INFINITE,
                QosLiveliness.AUTOMATIC, INFINITE, False)]


def qos_text(profiles: list[Qos], distro: ros2.Distro) -> str:
    """``offered_qos_profiles`` as a channel's metadata holds it: YAML of the profiles, with the enums as
    numbers (bag versions before 9: Humble) or names. Version 9's list is written as JSON, which is YAML."""
    if BAG_VERSION[distro] < 9:
        return dump_qos_v8(profiles)
    return json.dumps(dump_qos_v9(profiles))


def qos_metadata(profiles: list[Qos], distro: ros2.Distro) -> Any:
    """``offered_qos_profiles`` in metadata.yaml: a YAML string before version 9, a list from 9 on."""
    return dump_qos_v8(profiles) if BAG_VERSION[distro] < 9 else dump_qos_v9(profiles)


# --------------------------------------------------------------------------- recording


class Ros2Transcoder:
    """Bus samples -> ROS 2 messages in CDR on their channels, through the ``outputs`` table."""

    def __init__(self, outputs: Sequence[Ros2Output], robot: str, namespace: str, distro: ros2.Distro) -> None:
        self.distro = distro
        self.outputs = list(outputs)
        self.warn = LimitedLog(log)
        self.skipped = 0
        """Samples not recorded: not on the robot's own key, or not a message of it."""
        self._by_key: dict[str, list[tuple[Ros2Output, ChannelSpec]]] = {}
        for output in self.outputs:
            topic = ros2.qualified_name(namespace, output.topic)
            metadata = {"offered_qos_profiles": qos_text(offered_qos(distro), distro)}
            if distro != "humble":  # Humble's rosbag2 has no type hashes
                metadata["topic_type_hash"] = ros2.type_hash(output.ros_type, distro)
            spec = ChannelSpec(topic, "raw", output.ros_type, SCHEMA_ENCODING,
                               message_definition(output.ros_type, distro).encode(), MESSAGE_ENCODING, metadata)
            self._by_key.setdefault(keys.key(robot, output.key), []).append((output, spec))

    @property
    def keys(self) -> list[str]:
        """The bus keys to subscribe to."""
        return list(self._by_key)

    def specs(self) -> list[ChannelSpec]:
        return [spec for these in self._by_key.values() for _, spec in these]

    def encode(self, key: str, payload: bytes, encoding: str) -> Iterable[tuple[ChannelSpec, bytes, int | None]]:
        these = self._by_key.get(key)
        if these is None:  # a put on a wildcard (icefloe/*/odom/pose) reaches us with that key: not ours alone
            self.skipped += 1
            self.warn.warning("ros2 record", "not recording a sample put on %s: only on %s", key,
                              ", ".join(self._by_key))
            return ()
        try:
            msg = codec.decode(payload, encoding, these[0][0].key.type, key)
        except BadPayload as exc:
            self.skipped += 1
            self.warn.warning("ros2 record", "not recording a sample on %s: %s", key, exc)
            return ()
        stamp = getattr(msg, "stamp", 0) or None  # when it was made (publish time), else when received
        out = []
        for output, spec in these:
            message = output.message(msg)
            if message is not None:
                out.append((spec, ros2.to_cdr(message, output.ros_type, self.distro), stamp))
        return out


class Ros2BagWriter(BagWriter):
    """Writes a rosbag2 bag: a folder with ``metadata.yaml`` and ``<folder>_<n>.mcap`` (split at
    ``max_size``), each file in ROS 2's form (profile ``ros2``, ros2msg schemas, CDR messages, a
    ``rosbag2`` metadata record), as ``ros2 bag record -s mcap -o <folder>`` writes it."""

    profile = PROFILE

    def __init__(self, folder: str | os.PathLike[str], transcoder: Ros2Transcoder, **options: Any) -> None:
        folder = Path(folder)
        if folder.suffix == ".mcap":  # -o run.mcap: the bag is the folder run/, as ros2 bag names it
            folder = folder.with_suffix("")
        try:
            folder.mkdir(parents=True)
        except FileExistsError:
            raise OSError(17, f"{folder} exists already (a bag is a new folder)", str(folder)) from None
        self.folder = folder
        self.ros2 = transcoder
        self._counts: dict[str, int] = {}  # topic -> messages, this file
        self._files_meta: list[dict[str, Any]] = []
        self._topics: dict[str, int] = {}  # topic -> messages, all files
        self._first = self._last = 0  # log times, this file
        self._start = 0
        super().__init__(folder / f"{folder.name}_0.mcap", **options)

    def samples(self, key: str, payload: bytes, encoding: str) -> Iterable[tuple[ChannelSpec, bytes, int | None]]:
        out = list(self.ros2.encode(key, payload, encoding))
        for spec, _, _ in out:
            self._counts[spec.topic] = self._counts.get(spec.topic, 0) + 1
        return out

    def write(self, key: str, payload: bytes, encoding: str, log_time: int) -> None:
        before = self.messages
        super().write(key, payload, encoding, log_time)
        if self.messages > before:
            self._first = min(self._first or log_time, log_time)
            self._last = max(self._last, log_time)

    def part_path(self, index: int) -> Path:
        return self.folder / f"{self.folder.name}_{index}.mcap"

    def before_finish(self, writer: Writer) -> None:
        counts, self._counts = self._counts, {}
        meta = {"path": self.files[-1].name, "starting_time": {"nanoseconds_since_epoch": self._first},
                "duration": {"nanoseconds": self._last - self._first}, "message_count": sum(counts.values())}
        self._files_meta.append(meta)
        for topic, n in counts.items():
            self._topics[topic] = self._topics.get(topic, 0) + n
        self._start = min(self._start or self._first, self._first) if self._first else self._start
        writer.add_metadata("rosbag2", {"serialized_metadata": json.dumps(self._bag_metadata([meta], counts))})
        self._first = self._last = 0

    def close(self, metadata: dict[str, str] | None = None) -> None:
        if self._writer is None:
            return
        super().close(metadata)
        text = json.dumps({"rosbag2_bagfile_information": self._bag_metadata(self._files_meta, self._topics)},
                          indent=2)
        (self.folder / METADATA_FILE).write_text(text + "\n")

    def _bag_metadata(self, files: list[dict[str, Any]], counts: dict[str, int]) -> dict[str, Any]:
        """rosbag2's BagMetadata (what metadata.yaml and each file's ``rosbag2`` record hold)."""
        distro = self.ros2.distro
        specs = {spec.topic: spec for spec in self.ros2.specs()}
        start = min((f["starting_time"]["nanoseconds_since_epoch"] for f in files if f["message_count"]), default=0)
        end = max((f["starting_time"]["nanoseconds_since_epoch"] + f["duration"]["nanoseconds"] for f in files
                   if f["message_count"]), default=0)
        topics = []
        for topic, n in counts.items():
            spec = specs[topic]
            described: dict[str, Any] = {"name": topic, "type": spec.schema_name, "serialization_format":
                                         MESSAGE_ENCODING, "offered_qos_profiles": qos_metadata(
                                             offered_qos(distro), distro)}
            if "topic_type_hash" in spec.metadata:
                described["type_description_hash"] = spec.metadata["topic_type_hash"]
            topics.append({"topic_metadata": described, "message_count": n})
        return {"version": BAG_VERSION[distro], "storage_identifier": "mcap",
                "duration": {"nanoseconds": end - start}, "starting_time": {"nanoseconds_since_epoch": start},
                "message_count": sum(f["message_count"] for f in files), "topics_with_message_count": topics,
                "compression_format": "", "compression_mode": "",
                "relative_file_paths": [f["path"] for f in files], "files": files, "ros_distro": distro}


# --------------------------------------------------------------------------- reading back


class Ros2Replay:
    """Which channels of a ROS 2 recording go back onto which icefloe keys (``inputs``: the ros2
    service's table), decoded with the distribution's types."""

    def __init__(self, inputs: Sequence[Ros2Input], distro: ros2.Distro) -> None:
        self.inputs = list(inputs)
        self.distro = distro

    def plan(self, topic: str, ros_type: str, robot: str | None) -> ChannelPlan | None:
        """The plan of a ``ros2msg``/``cdr`` channel, or None if no input takes it (replayed as raw bytes).
        ``robot``: replay under this name; else the namespace (``/sim/odom`` -> ``sim``)."""
        for given in self.inputs:
            if given.ros_type != ros_type or not topic.endswith("/" + given.topic):
                continue
            namespace = topic[:-len(given.topic) - 1].strip("/")
            if not namespace:  # /odom: not a robot's (ours are /<robot>/odom); replayed as raw bytes
                return None
            name = robot or namespace
            if any(c in name for c in "/*$#? "):
                return ChannelPlan(topic, "", "raw", None, "", refused=True,
                                   note=f"no robot name in its namespace {namespace or '(none)'!r}: give --robot")
            return ChannelPlan(topic, keys.key(name, given.key), "ros2", given.key.type, codec.MSGPACK,
                               convert=self._converter(given))
        return None

    def _converter(self, given: Ros2Input) -> Callable[[bytes], m.Message]:
        def convert(data: bytes) -> m.Message:
            return given.message(ros2.from_cdr(data, given.ros_type, self.distro))  # ValueError: named there
        return convert


def require_ros2(bag: Bag) -> None:
    """BadRecording naming the file unless every file of ``bag`` is a whole ROS 2 recording with a topic
    replay turns back (``replay --ros2``). A truncated one is refused before it is read: one line."""
    for state in bag.files:
        if not state.whole:
            raise BadRecording(f"{state.path}: truncated (no summary section: was the recorder killed?); "
                               "without --ros2, replay reads it up to its last whole chunk")
        if state.profile != PROFILE:
            raise BadRecording(f"{state.path}: not a ROS 2 recording (its MCAP profile is {state.profile!r}, "
                               f"not {PROFILE!r})")
    plans = bag.channels()
    if not any(plan.form == "ros2" for plan in plans):
        had = ", ".join(sorted({p.topic for p in plans})) or "no channel"
        raise BadRecording(f"{bag.files[0].path}: no ROS 2 topic of it turns back into an icefloe key "
                           f"(it has {had})")

"""The recording library (icefloe.bag) without a bus: what goes in a file, what comes back out.

Files are written by `BagWriter` from the demo robot's messages (every message viz shows, as the
real stack publishes them) and read back both with our reader and with the `mcap` library alone,
as a student's script or Foxglove would.
"""

from __future__ import annotations

import base64
import csv
import json
import logging
import time
from pathlib import Path

import msgspec
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from icefloe import config as config_mod
from icefloe.bag import Bag, BagWriter, channels
from icefloe.bag.export import to_csv
from icefloe.bag.replay import ReplayOptions, choose
from icefloe.errors import BadRecording, IcefloeError
from icefloe.schemas import codec, export, keys
from icefloe.schemas import messages as m
from icefloe.services.viz.demo import RATES_HZ, DemoRobot
from icefloe.worldmap import load_world

START = 1_700_000_000_000_000_000


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def demo_messages(seconds: float = 2.0) -> list[tuple[str, m.Message, int]]:
    """(key, message, receive time ns) of the demo robot "sim" at its rates, in time order."""
    config = config_mod.load("sim")
    demo = DemoRobot(config, load_world(config.localizer.world).markers)
    out = []
    for topic, rate in RATES_HZ.items():
        for i in range(max(1, int(seconds * rate))):
            t = i / rate
            stamp = START + int(t * 1e9)
            out.append((keys.key("sim", topic), demo.message(topic, t, stamp), stamp + 2_000_000))
    return sorted(out, key=lambda item: item[2])


def write(path: Path, messages, **options) -> BagWriter:
    writer = BagWriter(path, metadata={"robot": "sim"}, **options)
    for key, msg, received in messages:
        writer.write(key, codec.encode(msg), codec.MSGPACK, received)
    writer.close()
    return writer


def foxglove_reads(schema: dict, where: str = "") -> None:
    """What Foxglove's JSON Schema reader (@foxglove/mcap-support parseJsonSchema) accepts, or AssertionError:
    an object with properties; each property of type boolean, number, integer, string (contentEncoding only
    base64), object (the same again), or array of one of those (no contentEncoding on strings)."""
    assert schema.get("type") == "object", f"{where}: not an object"
    for name, field in schema["properties"].items():
        at = f"{where}.{name}"
        kind = field.get("type")
        if kind == "object":
            foxglove_reads(field, at)
        elif kind == "array":
            items = field["items"]
            if items.get("type") == "object":
                foxglove_reads(items, at)
            else:
                assert items.get("type") in ("boolean", "number", "integer", "string"), f"{at}: items {items}"
                assert "contentEncoding" not in items, at
        else:
            assert kind in ("boolean", "number", "integer", "string"), f"{at}: type {kind!r}"
            assert field.get("contentEncoding", "base64") == "base64", at


def test_a_file_has_one_channel_per_key_with_its_json_schema_and_json_messages(tmp_path: Path) -> None:
    sent = demo_messages()
    write(tmp_path / "run.mcap", sent)
    got: dict[str, list] = {}
    with open(tmp_path / "run.mcap", "rb") as f:  # the mcap library alone, as Foxglove or a student reads it
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary.chunk_indexes[0].compression == "zstd"
        for schema, channel, message in reader.iter_messages():
            got.setdefault(channel.topic, []).append((schema, channel, message))
    assert set(got) == {key for key, _, _ in sent}
    for key, msg, received in sent:
        schema, channel, message = got[key].pop(0)
        assert (channel.message_encoding, schema.encoding) == ("json", "jsonschema")
        assert channel.metadata == {"zenoh_encoding": codec.MSGPACK}
        assert message.log_time == received
        assert message.publish_time == getattr(msg, "stamp", received)
        body = json.loads(message.data)
        declared = json.loads(schema.data)
        foxglove_reads(declared, schema.name)
        assert set(body) <= set(declared["properties"])
        if isinstance(msg, m.Image):  # Foxglove's image, plus what icefloe needs back
            assert schema.name == "foxglove.CompressedImage" and declared["title"] == "foxglove.CompressedImage"
            assert declared["properties"]["data"]["contentEncoding"] == "base64"
            assert base64.b64decode(body["data"]) == msg.data
            assert body["timestamp"] == {"sec": msg.stamp // 10**9, "nsec": msg.stamp % 10**9}
            assert (body["format"], body["width"], body["height"]) == ("jpeg", msg.width, msg.height)
        else:
            assert schema.name == f"icefloe.{type(msg).__name__}"
            assert msgspec.json.decode(message.data, type=type(msg)) == msg
    assert all(not rest for rest in got.values())


def test_every_message_schema_and_the_image_schema_are_read_by_foxglove() -> None:
    for type_ in export.message_types():
        foxglove_reads(json.loads(channels.message_schema(type_.__name__)), type_.__name__)
    foxglove_reads(json.loads(channels.image_schema()), "foxglove.CompressedImage")


def test_replay_payloads_are_the_bytes_that_were_on_the_bus(tmp_path: Path) -> None:
    sent = demo_messages(1.0)
    write(tmp_path / "run.mcap", sent)
    entries = list(Bag([tmp_path / "run.mcap"]).entries())
    assert [e.channel.key for e in entries] == [key for key, _, _ in sent]
    identical = 0
    for entry, (_, msg, _) in zip(entries, sent, strict=True):
        out, original = channels.payload(entry.channel, entry.data), codec.encode(msg)
        # The bytes that were sent, but for an int in a float field (the demo writes 0 for 0.0):
        # it comes back as the float its message says it is.
        assert out == codec.encode(codec.decode(original, codec.MSGPACK, type(msg)))
        identical += out == original
    assert identical > 0.8 * len(sent)
    # Under another name, the same bytes on that robot's keys.
    renamed = list(Bag([tmp_path / "run.mcap"], robot="copy").entries())
    assert {e.channel.key.split("/")[1] for e in renamed} == {"copy"}


def test_json_input_bad_payloads_and_unknown_keys_are_kept_as_they_came(tmp_path: Path) -> None:
    writer = BagWriter(tmp_path / "run.mcap")
    writer.write("icefloe/sim/cmd/twist", b'{"v": 0.1, "w": 0}', codec.JSON, START)
    writer.write("icefloe/sim/cmd/twist", b'{"v": "fast"}', codec.JSON, START + 1)  # a hostile student's
    writer.write("icefloe/sim/cmd/twist", b"\xc1\xc1", codec.MSGPACK, START + 2)
    writer.write("icefloe/sim/student/thing", b"\x81\xa1a\x01", codec.MSGPACK, START + 3)
    writer.close()
    got = [(e.channel.form, e.channel.encoding, channels.payload(e.channel, e.data))
           for e in Bag([tmp_path / "run.mcap"]).entries()]
    # a good one is decoded and encoded again: unnumbered, as it was sent (sender "", seq 0: hwbridge's
    # ordering for commands without the fields, docs/hwbridge.md)
    assert got == [("typed", codec.JSON, b'{"v":0.1,"w":0.0,"sender":"","seq":0,"stamp":0}'),
                   ("raw", codec.JSON, b'{"v": "fast"}'),
                   ("raw", codec.MSGPACK, b"\xc1\xc1"), ("raw", codec.MSGPACK, b"\x81\xa1a\x01")]


def test_a_truncated_file_is_read_to_its_last_whole_chunk_with_one_warning(tmp_path: Path, caplog) -> None:
    clock = FakeClock()
    writer = BagWriter(tmp_path / "run.mcap", clock=clock)
    sent = demo_messages(3.0)
    flushed: list[tuple[int, int]] = []  # (messages, bytes) in the file after each chunk
    for key, msg, received in sent:  # a chunk a second of receive time, as the recorder does
        clock.now = (received - START) * 1e-9
        before = writer.size
        writer.write(key, codec.encode(msg), codec.MSGPACK, received)
        if writer.size != before:
            flushed.append((writer.messages, writer.size))
    # SIGKILL: no summary, the last chunk still in memory, and the one before only half written.
    assert len(flushed) == 2
    whole = (tmp_path / "run.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: (flushed[0][1] + flushed[1][1]) // 2])
    caplog.set_level(logging.WARNING, logger="icefloe.bag")
    bag = Bag([cut])
    entries = list(bag.entries())
    assert bag.channels()  # reads it again: still one warning
    assert len(entries) == flushed[0][0]
    assert [e.log_time for e in entries] == [r for _, _, r in sent[: len(entries)]]
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1 and "cut.mcap: truncated" in warnings[0] and "bytes of a chunk cut off" in warnings[0]
    assert not bag.files[0].whole
    # Killed between two chunks: everything written is read.
    assert len(list(Bag([tmp_path / "run.mcap"]).entries())) == flushed[1][0]


def test_a_file_that_is_not_mcap_is_refused_naming_it(tmp_path: Path) -> None:
    (tmp_path / "notes.mcap").write_bytes(b"PK\x03\x04 a zip file")
    with pytest.raises(BadRecording, match=r"notes.mcap: not an MCAP file"):
        Bag([tmp_path / "notes.mcap"])
    with pytest.raises(BadRecording, match=r"missing.mcap: No such file"):
        Bag([tmp_path / "missing.mcap"])


def foreign_file(path: Path) -> None:
    """An MCAP file from other tools: a ROS 2 message, protobuf, JSON of unknown schemas, a bad topic."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="another tool")
        ros = w.register_schema("nav_msgs/msg/Odometry", "ros2msg", b"std_msgs/Header header\n...")
        proto = w.register_schema("foxglove.PoseInFrame", "protobuf", b"\x0a\x01x")
        weather = w.register_schema("weather.Report", "jsonschema", b'{"type": "object"}')
        topics = [("/odom", ros, "cdr", b"\x00\x01\x00\x00odom"), ("/pose", proto, "protobuf", b"\x08\x01"),
                  ("/weather", weather, "json", b'{"t": 21}'), ("notes", 0, "json", b'{"note": "hi"}'),
                  ("/a/*/b", 0, "json", b"{}")]
        for i, (topic, schema, encoding, data) in enumerate(topics):
            channel = w.register_channel(topic, encoding, schema)
            w.add_message(channel, log_time=START + i * 1_000_000, data=data, publish_time=START)
        w.finish()


def test_another_tools_file_is_replayed_key_by_key_as_raw_bytes_or_refused(tmp_path: Path) -> None:
    foreign_file(tmp_path / "ros.mcap")
    plans = {c.topic: c for c in Bag([tmp_path / "ros.mcap"], robot="sim").channels()}
    assert [(c.key, c.form, c.encoding, c.refused) for c in plans.values()] == [
        ("icefloe/sim/odom", "raw", "application/cdr;nav_msgs/msg/Odometry", False),
        ("icefloe/sim/pose", "raw", "application/protobuf;foxglove.PoseInFrame", False),
        ("icefloe/sim/weather", "raw", "application/json;weather.Report", False),
        ("icefloe/sim/notes", "raw", "application/json", False),
        ("", "raw", "", True)]
    assert "unknown schema nav_msgs/msg/Odometry (ros2msg, cdr): replayed as raw bytes" in plans["/odom"].note
    assert "'/a/*/b' cannot be a Zenoh key" in plans["/a/*/b"].note
    for name in ("*", "a/b", "**", ""):  # replay publishes under the name: never a wildcard
        with pytest.raises(IcefloeError, match="is not a robot name"):
            Bag([tmp_path / "ros.mcap"], robot=name)
    # Without --robot, another tool's topics become keys of their own.
    assert Bag([tmp_path / "ros.mcap"]).channels()[0].key == "odom"
    # A refused channel has no key: it is reported when everything is replayed, not when keys are chosen.
    everything = choose(list(plans.values()), ReplayOptions())
    assert [len(everything[0]), len(everything[1])] == [4, 1]
    some = choose(list(plans.values()), ReplayOptions(keys=["odom"], exclude=["pose"]))
    assert [[c.key for c in some[0]], some[1]] == [["icefloe/sim/odom"], []]


def test_max_size_splits_a_recording_into_whole_files_read_back_in_order(tmp_path: Path) -> None:
    clock = FakeClock()
    sent = demo_messages(4.0)
    writer = BagWriter(tmp_path / "run.mcap", max_size=20_000, clock=clock)
    for key, msg, received in sent:
        clock.now = (received - START) * 1e-9
        writer.write(key, codec.encode(msg), codec.MSGPACK, received)
    writer.close()
    assert [p.name for p in writer.files][:2] == ["run_000.mcap", "run_001.mcap"]
    bag = Bag(writer.files)
    assert all(state.whole for state in bag.files)
    assert [e.log_time for e in bag.entries()] == [r for _, _, r in sent]


def test_csv_export_one_file_per_key(tmp_path: Path) -> None:
    sent = demo_messages(1.0)
    write(tmp_path / "run.mcap", sent)
    writer = BagWriter(tmp_path / "raw.mcap")
    writer.write("icefloe/sim/cmd/twist", b"\xc1", codec.MSGPACK, START)
    writer.close()
    written = to_csv(Bag([tmp_path / "run.mcap", tmp_path / "raw.mcap"]), tmp_path / "out")
    out = tmp_path / "out"
    with open(out / "odom_pose.csv") as f:
        rows = list(csv.DictReader(f))
    poses = [msg for key, msg, _ in sent if key.endswith("odom/pose")]
    assert len(rows) == len(poses) == written[out / "odom_pose.csv"]
    assert float(rows[3]["x"]) == poses[3].x and int(rows[3]["stamp"]) == poses[3].stamp
    with open(out / "camera_landmarks.csv") as f:
        marks = list(csv.DictReader(f))
    frames = [msg for key, msg, _ in sent if key.endswith("camera/landmarks")]
    assert len(marks) == sum(max(1, len(fr.landmarks)) for fr in frames)  # one row per marker seen
    seen = next(fr for fr in frames if fr.landmarks)
    row = next(r for r in marks if int(r["stamp"]) == seen.stamp)
    assert int(row["id"]) == seen.landmarks[0].id and json.loads(row["corners"]) == seen.landmarks[0].corners
    with open(out / "camera_image.csv") as f:
        image_row = next(csv.DictReader(f))
    first_image = next(msg for key, msg, _ in sent if key.endswith("camera/image"))
    assert (out / image_row["data"]).read_bytes() == first_image.data
    with open(out / "cmd_twist.raw.csv") as f:
        assert list(csv.reader(f))[1] == [str(START), codec.MSGPACK, base64.b64encode(b"\xc1").decode()]


def test_writing_is_cheap_enough_to_never_fall_behind(tmp_path: Path) -> None:
    """Not a benchmark (bench/record_replay.py is): a sanity bound, far above the robot's ~700 msg/s."""
    sent = demo_messages(5.0)
    payloads = [(key, codec.encode(msg), received) for key, msg, received in sent]
    writer = BagWriter(tmp_path / "run.mcap")
    start = time.process_time()
    for key, payload, received in payloads:
        writer.write(key, payload, codec.MSGPACK, received)
    writer.close()
    per_message = (time.process_time() - start) / len(payloads)
    assert per_message < 1e-3, f"{per_message * 1e6:.0f} µs per message"

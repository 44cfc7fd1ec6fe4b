"""ROS 2 recordings (``icefloe record --ros2``, docs/ros2.md "ROS 2 recordings"): the bag is read by
tools that are not ours, and replay puts it back onto icefloe's keys.

* rosbags' `AnyReader` opens the folder as a rosbag2 bag, and every message decodes with the
  distribution's own types (``deserialize_cdr``) to the values that were sent.
* The `mcap` library's reader, with types built from nothing but the ``ros2msg`` text in the file
  (as Foxglove does: mcap-ros2-support is not in the lock, so rosbags' .msg parser reads the text),
  decodes every message the same: the definitions in the file are right.
* Samples not the robot's own (a wildcard put, another robot's key, bad bytes) are not recorded.
* Replay turns ``odom`` back into ``odom/pose`` and ``cmd_vel`` into ``cmd/twist``; a truncated file
  or a file that is not a ROS 2 recording given to ``replay --ros2`` is one line naming it, status 2.

The first tests write the bag with the recorder's writer from real icefloe payloads (no bus, well
under a second); the last records a two-session bus with ``icefloe record --ros2`` and replays it
with ``icefloe replay``, both real processes (measured 4.1 s; the whole file 5 s).
"""

from __future__ import annotations

import asyncio
import json
import math
import signal
from pathlib import Path

import msgspec
import pytest
from conftest import Robot, wait_for
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from test_bag import START
from test_bag_cli import cli, collect, icefloe

from icefloe import ros2
from icefloe.angles import wrap_angle
from icefloe.bag import Bag, BagWriter
from icefloe.bag.channels import decode
from icefloe.bag.ros2 import offered_qos, require_ros2
from icefloe.cli.record import ros2_recording, ros2_replay
from icefloe.config import RobotConfig
from icefloe.errors import BadRecording
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.services.ros2 import convert

ROBOT = "penguin1"
POSES = [m.Pose(stamp=START + i * 20_000_000, x=0.01 * i, y=-0.02 * i, theta=wrap_angle(0.4 * i), v=0.1 + 0.01 * i,
                w=-0.2 + 0.05 * i) for i in range(25)]
TWISTS = [m.Twist(v=0.15, w=0.0, sender="teleop", seq=1, stamp=START + 5), m.Twist(v=0.0, w=-0.5)]
RECEIVED = 1_000_000
"""Each sample is received this long after its stamp, ns (log time = stamp + this)."""


def config(distro: str = "jazzy") -> RobotConfig:
    base = RobotConfig(name=ROBOT)
    return msgspec.structs.replace(base, ros2=msgspec.structs.replace(base.ros2, distro=distro))


def write_bag(folder: Path, distro: str = "jazzy") -> Path:
    """POSES and TWISTS as the bus carries them (MessagePack), with hostile samples between, through
    the recorder's writer; returns the bag's folder."""
    writer = ros2_recording(config(distro), ROBOT, folder, metadata={"robot": ROBOT})
    pose_key, twist_key = keys.key(ROBOT, keys.ODOM_POSE), keys.key(ROBOT, keys.TWIST)
    for i, pose in enumerate(POSES):
        writer.write(pose_key, codec.encode(pose), codec.MSGPACK, pose.stamp + RECEIVED)
        if i == 3:
            writer.write(twist_key, codec.encode(TWISTS[0]), codec.MSGPACK, pose.stamp + RECEIVED + 1)
            writer.write(f"{keys.PREFIX}/*/odom/pose", codec.encode(pose), codec.MSGPACK, pose.stamp)  # wildcard
            writer.write(keys.key("other", keys.ODOM_POSE), codec.encode(pose), codec.MSGPACK, pose.stamp)
            writer.write(pose_key, b"\xc1not msgpack", codec.MSGPACK, pose.stamp)
    writer.write(twist_key, codec.encode(TWISTS[1]), codec.MSGPACK, POSES[-1].stamp + 2 * RECEIVED)
    assert writer.ros2.skipped == 3
    writer.close({"messages": str(writer.messages)})
    return writer.folder


def published(robot_config: RobotConfig) -> list:
    """What ``record --ros2`` records: the service's published topics (not the asked ``map``) and cmd_vel."""
    return [*(o for o in convert.outputs(robot_config) if o.request is None), convert.cmd_vel_output(robot_config)]


def check_odometry(msg, pose: m.Pose) -> None:
    """A nav_msgs/msg/Odometry (any decoder's object) holds ``pose``."""
    assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == pose.stamp
    assert (msg.header.frame_id, msg.child_frame_id) == ("odom", "base_link")
    at, q = msg.pose.pose.position, msg.pose.pose.orientation
    assert (at.x, at.y, at.z) == (pose.x, pose.y, 0.0)
    assert math.isclose(2 * math.atan2(q.z, q.w), pose.theta, abs_tol=1e-12) and q.x == q.y == 0.0
    assert (msg.twist.twist.linear.x, msg.twist.twist.angular.z) == (pose.v, pose.w)


def check_twist(msg, twist: m.Twist) -> None:
    assert (msg.linear.x, msg.linear.y, msg.linear.z) == (twist.v, 0.0, 0.0)
    assert (msg.angular.x, msg.angular.y, msg.angular.z) == (0.0, 0.0, twist.w)


@pytest.mark.parametrize("distro", ["jazzy", "humble"])
def test_rosbags_opens_the_bag_and_decodes_every_message_with_the_distros_types(tmp_path: Path, distro) -> None:
    folder = write_bag(tmp_path / "run", distro)
    assert sorted(p.name for p in folder.iterdir()) == ["metadata.yaml", "run_0.mcap"]
    types = ros2.typestore(distro)  # type: ignore[arg-type]
    got: dict[str, list] = {}
    with AnyReader([folder], default_typestore=types) as reader:
        by_topic = {c.topic: c.msgtype for c in reader.connections}
        # a channel for each topic that had a message (odom/pose makes odom and tf), of the table's type
        table = {ros2.qualified_name(f"/{ROBOT}", o.topic): o.ros_type for o in published(config(distro))}
        assert by_topic == {topic: table[topic] for topic in (f"/{ROBOT}/odom", f"/{ROBOT}/tf", f"/{ROBOT}/cmd_vel")}
        for connection, log_time, raw in reader.messages():
            got.setdefault(connection.topic, []).append((log_time, types.deserialize_cdr(raw, connection.msgtype)))
        hashes = {c.topic: c.digest for c in reader.connections}
    odoms, twists, tfs = got[f"/{ROBOT}/odom"], got[f"/{ROBOT}/cmd_vel"], got[f"/{ROBOT}/tf"]
    assert set(got) == {f"/{ROBOT}/odom", f"/{ROBOT}/cmd_vel", f"/{ROBOT}/tf"}  # what was sent, nothing else
    assert len(odoms) == len(tfs) == len(POSES) and len(twists) == len(TWISTS)
    for (_, msg), pose in zip(tfs, POSES, strict=True):
        (transform,) = msg.transforms
        assert (transform.transform.translation.x, transform.transform.translation.y) == (pose.x, pose.y)
    for (log_time, msg), pose in zip(odoms, POSES, strict=True):
        assert log_time == pose.stamp + RECEIVED
        check_odometry(msg, pose)
    for (_, msg), twist in zip(twists, TWISTS, strict=True):
        check_twist(msg, twist)
    info = json.loads((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert (info["version"], info["ros_distro"], info["message_count"]) == (
        9 if distro == "jazzy" else 5, distro, 2 * len(POSES) + len(TWISTS))
    if distro == "jazzy":  # REP 2016's hashes; Humble has none
        assert hashes[f"/{ROBOT}/odom"] == ros2.type_hash("nav_msgs/msg/Odometry", "jazzy")


def test_the_definitions_in_the_file_alone_decode_every_message(tmp_path: Path) -> None:
    """As Foxglove reads a ROS 2 MCAP: types from the file's ``ros2msg`` schema text, nothing else."""
    folder = write_bag(tmp_path / "run")
    stores: dict[int, object] = {}
    odoms, twists = [], []
    with open(folder / "run_0.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
            assert b"\n" + b"=" * 80 + b"\nMSG: " in schema.data  # each dependency after rosbag2's separator
            store = stores.get(schema.id)
            if store is None:
                store = stores[schema.id] = get_typestore(Stores.EMPTY)
                store.register(get_types_from_msg(schema.data.decode(), schema.name))
            assert parse_qos(channel.metadata["offered_qos_profiles"]) == offered_qos("jazzy")
            assert channel.metadata["topic_type_hash"] == ros2.type_hash(schema.name, "jazzy")
            msg = store.deserialize_cdr(message.data, schema.name)
            if channel.topic in (f"/{ROBOT}/odom", f"/{ROBOT}/cmd_vel"):
                (odoms if channel.topic == f"/{ROBOT}/odom" else twists).append((message, msg))
    for (message, msg), pose in zip(odoms, POSES, strict=True):
        assert (message.log_time, message.publish_time) == (pose.stamp + RECEIVED, pose.stamp)
        check_odometry(msg, pose)
    for (_, msg), twist in zip(twists, TWISTS, strict=True):
        check_twist(msg, twist)
    assert twists[1][0].publish_time == twists[1][0].log_time  # no stamp: published when received


def test_replay_reads_odom_back_as_odom_pose_and_refuses_what_is_not_a_ros2_recording(tmp_path: Path) -> None:
    folder = write_bag(tmp_path / "run")
    bag = Bag([folder], robot="replayed", ros2=ros2_replay(config()))
    require_ros2(bag)
    entries = list(bag.entries())
    assert {e.channel for e in entries} == set(bag.channels())  # one plan per channel: replay selects by it
    back = [(e.channel.key, decode(e.channel, e.data)) for e in entries]
    assert [msg for key, msg in back if key == "icefloe/replayed/odom/pose"] == [
        msgspec.structs.replace(p, theta=pytest.approx(p.theta, abs=1e-12)) for p in POSES]
    assert [msg for key, msg in back if key == "icefloe/replayed/cmd/twist"] == [
        m.Twist(v=t.v, w=t.w) for t in TWISTS]  # no sender: ordered by when they arrive, as a plain put
    # Not ROS 2's, cut short, or with no topic that turns back: one error naming the file.
    ours = tmp_path / "ours.mcap"
    writer = BagWriter(ours)
    writer.write(keys.key(ROBOT, keys.ODOM_POSE), codec.encode(POSES[0]), codec.MSGPACK, START)
    writer.close()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes((folder / "run_0.mcap").read_bytes()[:600])
    for path, why in ((ours, "not a ROS 2 recording (its MCAP profile is '', not 'ros2')"),
                      (cut, "truncated (no summary section")):
        with pytest.raises(BadRecording, match=rf"^{path}: ") as raised:
            require_ros2(Bag([path], ros2=ros2_replay(config())))
        assert why in str(raised.value)


async def test_record_ros2_then_replay_over_a_real_bus(robot: Robot) -> None:
    """icefloe record --ros2 of a bus fed with icefloe's messages, then icefloe replay of its folder."""
    out = robot.tmp / "bag"
    recorder = cli(robot, "record", "--ros2", "-o", str(out), name="record")
    twist = m.Twist(v=0.1, w=0.2, sender="tester", seq=1, stamp=START)
    async with robot.node("tester") as node:
        await wait_for(lambda: "recording" in recorder.output or not recorder.alive(), timeout=30)
        assert recorder.alive(), recorder.output
        poses, commands = node.publisher(keys.ODOM_POSE), node.publisher(keys.TWIST)
        await asyncio.sleep(0.3)  # the router matches the recorder's subscriptions with the publishers
        for pose in POSES:
            poses.put(pose)
            await asyncio.sleep(0.005)
        commands.put(twist)
        node.session.put(f"{keys.PREFIX}/*/odom/pose", codec.encode(POSES[0]))  # a wildcard: not recorded
        node.session.put(keys.key(robot.name, keys.ODOM_POSE), b"\xc1")  # bad bytes: not recorded
        await wait_for(lambda: "not recording a sample on" in recorder.output, timeout=10)
        recorder.signal(signal.SIGINT)
        assert await asyncio.to_thread(recorder.popen.wait, 20) == 0, recorder.output
    assert "put on icefloe/*/odom/pose" in recorder.output, recorder.output
    with AnyReader([out], default_typestore=ros2.typestore("jazzy")) as reader:
        got = [(c.topic, reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()]
    assert [t for t, _ in got].count(f"/{robot.name}/odom") == len(POSES), got
    for (_, msg), pose in zip([g for g in got if g[0].endswith("/odom")], POSES, strict=True):
        check_odometry(msg, pose)
    check_twist(next(msg for topic, msg in got if topic.endswith("/cmd_vel")), twist)

    # Replayed under another name (its hwbridge is not running: cmd/* goes too, as replay sends it).
    replayed: list = []
    async with robot.node("spy") as node:
        spy = asyncio.create_task(collect(node.subscribe_raw(f"icefloe/{robot.name}x/odom/pose"), replayed))
        await asyncio.sleep(0.3)  # the spy's subscription reaches the router before the replay starts
        status, _, err = await icefloe("replay", str(out), "--ros2", "--rate", "4", "--robot", f"{robot.name}x",
                                       "--config", str(robot.config_path))
        assert status == 0, err
        await wait_for(lambda: len(replayed) >= len(POSES), timeout=10)
        spy.cancel()
    back = [codec.decode(s.payload, s.encoding, m.Pose) for s in replayed]
    assert [(p.stamp, p.x, p.y, p.v, p.w) for p in back] == [(p.stamp, p.x, p.y, p.v, p.w) for p in POSES]
    # Not a ROS 2 recording: one line naming it, status 2.
    status, _, err = await icefloe("replay", str(out / "metadata.yaml"), "--ros2", "--config", str(robot.config_path))
    assert status == 2 and err.strip().count("\n") == 0 and "metadata.yaml: not an MCAP file" in err, err

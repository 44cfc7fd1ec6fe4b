"""The recording verbs as real processes over a real router: record, replay, bag info, export, viz FILE.

The robot here is the demo robot (services/viz/demo.py: every message viz shows, at the stack's
rates) or files written with `BagWriter`; the whole simulated stack is in test_record_replay.py.
"""

from __future__ import annotations

import asyncio
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from conftest import ROOT, Proc, Robot, wait_for
from test_bag import START, demo_messages, foreign_file

from icefloe.bag import Bag, BagWriter
from icefloe.runtime import Node
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.services.viz.demo import DemoRobot, publish
from icefloe.worldmap import load_world

ICEFLOE = [sys.executable, "-m", "icefloe.cli"]


def cli(robot: Robot, *args: str, name: str) -> Proc:
    """``icefloe <args> --config <robot>`` as a process, stopped at the end of the test."""
    proc = Proc(name, [*ICEFLOE, *args, "--config", str(robot.config_path)], robot.tmp / f"{name}.log", robot.env)
    robot.procs.append(proc)
    return proc


async def icefloe(*args: str, timeout: float = 60.0, env: dict[str, str] | None = None) -> tuple[int, str, str]:
    """Run ``icefloe <args>`` to its end without blocking the test's event loop: (status, stdout, stderr)."""
    proc = await asyncio.create_subprocess_exec(*ICEFLOE, *args, cwd=ROOT, stdout=subprocess.PIPE,
                                                stderr=subprocess.PIPE, env=env)
    out, err = await asyncio.wait_for(proc.communicate(), timeout)
    return proc.returncode or 0, out.decode(), err.decode()


async def collect(sub, into: list) -> None:
    async for item in sub:
        into.append(item)


async def test_a_recorder_killed_with_sigkill_leaves_a_file_read_to_its_last_whole_chunk(robot: Robot) -> None:
    out = robot.tmp / "killed.mcap"
    recorder = cli(robot, "record", "-o", str(out), name="record")
    sent: list[m.Message] = []
    async with robot.node("tester") as node:
        await wait_for(lambda: "recording" in recorder.output, timeout=30)
        await asyncio.sleep(0.5)
        demo = DemoRobot(robot.config, load_world(robot.config.localizer.world).markers)
        publishing = asyncio.create_task(publish(node, demo, duration=60.0, sent=lambda _, msg: sent.append(msg)))
        # Mid-run: once a few chunks are on disk (the file, read while written, is a truncated one).
        await wait_for(lambda: len(list(Bag([out]).entries())) > 300, timeout=40, interval=0.5)
        written = len(list(Bag([out]).entries()))
        recorder.signal(signal.SIGKILL)
        recorder.popen.wait(10)
        publishing.cancel()
        await asyncio.gather(publishing, return_exceptions=True)
    status, info, warning = await icefloe("bag", "info", str(out))
    assert status == 0, warning
    assert len(warning.strip().splitlines()) == 1 and "killed.mcap: truncated" in warning
    assert ", truncated)" in info and f"icefloe/{robot.name}/odom/pose" in info
    entries = list(Bag([out]).entries())
    assert len(entries) >= written  # every chunk written before the kill
    stamps = {getattr(msg, "stamp", None) for msg in sent}
    assert all(e.publish_time in stamps for e in entries if e.channel.type is not m.OledFrame)
    # ... and it replays.
    status, _, err = await icefloe("replay", str(out), "--rate", "10", "--robot", f"{robot.name}x",
                                   "--config", str(robot.config_path))
    assert status == 0, err


def commands_file(path: Path, robot: str) -> None:
    writer = BagWriter(path)
    for i in range(5):
        writer.write(keys.key(robot, keys.TWIST), codec.encode(m.Twist(v=0.1, w=0.0)), codec.MSGPACK,
                     START + i * 20_000_000)
        writer.write(keys.key(robot, keys.ODOM_POSE), codec.encode(m.Pose(stamp=START + i, x=0.01 * i, y=0, theta=0)),
                     codec.MSGPACK, START + i * 20_000_000 + 1)
    writer.close()


async def test_replay_refuses_to_send_commands_to_a_live_robot_unless_asked(robot: Robot) -> None:
    recording = robot.tmp / "drive.mcap"
    commands_file(recording, robot.name)
    config = str(robot.config_path)
    seen: list = []
    async with robot.node("tester") as node, Node("hwbridge", robot.config) as hwbridge:
        # The robot is live: its hwbridge holds its liveliness token (this stand-in holds only that).
        assert keys.alive_key(robot.name, "hwbridge") in await hwbridge.alive()
        spy = asyncio.create_task(collect(node.subscribe_raw(f"icefloe/{robot.name}/**"), seen))
        await asyncio.sleep(0.5)
        status, _, err = await icefloe("replay", str(recording), "--config", config)
        assert status == 2
        assert (f"not replaying: the recording has commands (icefloe/{robot.name}/cmd/twist) and robot "
                f"{robot.name} is live") in err
        await asyncio.sleep(0.5)
        assert not [s for s in seen if not s.key.endswith("/log")], "nothing may be sent"
        status, _, err = await icefloe("replay", str(recording), "--exclude", "cmd/*", "--config", config)
        assert status == 0, err
        await wait_for(lambda: len(seen) >= 5)
        assert {s.key.rsplit("/", 2)[-2:][0] for s in seen} == {"odom"}
        status, _, err = await icefloe("replay", str(recording), "--allow-commands", "--config", config)
        assert status == 0, err
        await wait_for(lambda: sum(s.key.endswith("/cmd/twist") for s in seen) == 5)
        spy.cancel()


async def test_replay_keeps_the_timing_and_honours_rate_start_end_clock_and_loop(robot: Robot) -> None:
    recording = robot.tmp / "steady.mcap"
    writer = BagWriter(recording)
    for i in range(200):  # 100 Hz for 2 s
        pose = m.Pose(stamp=START + i * 10_000_000, x=0.001 * i, y=0.0, theta=0.0)
        writer.write(keys.key(robot.name, keys.ODOM_POSE), codec.encode(pose), codec.MSGPACK,
                     pose.stamp + 5_000_000)
    writer.close()
    poses: list = []
    clock: list[m.Clock] = []
    async with robot.node("tester") as node:
        tasks = [asyncio.create_task(collect(node.subscribe_raw(node.key(keys.ODOM_POSE), maxsize=10_000), poses)),
                 asyncio.create_task(collect(node.subscribe(keys.CLOCK, latest=False), clock))]
        await asyncio.sleep(0.5)
        status, _, err = await icefloe("replay", str(recording), "--rate", "2", "--start", "0.5", "--end", "1.5",
                                       "--clock", "50", "--config", str(robot.config_path))
        assert status == 0, err
        await asyncio.sleep(0.3)
        got = [codec.decode(p.payload, p.encoding, m.Pose) for p in poses]
        # Recorded 0.5 s to 1.5 s (both ends included): poses 50 to 150, in order, in half the time.
        assert [p.stamp for p in got] == [START + i * 10_000_000 for i in range(50, 151)]
        span = poses[-1].received - poses[0].received
        assert 0.4 < span < 1.5, span
        assert clock and all(c.rate == 2.0 for c in clock)
        assert [c.stamp for c in clock] == sorted(c.stamp for c in clock)
        assert START + 500_000_000 <= clock[0].stamp < START + 800_000_000
        # --loop: again and again until Ctrl-C, which ends it cleanly.
        poses.clear()
        looping = cli(robot, "replay", str(recording), "--loop", "--end", "0.3", "--rate", "3", name="loop")
        await wait_for(lambda: len(poses) > 100, timeout=30)
        assert looping.stop(signal.SIGINT) == 0, looping.output
        stamps = [codec.decode(p.payload, p.encoding, m.Pose).stamp for p in poses]
        assert stamps.count(START) >= 3  # each pass starts from the first pose again
        for task in tasks:
            task.cancel()


async def test_another_tools_file_is_replayed_as_raw_bytes_and_a_bad_topic_refused(robot: Robot) -> None:
    recording = robot.tmp / "ros.mcap"
    foreign_file(recording)
    seen: list = []
    async with robot.node("tester") as node:
        spy = asyncio.create_task(collect(node.subscribe_raw(f"icefloe/{robot.name}/**"), seen))
        await asyncio.sleep(0.5)
        status, _, err = await icefloe("replay", str(recording), "--robot", robot.name,
                                       "--config", str(robot.config_path))
        assert status == 0, err
        await wait_for(lambda: len(seen) >= 4)
        spy.cancel()
    assert "not replaying /a/*/b: topic '/a/*/b' cannot be a Zenoh key" in err
    assert "/odom: unknown schema nav_msgs/msg/Odometry (ros2msg, cdr): replayed as raw bytes" in err
    odom = next(s for s in seen if s.key == f"icefloe/{robot.name}/odom")
    assert (odom.payload, odom.encoding) == (b"\x00\x01\x00\x00odom", "application/cdr;nav_msgs/msg/Odometry")


async def test_record_only_the_keys_asked_for_for_the_time_asked(robot: Robot) -> None:
    out = robot.tmp / "some.mcap"
    recorder = cli(robot, "record", "odom/pose", "hw/*", "--exclude", "hw/battery", "--duration", "3",
                   "-o", str(out), name="record")
    async with robot.node("tester") as node:
        await wait_for(lambda: "recording" in recorder.output, timeout=30)
        demo = DemoRobot(robot.config, ())
        await publish(node, demo, duration=4.0)
    assert recorder.popen.wait(10) == 0, recorder.output  # it ended by itself
    assert re.search(r"recorded .*some.mcap: +\d+\.\d s +\d+ messages", recorder.output), recorder.output
    assert {e.channel.key for e in Bag([out]).entries()} == {
        keys.key(robot.name, t) for t in (keys.ODOM_POSE, keys.WHEELS, keys.LOOP)}


async def test_a_full_disk_or_a_bad_key_is_one_clear_line(robot: Robot) -> None:
    recorder = cli(robot, "record", "-o", "/dev/full", name="record")  # every write: ENOSPC
    async with robot.node("tester") as node:
        demo = DemoRobot(robot.config, ())
        publishing = asyncio.create_task(publish(node, demo, duration=40.0))
        await asyncio.to_thread(recorder.popen.wait, 40)
        publishing.cancel()
        await asyncio.gather(publishing, return_exceptions=True)
    assert recorder.popen.returncode == 2, recorder.output
    assert "icefloe: /dev/full: cannot write: No space left on device" in recorder.output
    assert "Traceback" not in recorder.output
    status, _, err = await icefloe("record", "icefloe/sim//pose", "--duration", "1", "--config", str(robot.config_path))
    assert status == 2 and err.startswith("icefloe: bad key expression") and "Traceback" not in err


async def test_bag_info_export_and_viz_read_a_recording(tmp_path: Path) -> None:
    recording = tmp_path / "demo.mcap"
    sent = demo_messages(2.0)
    writer = BagWriter(recording, metadata={"robot": "sim"})
    for key, msg, received in sent:
        writer.write(key, codec.encode(msg), codec.MSGPACK, received)
    writer.close({"dropped": "3"})  # as a recorder that could not keep up says
    status, info, err = await icefloe("bag", "info", str(recording))
    assert status == 0, err
    assert f"messages:  {len(sent)} (3 dropped by the recorder)" in info
    assert re.search(r"icefloe/sim/hw/wheels +200 +100.0 Hz +typed +application/msgpack", info), info
    assert "duration:  1.990 s" in info and "image  application/msgpack" in info
    status, out, err = await icefloe("export", str(recording), "--csv", str(tmp_path / "csv"))
    assert status == 0, err
    assert f"{tmp_path / 'csv' / 'hw_wheels.csv'}: 200 rows" in out
    status, out, err = await icefloe("viz", str(recording), "--save", str(tmp_path / "demo.rrd"))
    assert status == 0, err
    from icefloe.services.viz.readback import read_rrd

    shown = read_rrd(tmp_path / "demo.rrd")
    odom = shown["/robots/sim/map/odom"]
    assert odom["stamp"] == [msg.stamp for key, msg, _ in sent if key.endswith("odom/pose")]  # every one, on time
    assert len(shown["/robots/sim/camera/image"]["stamp"]) == 4 and shown["/robots/sim/oled"]["stamp"]
    status, _, err = await icefloe("bag", "info", str(tmp_path / "demo.rrd"))
    assert status == 2 and "demo.rrd: not an MCAP file" in err
    headless = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    status, _, err = await icefloe("viz", str(recording), env=headless)  # no window to open: one line, what to do
    assert status == 2 and "no display here" in err and "--save FILE.rrd" in err and "Traceback" not in err, err


def docs_snippet(doc: Path, after: str) -> str:
    """The first ```python block after the line containing ``after`` in a doc."""
    text = doc.read_text()
    block = re.search(r"```python\n(.*?)```", text[text.index(after):], re.S)
    assert block, f"no python block after {after!r} in {doc}"
    return block.group(1)


async def test_the_students_snippet_reads_a_recording(tmp_path: Path) -> None:
    """The snippet of docs/record-replay.md, as written, on a recording of the demo robot "sim"."""
    sent = demo_messages(2.0)
    writer = BagWriter(tmp_path / "run.mcap")
    for key, msg, received in sent:
        writer.write(key, codec.encode(msg), codec.MSGPACK, received)
    writer.write("icefloe/sim/odom/pose", b"\xc1 not a pose", codec.MSGPACK, received + 1)  # a raw channel
    writer.close()
    snippet = docs_snippet(ROOT / "docs" / "record-replay.md", "read the file directly")
    (tmp_path / "homework.py").write_text(snippet)
    proc = await asyncio.create_subprocess_exec(sys.executable, "homework.py", cwd=tmp_path,
                                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    out = (await asyncio.wait_for(proc.communicate(), 60))[0].decode()
    assert proc.returncode == 0, out
    poses = sum(1 for key, _, _ in sent if key.endswith("odom/pose"))
    sightings = sum(len(msg.landmarks) for key, msg, _ in sent if key.endswith("camera/landmarks"))
    assert out.strip() == f"{poses} poses, {sightings} landmark sightings" and sightings > 0


async def test_under_access_control_a_guest_records_and_only_the_owner_replays(make_robot) -> None:
    robot = make_robot(access_control=True)
    guest = robot.tmp / "guest.toml"  # a laptop's config with no credentials: the read-only guest
    guest.write_text(f'extends = "sim"\nname = "{robot.name}"\nrun_dir = "{robot.tmp}/guest-run"\n'
                     f'[zenoh]\nconnect = ["tcp/127.0.0.1:{robot.port}"]\n')
    out = robot.tmp / "guest.mcap"
    recorder = Proc("record", [*ICEFLOE, "record", "odom/pose", "--duration", "1", "-o", str(out),
                               "--config", str(guest)], robot.tmp / "record.log", robot.env)
    robot.procs.append(recorder)
    seen: list = []
    async with robot.node("owner") as node:  # the robot's config: its owner's credentials
        await wait_for(lambda: "recording" in recorder.output, timeout=30)
        await publish(node, DemoRobot(robot.config, ()), duration=1.5)
        assert recorder.popen.wait(10) == 0, recorder.output
        assert "read-only user" in recorder.output
        recorded = sum(1 for _ in Bag([out]).entries())
        assert recorded > 20
        spy = asyncio.create_task(collect(node.subscribe_raw("icefloe/**"), seen))
        await asyncio.sleep(0.3)
        # At once: the guest's replay and the owner's under another robot's name, whose messages the
        # router would drop (the owner publishes under the robot's own name only), are refused in one
        # line each; the owner's under the robot's name arrives, once.
        as_guest, not_mine, as_owner = await asyncio.gather(
            icefloe("replay", str(out), "--config", str(guest)),
            icefloe("replay", str(out), "--robot", "not-mine", "--config", str(robot.config_path)),
            icefloe("replay", str(out), "--config", str(robot.config_path)))
        assert as_guest[0] == 2 and "the router does not take messages for robot" in as_guest[2], as_guest
        assert not_mine[0] == 2 and "for robot not-mine" in not_mine[2], not_mine
        assert as_owner[0] == 0, as_owner
        await asyncio.sleep(0.5)
        spy.cancel()
    assert sum(s.key == keys.key(robot.name, keys.ODOM_POSE) for s in seen) == recorded
    assert not [s.key for s in seen if "/not-mine/" in s.key]

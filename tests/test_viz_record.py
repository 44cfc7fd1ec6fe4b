"""viz as a real process: a test publisher sends every message type, viz records, we read the .rrd back."""

from __future__ import annotations

import asyncio
import math
import time

from conftest import wait_for

from icefloe.schemas import keys
from icefloe.services.viz.demo import DemoRobot, publish
from icefloe.services.viz.readback import read_rrd, read_static
from icefloe.worldmap import load_world


async def test_records_every_stream_with_the_published_values(robot, tmp_path):
    out = tmp_path / "out.rrd"
    viz = robot.start_module("icefloe.services.viz", "--save", str(out))
    sent: dict[str, dict[int, object]] = {}
    async with robot.node("tester") as node:
        await wait_for(lambda: viz.output.count("showing robot") > 0, timeout=20)
        demo = DemoRobot(robot.config, load_world(robot.config.localizer.world).markers)
        bad = node.session.declare_publisher(node.key(keys.WHEELS))
        await publish(node, demo, duration=4.0,
                      sent=lambda t, msg: sent.setdefault(t.name, {}).__setitem__(getattr(msg, "stamp", 0), msg))
        bad.put(b"\xc1 not msgpack")  # must be dropped with a log line, viz keeps going
        await asyncio.sleep(0.5)
        bad.undeclare()
    assert viz.alive(), viz.output
    assert viz.stop() == 0, viz.output
    assert "dropped" in viz.output

    data = read_rrd(out)
    root = f"/robots/{robot.name}"
    for entity in ("map/odom", "map/loc", "map/loc/covariance", "map/truth", "map/extloc",
                   "map/extloc/covariance", "map/rays", "camera/image",
                   "camera/image/markers", "oled", "wheels/left/target", "wheels/right/measured",
                   "battery/voltage/filtered", "battery/current/raw", "loop/latency_ms/p99",
                   "loop/errors/overruns", "log"):
        assert data.get(f"{root}/{entity}", {}).get("log_time"), f"{entity} missing from the recording"

    # Every logged odometry pose is the one published with that stamp, and the pose moved.
    odom = data[f"{root}/map/odom"]
    for stamp, origins in zip(odom["stamp"], odom["Arrows2D:origins"], strict=True):
        pose = sent["odom/pose"][stamp]
        assert math.isclose(origins[0][0], pose.x, abs_tol=1e-5) and math.isclose(origins[0][1], pose.y, abs_tol=1e-5)
    first, last = odom["Arrows2D:origins"][0][0], odom["Arrows2D:origins"][-1][0]
    assert math.dist(first, last) > 0.3
    # hw/wheels at 100 Hz reaches the viewer decimated to about 20 Hz.
    wheels = data[f"{root}/wheels/left/target"]
    assert 0 < len(wheels["stamp"]) < len(sent["hw/wheels"]) / 3
    assert wheels["Scalars:scalars"][-1][0] == sent["hw/wheels"][wheels["stamp"][-1]].target_left
    # The landmark map from the world file is static data.
    static = read_static(out)
    landmarks = static[f"{root}/map/landmarks"]
    assert len(landmarks["Points2D:positions"][0]) == len(demo.markers)
    # Rerun's 2D views put +y down: the map hangs under a y flip so it reads as a plan (x right, y up).
    assert static[f"{root}/map"]["Transform3D:scale"] == [[[1.0, -1.0, 1.0]]]


async def test_discovers_two_robots_and_follows_only_the_one_asked_for(make_robot, tmp_path):
    import msgspec

    from icefloe.runtime import Node

    robot = make_robot()
    other = msgspec.structs.replace(robot.config, name=f"{robot.name}b")
    every, only = tmp_path / "every.rrd", tmp_path / "only.rrd"
    async with robot.node("tester") as a, Node("tester", other) as b:
        viz_all = robot.start_module("icefloe.services.viz", "--save", str(every), name="viz-all")
        viz_one = robot.start_module("icefloe.services.viz", "--save", str(only), "--robot", other.name,
                                     name="viz-one")
        await wait_for(lambda: viz_all.output.count("showing robot") >= 2 and "showing" in viz_one.output,
                       timeout=20)
        demo = DemoRobot(robot.config, ())
        rates = {keys.ODOM_POSE: 20.0}
        await asyncio.gather(publish(a, demo, 2.0, rates=rates), publish(b, demo, 2.0, rates=rates))
        await asyncio.sleep(0.5)
    assert viz_all.stop() == 0 and viz_one.stop() == 0
    got_all, got_one = read_rrd(every), read_rrd(only)
    assert f"/robots/{robot.name}/map/odom" in got_all and f"/robots/{other.name}/map/odom" in got_all
    assert f"/robots/{other.name}/map/odom" in got_one and f"/robots/{robot.name}/map/odom" not in got_one


async def test_records_the_simulated_robot_driving(robot, tmp_path):
    """The real simulated stack (sim, hwbridge, odometry, localizer, camera, power, oled) and viz."""
    from icefloe.schemas import messages as m

    services = ["sim", "hwbridge", "odometry", "localizer", "camera", "power", "oled"]
    procs = [robot.start(s) for s in services]
    out = tmp_path / "sim.rrd"
    async with robot.node("tester") as node:
        alive = {keys.alive_key(robot.name, s) for s in services}
        deadline = asyncio.get_running_loop().time() + 40
        while not alive <= set(await node.alive()) and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(0.5)
        viz = robot.start_module("icefloe.services.viz", "--save", str(out))
        await wait_for(lambda: "showing robot" in viz.output, timeout=20)
        twist = node.publisher(keys.TWIST)
        for _ in range(50):  # 5 s of a gentle arc
            twist.put(m.Twist(v=0.15, w=0.4))
            await asyncio.sleep(0.1)
        node.publisher(keys.STOP).put(m.Stop())
        node.session.put(node.key(keys.TWIST), b'{"v": "fast"}', encoding="application/json")  # a log line
        await asyncio.sleep(1.0)
    assert viz.stop() == 0, viz.output
    for proc in procs:
        assert proc.alive(), proc.output
    data = read_rrd(out)
    root = f"/robots/{robot.name}"
    for entity in ("map/odom", "map/loc", "map/truth", "camera/image", "oled", "wheels/left/target",
                   "wheels/left/measured", "battery/voltage/filtered", "loop/latency_ms/p99", "log"):
        assert data.get(f"{root}/{entity}", {}).get("log_time"), f"{entity} missing from the recording"
    for entity in ("map/odom", "map/truth"):  # the robot was driven: its pose moved
        origins = [row[0] for row in data[f"{root}/{entity}"]["Arrows2D:origins"] if row]
        assert math.dist(origins[0], origins[-1]) > 0.2, entity
    assert max(v[0] for v in data[f"{root}/wheels/left/measured"]["Scalars:scalars"] if v) > 0.05


async def test_records_the_obstacles_and_the_path_the_follower_drives(robot, tmp_path):
    """The world's walls and boxes once, ``nav/path`` as a line strip cleared by an empty path, the
    follower's state as a log line; a hostile path (too long, NaN) is one dropped line, viz keeps going."""
    import msgspec

    from icefloe.schemas import messages as m
    from icefloe.services.viz.logging_rr import obstacle_outlines
    from icefloe.services.viz.readback import read_static

    out = tmp_path / "nav.rrd"
    viz = robot.start_module("icefloe.services.viz", "--save", str(out))
    route = [m.Waypoint(0.0, 0.0), m.Waypoint(1.0, 0.0), m.Waypoint(1.0, 1.0)]
    async with robot.node("tester") as node:
        await wait_for(lambda: "showing robot" in viz.output, timeout=60)
        path, status = node.publisher(keys.NAV_PATH), node.publisher(keys.NAV_STATUS)
        await wait_for(lambda: path.matched and status.matched, timeout=20)  # viz has subscribed
        path.put(m.NavPath(points=route, stamp=time.time_ns(), seq=1))
        for state in ("following", "following", "arrived"):
            status.put(m.FollowStatus(stamp=time.time_ns(), state=state, seq=1, points=3))
            await asyncio.sleep(0.2)
        raw = node.session.declare_publisher(node.key(keys.NAV_PATH))
        # One at a time: the viewer keeps only the newest sample, so a second one may replace the first.
        origin = {"x": 0.0, "y": 0.0}
        for payload, said in (({"points": [origin] * 100_000}, "100000 points"),  # the schema allows 20 000
                              ({"points": [{"x": 0.0, "y": float("nan")}]}, "not finite")):
            raw.put(msgspec.msgpack.encode(payload))
            try:
                await wait_for(lambda said=said: said in viz.output, timeout=20)
            except AssertionError as exc:
                raise AssertionError(viz.output) from exc
        for _ in range(50):  # a flood of them: a few lines, not one each
            raw.put(msgspec.msgpack.encode({"points": [{"x": 0.0, "y": float("nan")}]}))
        raw.undeclare()
        await asyncio.sleep(0.5)
        path.put(m.NavPath(points=[], stamp=time.time_ns(), seq=2))  # clears the drawn path
        await asyncio.sleep(1.0)
    assert viz.alive(), viz.output
    assert viz.stop() == 0, viz.output
    assert viz.output.count("nav/path") <= 8, viz.output  # rate-limited: a few lines, not one per path

    root = f"/robots/{robot.name}"
    strips = read_rrd(out)[f"{root}/map/path"]["LineStrips2D:strips"]
    assert [[list(p) for p in s] for s in strips[0]] == [[[p.x, p.y] for p in route]]
    assert strips[-1] in ([], None) and len(strips) == 2  # the hostile paths drew nothing
    texts = read_rrd(out)[f"{root}/log/nav"]["TextLog:text"]
    assert [t[0].split(" ")[0] for t in texts] == ["following", "arrived"]  # only changes are logged
    world = load_world(robot.config.localizer.world)
    assert world.obstacles, "the test world has no obstacles"
    drawn = read_static(out)[f"{root}/map/obstacles"]["LineStrips2D:strips"][0]
    want = obstacle_outlines([o.rectangle() for o in world.obstacles])
    assert len(drawn) == len(want)
    for got, expected in zip(drawn, want, strict=True):
        assert all(math.dist(a, b) < 1e-5 for a, b in zip(got, expected, strict=True))

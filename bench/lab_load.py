"""The lab router alone: stand-ins for N robots' bus traffic, with no physics.

    .venv/bin/python bench/lab_scale.py --router-load [--robots 10,30,60,100] [--seconds 10] [--workers 2]

`lab_scale.py` runs real simulated robots, which cost about a fifth of a core each:
a machine runs out of cores long before a lab router runs out of anything. Here
each robot is only its traffic, so one machine can offer a lab router what a
hundred Raspberry Pis would:

* per robot, one Zenoh session per service of a real robot (hwbridge, odometry,
  localizer, camera, power, oled, webapi, info), each logged in to the lab router
  with the robot's own credentials, holding the service's liveliness token,
  subscriptions and queryables (`ROBOT_SIDE`, from the services' code) and
  publishing its keys at the robot config's rates (`robot_flows`: hw/wheels at
  ``hwbridge.wheels_rate_hz``, odom/pose at ``odometry.rate_hz``, landmarks at
  ``camera.fps`` ...) with payloads the size of the real ones (the camera's
  picture and landmarks come from the simulated camera and the real detector);
* per robot, a student's laptop with the robot's credentials that watches what
  ``icefloe viz`` shows of it (`LAPTOP_WATCHES`) and sends ``cmd/twist`` at 10 Hz.

That is the lab of docs/lab.md where every robot's services are clients of the
lab router, so each robot's own traffic crosses it too (hwbridge -> odometry).
The stand-ins run in ``--workers`` processes; their subscribers hand samples to
Zenoh ring buffers, so no Python runs per sample received.

Measured for each N, next to N = 0 (the router with only the probe): the lab
router's CPU (% of one core, /proc/<pid>/stat) and memory (RSS) per robot; the
latency a probe robot's ``hw/wheels`` takes through the router to its laptop
(stamp -> callback, one process, one clock) and how much it grows per robot;
the share of one robot's traffic that reached a watcher; and whether the
stand-ins offered their whole load. References: the figures of issue #19 (a
16-core machine, simulated robots at full rates, the lab router at 12.8 % of
one core for 10 robots, 30.8 % for 30, 37.5 % for 60).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import heapq
import json
import math
import multiprocessing as mp
import os
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path

import zenoh
from lab_harness import CpuMeter, Lab

from icefloe import config as config_mod
from icefloe import credentials
from icefloe.config import RobotConfig
from icefloe.runtime import MSGPACK, zenoh_config
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

# ---------------------------------------------------------------------------- one robot's traffic

ROBOT_SIDE: dict[str, tuple[tuple[keys.Topic, ...], tuple[keys.Topic, ...]]] = {
    # service: (what it subscribes to, the queryables it serves), from services/<name>/
    "hwbridge": ((keys.TWIST, keys.WHEELS_CMD, keys.STOP, keys.LEDS, keys.LEDARRAY, keys.BOARD_SCREEN,
                  keys.BOARD_TEXT), (keys.MOTION, keys.HALT)),
    "odometry": ((keys.WHEELS,), (keys.ODOM_RESET,)),
    "localizer": ((keys.ODOM_POSE, keys.LANDMARKS), ()),
    "camera": ((), (keys.SNAPSHOT,)),
    "power": ((keys.HW_BATTERY,), (keys.SHUTDOWN_REQUEST,)),
    "oled": ((keys.BATTERY, keys.WHEELS, keys.LOOP, keys.ODOM_POSE, keys.LOG, keys.OLED_TEXT, keys.OLED_SCREEN),
             ()),
    "webapi": ((keys.DIP,), ()),
    "info": ((), (keys.INFO,)),
}
"""A real robot's services (no simulator) and what each holds on the bus besides its publishers."""

LAPTOP_WATCHES = (keys.WHEELS, keys.ODOM_POSE, keys.LOC_POSE, keys.LANDMARKS, keys.IMAGE, keys.BATTERY,
                  keys.HW_BATTERY, keys.LOOP, keys.OLED_FRAME, keys.LOG)
"""What ``icefloe viz`` subscribes to for a robot (services/viz/app.py ``STREAMS``, less sim/truth)."""
TWIST_HZ = 10.0
"""The student's laptop repeats its twist at this rate (as `icefloe pub --rate 10` and lab_scale do)."""
PENGUINPI_BATTERY_HZ = 10.0
"""hwbridge publishes a voltage and current pair each time the PenguinPi has answered both polls
(docs/hwbridge.md: about 10 Hz); power publishes one `Battery` per reading."""
LOG_HZ = 0.3
"""Log lines of a robot's services, all together (0.3/s measured on the simulated robot)."""


@dataclass(frozen=True)
class Flow:
    """One stream of one robot: ``service`` publishes ``topic`` at ``rate_hz``."""

    service: str
    topic: keys.Topic
    rate_hz: float
    payload: bytes


def camera_messages(config: RobotConfig) -> tuple[m.Image, m.Landmarks]:
    """A picture and its landmarks as the camera service makes them, from the simulated camera at a
    pose where it sees at least two markers of the world."""
    import cv2

    from icefloe.services.camera.detection import make_detector
    from icefloe.services.camera.frames import jpeg
    from icefloe.sim.camera import CameraRenderer

    cam, renderer = config.camera, CameraRenderer.of_robot(config)
    detector = make_detector(config)
    best: tuple[m.Image, m.Landmarks] | None = None
    for heading in range(0, 360, 30):
        image, _ = renderer.render(0.0, 0.0, math.radians(heading))
        found = detector.detect(image)
        small = cv2.resize(image, (cam.image_width, cam.image_height), interpolation=cv2.INTER_AREA)
        picture = m.Image(stamp=time.time_ns(), width=cam.image_width, height=cam.image_height,
                          data=jpeg(small, cam.jpeg_quality))
        if best is None or len(found) > len(best[1].landmarks):
            best = picture, m.Landmarks(stamp=time.time_ns(), landmarks=found)
        if len(found) >= 2:
            break
    assert best is not None
    return best


def robot_flows(config: RobotConfig) -> list[Flow]:
    """What a robot with this config publishes, at the config's rates, with real-sized payloads."""
    now = time.time_ns()
    image, landmarks = camera_messages(config)
    hw, cam = config.hwbridge, config.camera
    loop = m.LoopStats(stamp=now, rate=999.8, period_mean=0.0010002, period_max=0.00131, latency_p50=2.3e-05,
                       latency_p99=4.7e-05, latency_p999=7.4e-05, latency_max=0.000412, overruns=12,
                       cycles=3_600_123, board="penguinpi", link_errors=3, link_rate=200.1, timeouts=3)
    table = [
        ("hwbridge", keys.WHEELS, hw.wheels_rate_hz,
         m.Wheels(stamp=now, ticks_left=123_456, ticks_right=123_398, speed_left=0.15031, speed_right=0.14968,
                  target_left=0.15, target_right=0.15)),
        ("hwbridge", keys.HW_BATTERY, PENGUINPI_BATTERY_HZ, m.BatteryReading(stamp=now, voltage=7.834, current=0.412)),
        ("hwbridge", keys.LOOP, 1.0, loop),
        ("hwbridge", keys.DIP, 1.0, m.Dip(stamp=now, value=5)),
        ("hwbridge", keys.LOG, LOG_HZ, m.Log(stamp=now, level="info", service="hwbridge",
                                             text="board link up: penguinpi")),
        ("odometry", keys.ODOM_POSE, config.odometry.rate_hz,
         m.Pose(stamp=now, x=1.23456, y=-0.56789, theta=0.78901, v=0.15, w=0.012)),
        # The localizer publishes after every landmark update (a frame with markers), and a period of
        # its rate after the last pose: the faster of the two rates.
        ("localizer", keys.LOC_POSE, max(config.localizer.rate_hz, cam.detection_hz),
         m.PoseEstimate(stamp=now, x=1.2301, y=-0.5702, theta=0.7911,
                        covariance=[0.0021, 0.0001, 0.0002, 0.0001, 0.0019, -0.0001, 0.0002, -0.0001, 0.0008])),
        ("camera", keys.LANDMARKS, cam.detection_hz, landmarks),
        ("camera", keys.IMAGE, cam.image_rate_hz, image),
        ("power", keys.BATTERY, PENGUINPI_BATTERY_HZ, m.Battery(stamp=now, voltage=7.81, current=0.41, state="ok")),
        ("oled", keys.OLED_FRAME, config.display.rate_hz,  # the pose and wheel screens change while driving
         m.OledFrame(width=128, height=32, pixels=bytes(range(256)) * 2)),
    ]
    return [Flow(service, topic, rate, codec.encode(msg)) for service, topic, rate, msg in table if rate > 0]


def subscribers(topic: keys.Topic) -> int:
    """How many sessions of one robot (its services and its laptop) receive a topic."""
    return sum(topic in subs for subs, _ in ROBOT_SIDE.values()) + (topic in LAPTOP_WATCHES)


@dataclass(frozen=True)
class Crossing:
    """What one robot (its services and its laptop) asks of the lab router, per second."""

    puts: float
    """Messages that reach the router."""
    deliveries: float
    """Messages the router sends on (each put times its subscribers)."""
    bytes_in: float
    """Payload bytes that reach the router (Zenoh adds a few bytes a message; batches share headers)."""
    bytes_out: float
    sessions: int


def crossing(flows: Sequence[Flow]) -> Crossing:
    """Every service on the lab router: all of a robot's traffic goes through it."""
    twist = len(codec.encode(m.Twist(v=0.15, w=0.0)))
    streams = [(f.rate_hz, len(f.payload), subscribers(f.topic)) for f in flows]
    streams.append((TWIST_HZ, twist, subscribers(keys.TWIST)))
    return Crossing(puts=sum(r for r, _, _ in streams), deliveries=sum(r * k for r, _, k in streams),
                    bytes_in=sum(r * b for r, b, _ in streams), bytes_out=sum(r * b * k for r, b, k in streams),
                    sessions=len(ROBOT_SIDE) + 1)


# ---------------------------------------------------------------------------- the stand-ins


@dataclass(frozen=True)
class StandIn:
    """One robot's name and credentials, as its stand-in logs in."""

    robot: str
    user: str
    password: str


def session_config(endpoint: str, user: str, password: str) -> zenoh.Config:
    """A client session of the lab router, as a robot's service or a laptop on another machine
    opens it: with credentials, without shared memory (only processes on one machine share it;
    the lab router offers each a segment, and runs out of them after about 350)."""
    zc = zenoh_config(config_mod.RobotConfig(), connect=[endpoint])
    zc.insert_json5("transport/shared_memory/enabled", "false")
    zc.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
    zc.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return zc


class Robots:
    """The sessions of some stand-in robots in this process, and their publishing loop."""

    def __init__(self, endpoint: str, robots: Sequence[StandIn], flows: Sequence[Flow]) -> None:
        self.sessions: list[zenoh.Session] = []
        self._keep: list[object] = []  # declarations live as long as we hold them
        self._flows: list[tuple[zenoh.Publisher, zenoh.ZBytes, float, int]] = []
        """(publisher, payload, period, index of its robot)."""
        self.puts = [0] * len(robots)
        """Puts so far, per robot."""
        twist = zenoh.ZBytes(codec.encode(m.Twist(v=0.15, w=0.0)))  # made once: a put of ZBytes copies nothing
        for r, robot in enumerate(robots):
            for service, (subs, queryables) in ROBOT_SIDE.items():
                session = self._open(endpoint, robot)
                self._keep.append(session.liveliness().declare_token(keys.alive_key(robot.robot, service)))
                self._keep += [session.declare_subscriber(keys.key(robot.robot, t), zenoh.handlers.RingChannel(1))
                               for t in subs]
                self._keep += [session.declare_queryable(keys.key(robot.robot, t), zenoh.handlers.RingChannel(1))
                               for t in queryables]
                self._flows += [(session.declare_publisher(keys.key(robot.robot, f.topic), encoding=MSGPACK),
                                 zenoh.ZBytes(f.payload), 1.0 / f.rate_hz, r) for f in flows if f.service == service]
            laptop = self._open(endpoint, robot)
            self._keep += [laptop.declare_subscriber(keys.key(robot.robot, t), zenoh.handlers.RingChannel(1))
                           for t in LAPTOP_WATCHES]
            self._flows.append((laptop.declare_publisher(keys.key(robot.robot, keys.TWIST), encoding=MSGPACK),
                                twist, 1.0 / TWIST_HZ, r))
        self.planned = sum(1.0 / flow[2] for flow in self._flows)
        """Puts per second these robots offer."""

    def _open(self, endpoint: str, robot: StandIn) -> zenoh.Session:
        session = zenoh.open(session_config(endpoint, robot.user, robot.password))
        self.sessions.append(session)
        return session

    def publish(self, stop: threading.Event) -> None:
        """Put every flow at its rate (spread phases; behind time, skip instead of bursting) until ``stop``."""
        start = time.monotonic()
        heap = [(start + flow[2] * (i * 0.618 % 1.0), i) for i, flow in enumerate(self._flows)]
        heapq.heapify(heap)
        puts = self.puts
        while not stop.is_set():
            now = time.monotonic()
            while heap[0][0] <= now:
                due, i = heap[0]
                publisher, payload, period, robot = self._flows[i]
                publisher.put(payload)
                puts[robot] += 1
                due += period
                heapq.heapreplace(heap, (due if due > now else now + period, i))
            time.sleep(max(0.0, min(heap[0][0] - time.monotonic(), 0.01)))

    def close(self) -> None:
        self._keep.clear()
        for session in self.sessions:
            with contextlib.suppress(Exception):
                session.close()


NICE = 10
"""The stand-ins run niced: on this machine they stand for other machines, so the router and the
probe get the CPU first (the "offered" column says whether the stand-ins still made every put)."""


def worker(endpoint: str, robots: list[StandIn], flows: list[Flow], conn: Connection, nice: int) -> None:
    """A stand-in process: open its robots' sessions, say "ready", publish from "go" until "stop".
    Each "mark" takes (time, puts per robot); the answer at the end is (marks, planned puts per s,
    puts per robot in all)."""
    os.nice(nice)
    group = Robots(endpoint, robots, flows)
    stop = threading.Event()
    marks: list[tuple[float, list[int]]] = []

    def control() -> None:
        while conn.recv() == "mark":
            marks.append((time.monotonic(), list(group.puts)))
        stop.set()

    conn.send("ready")
    assert conn.recv() == "go"
    threading.Thread(target=control, daemon=True).start()
    group.publish(stop)
    conn.send((marks, group.planned, group.puts))
    group.close()


# ---------------------------------------------------------------------------- the probe


class Probe:
    """A probe robot in this process: its hwbridge stand-in puts ``hw/wheels`` stamped now at 100 Hz;
    its laptop's callback takes the latency (one clock); a watcher counts one stand-in's traffic."""

    def __init__(self, endpoint: str, probe: StandIn, audited: str | None) -> None:
        self.latencies: list[float] = []
        self.heard = 0
        """Probe samples that came back, in all."""
        self.audit: dict[str, int] = defaultdict(int)
        self.measuring = False
        self._pub_session = zenoh.open(session_config(endpoint, probe.user, probe.password))
        self._sub_session = zenoh.open(session_config(endpoint, probe.user, probe.password))
        self._publisher = self._pub_session.declare_publisher(keys.key(probe.robot, keys.WHEELS), encoding=MSGPACK)
        self._subs = [self._sub_session.declare_subscriber(keys.key(probe.robot, keys.WHEELS), self._on_wheels)]
        if audited:
            self._subs.append(self._sub_session.declare_subscriber(f"{keys.key(audited, '**')}", self._on_audit))

    def _on_wheels(self, sample: zenoh.Sample) -> None:
        received = time.time_ns()
        self.heard += 1
        if self.measuring:
            stamp = codec.decode(sample.payload.to_bytes(), codec.MSGPACK, m.Wheels).stamp
            self.latencies.append((received - stamp) * 1e-9)

    def _on_audit(self, sample: zenoh.Sample) -> None:
        self.audit[keys.split(str(sample.key_expr))[1]] += 1  # from "go" to the end: every put of that robot

    async def run(self, seconds: float, rate_hz: float = 100.0) -> None:
        period = 1.0 / rate_hz
        deadline = time.monotonic()
        end = deadline + seconds
        while deadline < end:
            self._publisher.put(codec.encode(m.Wheels(stamp=time.time_ns(), ticks_left=1, ticks_right=1,
                                                      speed_left=0.15, speed_right=0.15)))
            deadline += period
            await asyncio.sleep(max(0.0, deadline - time.monotonic()))

    def close(self) -> None:
        self._subs.clear()
        self._pub_session.close()
        self._sub_session.close()


# ---------------------------------------------------------------------------- one measurement


@dataclass
class Row:
    robots: int
    sessions: int
    per_robot: Crossing
    router_cpu: float
    """% of one core over the window."""
    router_rss_mb: float
    router_idle_rss_mb: float
    latency_p50_ms: float
    latency_p99_ms: float
    probes: int
    delivered: float
    """Share of one stand-in robot's puts (services and laptop) that reached a watcher, over the window."""
    kept_up: float
    """Puts the stand-ins made / puts planned over the window."""
    generators_cpu: float
    machine_pct: float
    warm_up_s: float
    """From "go" until the probe and the audited robot both came through the router."""


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return math.nan


def measure(n: int, seconds: float, flows: list[Flow], workers: int, root: Path, nice: int = NICE) -> Row:
    """A lab router for the probe and ``n`` stand-in robots; the window's figures."""
    ctx = mp.get_context("spawn")  # no fork of a process that runs Zenoh's threads
    with Lab(root, n + 1) as lab:
        lab.start_router()
        idle_rss = rss_mb(lab.router.pid)
        creds = [credentials.read(lab.credentials_file(name)) for name in lab.names]
        standins = [StandIn(c.robot, c.user, c.password) for c in creds]
        probe_robot, robots = standins[0], standins[1:]
        procs, conns = [], []
        for k in range(min(workers, n)):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=worker, args=(lab.endpoint, robots[k::workers], flows, child, nice),
                               daemon=True)
            proc.start()
            procs.append(proc)
            conns.append(parent)
        try:
            for conn in conns:
                if not conn.poll(120 + n):
                    raise RuntimeError("a stand-in process did not open its sessions in time")
                assert conn.recv() == "ready"
            probe = Probe(lab.endpoint, probe_robot, robots[0].robot if robots else None)  # worker 0's first
            for conn in conns:
                conn.send("go")
            row = asyncio.run(_window(lab, probe, procs, conns, seconds))
            for conn in conns:
                conn.send("stop")
            results = [conn.recv() for conn in conns]
            time.sleep(1.0)  # the last puts reach the watcher
            probe.close()
        finally:
            for conn in conns:  # also when something failed: the stand-ins stop and exit
                with contextlib.suppress(OSError):
                    conn.send("stop")
            for proc in procs:
                proc.join(30)
                if proc.is_alive():
                    proc.kill()
        # Each worker's two marks bracket the window: puts made in it, against its plan.
        made = sum(sum(b) - sum(a) for ((_, a), (_, b)), _, _ in results)
        planned = sum(rate * (tb - ta) for ((ta, _), (tb, _)), rate, _ in results)
        audited_puts = results[0][2][0] if results else 0  # worker 0's first robot, from "go" to "stop"
    per_robot = crossing(flows)
    audited = sum(probe.audit.values())
    return Row(robots=n, sessions=n * per_robot.sessions + 2, per_robot=per_robot,
               router_cpu=row["router"], router_rss_mb=row["rss"],
               router_idle_rss_mb=idle_rss,
               latency_p50_ms=_pct(probe.latencies, 0.5) * 1e3, latency_p99_ms=_pct(probe.latencies, 0.99) * 1e3,
               probes=len(probe.latencies),
               delivered=audited / audited_puts if audited_puts else math.nan,
               kept_up=made / planned if planned else math.nan, generators_cpu=row["generators"],
               machine_pct=row["machine"], warm_up_s=row["warm_up"])


WARM_UP_S = 120.0
"""At most this long for the probe and the audited robot to come through the router, before the window."""


async def _window(lab: Lab, probe: Probe, procs: list[mp.Process], conns: list[Connection],
                  seconds: float) -> dict[str, float]:
    # Warm up until the router has taken every declaration: the probe and the audited robot come through.
    start = time.monotonic()
    while probe.heard < 100 or (len(procs) and sum(probe.audit.values()) < 100):
        if time.monotonic() - start > WARM_UP_S:
            raise RuntimeError(f"nothing through the lab router {WARM_UP_S:.0f} s after the stand-ins started")
        await probe.run(0.5)
    await probe.run(1.0)
    meter = CpuMeter({"router": [lab.router.pid], "generators": [p.pid for p in procs if p.pid]})
    meter.start()
    probe.measuring = True
    for conn in conns:
        conn.send("mark")
    t0 = time.monotonic()
    await probe.run(seconds)
    window = time.monotonic() - t0
    probe.measuring = False
    for conn in conns:
        conn.send("mark")
    cpu, machine = meter.stop()
    if not lab.router.alive():
        raise RuntimeError(f"the lab router died:\n{lab.router.tail()}")
    return {"router": cpu["router"], "generators": cpu["generators"], "machine": machine,
            "rss": rss_mb(lab.router.pid), "window": window, "warm_up": t0 - start}


def _pct(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


# ---------------------------------------------------------------------------- the table

REFERENCES = {10: 12.8, 30: 30.8, 60: 37.5}
"""Issue #19: the lab router's CPU (% of one core) with N simulated robots at full rates, 16 cores."""


def print_table(rows: list[Row], flows: list[Flow], workers: int, nice: int) -> None:
    config = config_mod.load(None)
    print(f"per robot: {len(ROBOT_SIDE)} service sessions + 1 laptop, all with the robot's credentials, "
          "direct on the lab router")
    print("  puts per second: " + ", ".join(f"{f.topic.name} {f.rate_hz:g} ({len(f.payload)} B)" for f in flows)
          + f", cmd/twist {TWIST_HZ:g} (laptop)")
    c = rows[-1].per_robot
    print(f"  through the lab router per robot: {c.puts:.0f} msg/s in, {c.deliveries:.0f} out; payloads "
          f"{c.bytes_in / 1e3:.0f} kB/s in, {c.bytes_out / 1e3:.0f} kB/s out")
    print(f"  rates from the robot config {config.source}; stand-ins in {workers} processes at nice {nice}\n")
    base = rows[0]
    print(f"{'robots':>6} {'sessions':>8} {'msg/s in':>9} {'msg/s out':>9} {'kB/s out':>8} {'router CPU %':>12} "
          f"{'/robot':>7} {'/1k out':>7} {'RSS MB':>7} {'/robot':>7} {'ref CPU %':>9}")
    for r in rows:
        made = r.robots * _ok(r.kept_up)  # robots' worth of traffic the stand-ins really offered
        out = made * r.per_robot.deliveries
        per_cpu = (r.router_cpu - base.router_cpu) / r.robots if r.robots else math.nan
        per_k = (r.router_cpu - base.router_cpu) / out * 1e3 if out else math.nan
        per_rss = (r.router_rss_mb - base.router_rss_mb) / r.robots if r.robots else math.nan
        ref = REFERENCES.get(r.robots)
        print(f"{r.robots:>6} {r.sessions:>8} {made * r.per_robot.puts:>9.0f} {out:>9.0f} "
              f"{made * r.per_robot.bytes_out / 1e3:>8.0f} {r.router_cpu:>12.1f} {per_cpu:>7.2f} {per_k:>7.2f} "
              f"{r.router_rss_mb:>7.0f} {per_rss:>7.2f} {f'{ref:.1f}' if ref else '':>9}")
    print(f"\n{'robots':>6} {'probe p50 ms':>12} {'p99 ms':>7} {'+p50/robot':>11} {'delivered':>9} "
          f"{'offered':>8} {'stand-ins CPU %':>15} {'machine busy':>12} {'through after':>13}")
    for r in rows:
        added = (r.latency_p50_ms - base.latency_p50_ms) / r.robots * 1e3 if r.robots else math.nan
        print(f"{r.robots:>6} {r.latency_p50_ms:>12.2f} {r.latency_p99_ms:>7.2f} {added:>8.1f} µs "
              f"{_share(r.delivered):>9} {_share(r.kept_up):>8} {r.generators_cpu:>15.0f} {r.machine_pct:>11.0f}% "
              f"{r.warm_up_s:>11.1f} s")
    print("\nmsg/s in: puts that reached the router (as the stand-ins made them); out: deliveries those ask of the "
          "router (each put times its subscribers); kB/s out: their payloads; router CPU in % of one core, /robot "
          "above the 0-robot row, /1k out per 1000 deliveries/s; RSS after the window; ref: issue #19's lab router "
          "with simulated robots at full rates, 16 cores.\n"
          "probe: a robot's hw/wheels at 100 Hz to its laptop through the router, stamp to callback (+p50/robot: "
          "above the 0-robot row); delivered: one stand-in robot's puts that reached a watcher; offered: puts made "
          f"/ planned; machine busy: all {os.cpu_count()} CPUs, everyone's work; through after: from the start of "
          "the stand-ins' puts until the probe and the audited robot came through. "
          f"Router memory with no session: {rows[0].router_idle_rss_mb:.0f} MB.")


def _ok(x: float) -> float:
    return 1.0 if math.isnan(x) else x


def _share(x: float) -> str:
    return "" if math.isnan(x) else f"{100 * x:.1f}%"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robots", default="10,30,60,100", help="comma-separated robot counts (0 is always run)")
    parser.add_argument("--seconds", type=float, default=10.0, help="measuring window per count, s")
    parser.add_argument("--workers", type=int, default=2, help="processes the stand-ins run in")
    parser.add_argument("--nice", type=int, default=NICE, help=f"niceness of the stand-ins (default {NICE})")
    args = parser.parse_args(argv)
    counts = [0, *sorted({int(n) for n in args.robots.split(",") if int(n) > 0})]
    print(f"$ {' '.join([Path(sys.executable).name, *sys.argv])}")
    flows = robot_flows(config_mod.load(None))
    rows = []
    for n in counts:
        with tempfile.TemporaryDirectory() as tmp:
            rows.append(measure(n, args.seconds, flows, args.workers, Path(tmp), args.nice))
        r = rows[-1]
        print(f"  {n} robots: router {r.router_cpu:.1f} % CPU, {r.router_rss_mb:.0f} MB, probe p50 "
              f"{r.latency_p50_ms:.2f} ms", flush=True)
    print()
    print_table(rows, flows, args.workers, args.nice)
    failures = [f"{r.robots} robots: only {_share(r.delivered)} of a robot's traffic reached its watcher"
                for r in rows if r.robots and r.delivered < 0.95]
    failures += [f"{r.robots} robots: no probe got through" for r in rows if not r.probes]
    for line in failures:
        print(f"FAIL {line}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

"""Lab scale: one lab router, N simulated robots, laptops that drive two of them.

    .venv/bin/python bench/lab_scale.py [--robots 10] [--seconds 10] [--cycle-hz 250] [--odom-hz 25] [--direct]
    .venv/bin/python bench/lab_scale.py --router-load [--robots 10,30,60,100] [--seconds 10]

"A lab is a room with twenty robots and forty laptops on one Wi-Fi." This script
builds that room on one machine, with real processes and real Zenoh sessions
(`lab_harness.Lab`):

* a TA's folder of credentials files, one per robot;
* one lab router, ``icefloe router lab.toml --lab DIR``, on a free loopback port;
* N simulated robots without cameras (``services.sim`` + ``services.hwbridge`` +
  ``services.odometry`` each), each in its own namespace ``icefloe/<name>/`` with
  its own credentials and its own router, which joins the lab router (``[zenoh] lab``;
  ``--direct``: no robot routers, the services connect to the lab router);
* a student's laptop holding two robots' credentials (one Zenoh session per
  credential), and a classmate's laptop logged in as the read-only ``guest``.

The laptop waits until every robot is alive (liveliness ``icefloe/*/alive/*``)
and sends its first pose. Then, for the measuring window, it drives robots 0
and 1, each with its own credentials, and tries to drive robot 2 with robot 0's
credentials, which the lab router must drop; then it waits for the deadman to
stop them. It reports per robot how far it truly moved (``sim/truth``) against
the distance its delivered twists asked for (the twists the guest saw pass
the router: speed x (last - first + deadman), less the acceleration ramp), the
rate of ``odom/pose`` against the configured ``odometry.rate_hz``, hwbridge's
cycle rate, overruns and stalled shared-memory reads (``hw/loop``); every
process that exited (crashed) and every hwbridge whose real-time cycle was
replaced (restarted); and the CPU used by the router and by all robot
processes. References from the same run: the configured rates, and the
router's CPU while idle, before the robots joined. Exit status 1 if any check
fails: a driven robot off its asked distance by more than 5 %, any other robot
moving, a pose rate under 80 % of its configuration, a twist through with the
wrong credentials, a crashed or restarted process.

``--router-load`` measures the lab router alone, with stand-ins for N robots'
bus traffic and no physics (`lab_load.py`).

A simulated robot's sim clock always runs at 1 kHz; the hwbridge cycle and the
bus rates are options, because ten robots' 1 kHz cycles do not fit well on the
two shared cores that stand in for ten Raspberry Pis here.

``tests/test_lab.py`` runs the same code with three robots.
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import contextlib
import math
import os
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import zenoh
from lab_harness import SERVICES, CpuMeter, Lab, Rates

from icefloe import config as config_mod
from icefloe import credentials
from icefloe.config import RobotConfig
from icefloe.runtime import MSGPACK, Node
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

MOVED_M = 0.05
"""A driven robot must move at least this far in the window, m (and `DISTANCE_TOLERANCE` of what it was asked)."""
DISTANCE_TOLERANCE = 0.05
"""A driven robot's true distance must be within this fraction of what its delivered twists asked for."""
SETTLE_S = 0.7
"""After the last twist, the deadman stops the robot (0.5 s) and the wheels come to rest: wait this long more."""
STILL_M = 0.005
"""Any other robot must move less than this, m (the sim adds no noise unless configured to)."""
MIN_RATE = 0.8
"""Each robot's odom/pose must arrive at this fraction of its configured rate, or better."""
TWIST_HZ = 10.0
"""How often the laptop repeats its twist: well inside hwbridge's 0.5 s deadman."""


# ---------------------------------------------------------------------------- the laptops


def laptop_config(creds_path: Path, endpoint: str) -> RobotConfig:
    """What ``icefloe ... --credentials FILE`` gives a student's laptop: that robot, that user."""
    creds = credentials.read(creds_path)
    base = config_mod.load(None)
    zenoh = msgspec.structs.replace(base.zenoh, connect=[endpoint], user=creds.user, password=creds.password)
    return msgspec.structs.replace(base, name=creds.robot, zenoh=zenoh)


def guest_config(endpoint: str) -> RobotConfig:
    """A laptop without credentials: icefloe logs it in to a guarded router as the read-only guest."""
    base = config_mod.load(None)
    zenoh = msgspec.structs.replace(base.zenoh, connect=[endpoint], access_control=True)
    return msgspec.structs.replace(base, zenoh=zenoh)


class Laptops:
    """Sessions on the lab router: robot A's and robot B's credentials, and a guest.

    Session A collects every robot's ``odom/pose``, session B every robot's
    ``hw/loop`` (the cycle's own account of its rate); the guest collects every
    robot's ``sim/truth`` and the times of the ``cmd/twist`` samples the router
    lets through, per robot.
    """

    def __init__(self, lab: Lab, a: str, b: str) -> None:
        self._configs = (laptop_config(lab.credentials_file(a), lab.endpoint),
                         laptop_config(lab.credentials_file(b), lab.endpoint), guest_config(lab.endpoint))
        self._stack = contextlib.AsyncExitStack()
        self._tasks: list[asyncio.Task[None]] = []
        self.poses: dict[str, list[tuple[float, m.Pose]]] = defaultdict(list)
        """Per robot: (time.monotonic() when Zenoh's callback saw it, pose)."""
        self.loops: dict[str, list[tuple[float, m.LoopStats]]] = defaultdict(list)
        self.truths: dict[str, list[tuple[float, m.Truth]]] = defaultdict(list)
        self.twists_heard: dict[str, list[float]] = defaultdict(list)
        """Per robot: time.monotonic() when the guest's session saw each twist the router let through."""

    async def __aenter__(self) -> Laptops:
        try:
            self.a, self.b, self.guest = [
                await self._stack.enter_async_context(Node(name, cfg, announce=False))
                for name, cfg in zip(("laptop", "laptop", "classmate"), self._configs, strict=True)]
        except BaseException:
            await self._stack.aclose()  # close the sessions that did open
            raise
        self._tasks = [asyncio.create_task(self._collect(self.a, keys.ODOM_POSE, self.poses)),
                       asyncio.create_task(self._collect(self.b, keys.LOOP, self.loops)),
                       asyncio.create_task(self._collect(self.guest, keys.TRUTH, self.truths)),
                       asyncio.create_task(self._count_twists())]
        return self

    async def __aexit__(self, *exc: object) -> None:
        for task in self._tasks:
            task.cancel()
        await self._stack.aclose()

    @staticmethod
    async def _collect(node: Node, topic: keys.Topic, into: dict[str, list[tuple[float, Any]]]) -> None:
        """Every robot's messages of ``topic``, stamped with the time Zenoh's callback saw them."""
        async for raw in node.subscribe_raw(keys.key("*", topic), maxsize=100_000):
            message = codec.decode(raw.payload, raw.encoding, topic.type, raw.key)
            into[keys.split(raw.key)[0]].append((raw.received, message))

    async def _count_twists(self) -> None:
        async for raw in self.guest.subscribe_raw(keys.key("*", keys.TWIST), maxsize=100_000):
            self.twists_heard[keys.split(raw.key)[0]].append(raw.received)

    async def wait_alive(self, names: list[str], timeout: float) -> dict[str, set[str]]:
        """Poll liveliness ``icefloe/*/alive/*`` until every robot holds a token per service."""
        deadline = time.monotonic() + timeout
        while True:
            seen: dict[str, set[str]] = defaultdict(set)
            for token in await self.a.alive("*"):
                robot, rest = keys.split(token)
                seen[robot].add(rest.removeprefix("alive/"))
            if all(set(SERVICES) <= seen[n] for n in names) or time.monotonic() > deadline:
                return dict(seen)
            await asyncio.sleep(0.5)

    async def wait_truths(self, names: list[str], since_ns: int, timeout: float) -> None:
        """Wait until each robot's ``sim/truth`` stamped at or after ``since_ns`` (wall clock) is here."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not all(
                self.truths[n] and self.truths[n][-1][1].stamp >= since_ns for n in names):
            await asyncio.sleep(0.1)

    async def wait_poses(self, names: list[str], timeout: float) -> list[str]:
        """Wait for a first pose from each robot (odometry publishes once hw/wheels flows); the silent ones."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not all(self.poses[n] for n in names):
            await asyncio.sleep(0.1)
        return [n for n in names if not self.poses[n]]


async def drive(publishers: list[zenoh.Publisher], twist: m.Twist, seconds: float) -> int:
    """Put ``twist`` on every publisher at `TWIST_HZ` for ``seconds``; returns how many rounds."""
    payload, rounds = codec.encode(twist), 0
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        for pub in publishers:
            pub.put(payload)
        rounds += 1
        await asyncio.sleep(1.0 / TWIST_HZ)
    return rounds


# ---------------------------------------------------------------------------- the measurement


@dataclass
class RobotResult:
    name: str
    role: str
    configured_hz: float
    """odometry.rate_hz from the robot's config."""
    poses: int
    """odom/pose samples the laptop received in the window."""
    rate_hz: float
    moved_m: float
    """Straight-line distance between the robot's true poses (``sim/truth``) at rest before the window
    and at rest after it (the deadman has stopped it)."""
    asked_m: float
    """What the delivered twists asked for: speed x the simulated time from the first twist to the last
    plus the deadman (`SimClockTrace`), less the acceleration ramp."""
    sim_pace: float
    """Driven robots: that simulated time over the wall-clock time. Below 1 the simulator fell behind this
    machine and dropped the backlog (sim/clock.py): its world stood still meanwhile."""
    twists_sent: int
    twists_heard: int
    """cmd/twist samples the guest's laptop received for this robot (what the router let through)."""
    cycle_hz: float
    """hwbridge's real-time cycle rate over the window, from its own ``hw/loop`` counts (nan: too few)."""
    overruns: int
    """Cycles that missed their deadline in the window."""
    stalled_reads: int
    """hwbridge's shared-memory reads put off in the window (a process descheduled mid-write)."""


@dataclass
class Report:
    rates: Rates
    speed: float
    """The twist the laptop sent, m/s."""
    window_s: float
    startup_s: float
    """From starting the robots' processes until every service of every robot was alive."""
    seen: dict[str, set[str]]
    """Services alive per robot, as the laptop saw them."""
    robots: dict[str, RobotResult]
    cpu: dict[str, float]
    """Percent of one core: router, router idle (before the robots), robots, per service, laptop."""
    machine_pct: float
    """Busy percent of the whole machine (all CPUs, everyone's processes) over the window."""
    driven: tuple[str, str]
    intruded: str
    """The robot the laptop tried to drive with robot 0's credentials."""
    crashed: list[str]
    """Processes that exited before the end (robot services, the router), with their status."""
    restarted: list[str]
    """hwbridges whose real-time cycle was not the same process at the end as when the robots were up."""
    mesh: bool = False
    """Each robot has its own router, joined to the lab router (else: services on the lab router)."""

    def failures(self) -> list[str]:
        """What went wrong, in words (empty: every check passed)."""
        bad = [f"{n}: alive services {sorted(self.seen.get(n, ()))}, expected {list(SERVICES)}"
               for n in self.robots if not set(SERVICES) <= self.seen.get(n, set())]
        for r in self.robots.values():
            if math.isnan(r.moved_m):
                bad.append(f"{r.name}: no sim/truth before and after the window")
            if r.name in self.driven and r.moved_m < MOVED_M:
                bad.append(f"{r.name}: driven with its own credentials but moved only {r.moved_m:.3f} m")
            if r.name in self.driven and abs(r.moved_m - r.asked_m) > DISTANCE_TOLERANCE * r.asked_m:
                bad.append(f"{r.name}: moved {r.moved_m:.3f} m of the {r.asked_m:.3f} m its {r.twists_heard} "
                           f"delivered twists asked for (off by more than {DISTANCE_TOLERANCE:.0%})")
            if r.name not in self.driven and r.moved_m >= STILL_M:
                bad.append(f"{r.name}: not driven ({r.role}) but moved {r.moved_m:.3f} m")
            if r.rate_hz < MIN_RATE * r.configured_hz:
                bad.append(f"{r.name}: odom/pose at {r.rate_hz:.1f} Hz, below {MIN_RATE:.0%} of "
                           f"{r.configured_hz:g} Hz")
        if heard := self.robots[self.intruded].twists_heard:
            bad.append(f"{self.intruded}: {heard} twists sent with another robot's credentials "
                       "got through the lab router")
        bad += [f"crashed: {line}" for line in self.crashed]
        bad += [f"restarted: {line}" for line in self.restarted]
        return bad


async def measure(lab: Lab, seconds: float, *, start_timeout: float = 60.0, speed: float = 0.15) -> Report:
    """Start the robots, wait for them, drive two, try a third with the wrong credentials; measure."""
    assert lab.router is not None, "start the router first"
    idle = CpuMeter({"router": [lab.router.pid]})
    idle.start()
    await asyncio.sleep(2.0)  # the reference: the lab router with nobody connected
    router_idle = idle.stop()[0]["router"]

    started = time.monotonic()
    lab.start_robots()
    a, b, intruded = lab.names[:3]
    async with Laptops(lab, a, b) as laptops:
        seen = await laptops.wait_alive(lab.names, start_timeout)
        startup_s = time.monotonic() - started
        if missing := [n for n in lab.names if not set(SERVICES) <= seen.get(n, set())]:
            raise RuntimeError(f"not alive after {start_timeout:.0f} s: {missing}\n" + "\n".join(lab.dead()))
        if silent := await laptops.wait_poses(lab.names, start_timeout):
            raise RuntimeError(f"no odom/pose from {silent}\n" + "\n".join(lab.dead()))

        # Each session publishes to its own robot; session A also to robot 2, which is not its robot.
        targets = {a: laptops.a, b: laptops.b, intruded: laptops.a}
        publishers = [session.session.declare_publisher(keys.key(robot, keys.TWIST), encoding=MSGPACK)
                      for robot, session in targets.items()]
        await asyncio.sleep(0.5)  # let the router learn the new publishers

        pids = lab.robot_pids()
        cycles = lab.cycle_pids()
        clocks = {n: SimClockTrace(session, n) for n, session in ((a, laptops.a), (b, laptops.b))}
        for clock in clocks.values():
            await clock.start()
        meter = CpuMeter({"router": [lab.router.pid], "laptop": [os.getpid()],
                          "robots": [p for ps in pids.values() for p in ps], **pids})
        meter.start()
        t0 = time.monotonic()
        sent = await drive(publishers, m.Twist(v=speed, w=0.0), seconds)
        t1 = time.monotonic()
        cpu, machine_pct = meter.stop()
        for pub in publishers:
            pub.undeclare()
        # The deadman stops the driven robots; the last twists reach the guest (or do not).
        await asyncio.sleep(max(lab.config(n).hwbridge.deadman_s for n in lab.names) + SETTLE_S)
        t2, at_rest_ns = time.monotonic(), time.time_ns()
        # The truth at rest is one the simulator published after this moment: on a starved laptop
        # the samples received by now may be seconds old (the robot still under way in them).
        await laptops.wait_truths(lab.names, at_rest_ns, start_timeout)
        for clock in clocks.values():
            await clock.stop()

    crashed = lab.dead()
    now = lab.cycle_pids()
    restarted = [f"{n}: hwbridge's real-time cycle {cycles[n]} is now {now.get(n)}" for n in cycles
                 if now.get(n) != cycles[n]]
    cpu["router idle"] = router_idle
    results = {}
    for n in lab.names:
        config = lab.config(n)
        in_window = [pose for t, pose in laptops.poses[n] if t0 <= t <= t1]
        truth0 = _last(laptops.truths[n], t0)
        truth1 = next((truth for _, truth in laptops.truths[n] if truth.stamp >= at_rest_ns), None)
        stats = [s for t, s in laptops.loops[n] if t0 <= t <= t2]
        cycle_hz, overruns = _cycle_rate(stats)
        heard = laptops.twists_heard[n]
        asked, pace = 0.0, 1.0
        if heard:  # each twist holds the speed until the next, the last one until the deadman
            start, end = heard[0], heard[-1] + config.hwbridge.deadman_s
            span = end - start
            if n in clocks:  # the simulated time that passed meanwhile: the world stands still when it lags
                span = clocks[n].elapsed(start, end)
                pace = min(1.0, span / (end - start))
            asked = speed * span - speed**2 / (2 * config.hwbridge.max_accel)
        results[n] = RobotResult(
            name=n, role=("own credentials" if n in (a, b) else f"{a}'s credentials" if n == intruded
                          else "not driven"),
            configured_hz=config.odometry.rate_hz, poses=len(in_window),
            rate_hz=len(in_window) / (t1 - t0),
            moved_m=math.nan if truth0 is None or truth1 is None
            else math.hypot(truth1.x - truth0.x, truth1.y - truth0.y),
            asked_m=asked, sim_pace=pace, twists_sent=sent if n in targets else 0, twists_heard=len(heard),
            cycle_hz=cycle_hz, overruns=overruns,
            stalled_reads=stats[-1].stalled_reads - stats[0].stalled_reads if stats else 0)
    return Report(rates=lab.rates, speed=speed, window_s=t1 - t0, startup_s=startup_s, seen=seen, robots=results,
                  cpu=cpu, machine_pct=machine_pct, driven=(a, b), intruded=intruded, crashed=crashed,
                  restarted=restarted, mesh=lab.mesh)


class SimClockTrace:
    """The simulator's clock of a robot (whose credentials ``node`` holds) against time.monotonic(),
    sampled every `period` s through ``sim/control``: how much simulated time passed between two instants."""

    period = 0.1

    def __init__(self, node: Node, robot: str) -> None:
        self.node, self.robot = node, robot
        self.samples: list[tuple[float, float]] = []
        """(time.monotonic() when the simulator read its clock, its clock), s."""
        self._task: asyncio.Task[None] | None = None
        self._offset = time.time() - time.monotonic()  # the simulator stamps with the wall clock

    async def _sample(self) -> None:
        state = await self.node.query(keys.SIM_CONTROL, m.SimControl(action="read"), robot=self.robot, timeout=10.0)
        self.samples.append((state.stamp * 1e-9 - self._offset, state.sim_time))

    async def _loop(self) -> None:
        while True:
            await asyncio.sleep(self.period)
            await self._sample()

    async def start(self) -> None:
        await self._sample()
        self._task = asyncio.create_task(self._loop())

    async def stop(self) -> None:
        assert self._task is not None
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task
        await self._sample()

    def at(self, t: float) -> float:
        """The simulator's clock at monotonic time ``t``, interpolated between samples."""
        times = [w for w, _ in self.samples]
        i = min(max(bisect.bisect_left(times, t), 1), len(times) - 1)
        (w0, s0), (w1, s1) = self.samples[i - 1], self.samples[i]
        return s0 + (s1 - s0) * (t - w0) / (w1 - w0) if w1 > w0 else s1

    def elapsed(self, start: float, end: float) -> float:
        return self.at(end) - self.at(start)


def _last(samples: list[tuple[float, Any]], before: float) -> Any:
    """The last message received at or before ``before`` (None if there is none)."""
    older = [msg for t, msg in samples if t <= before]
    return older[-1] if older else None


def _cycle_rate(stats: list[m.LoopStats]) -> tuple[float, int]:
    """Cycle rate and overruns between the first and the last ``hw/loop`` report (counts since start)."""
    if len(stats) < 2:
        return math.nan, 0
    first, last = stats[0], stats[-1]
    return ((last.cycles - first.cycles) / ((last.stamp - first.stamp) * 1e-9),
            last.overruns - first.overruns)


# ---------------------------------------------------------------------------- printing


def print_report(report: Report) -> None:
    r, n, speed = report.rates, len(report.robots), report.speed
    print("topology: " + ("each robot's own router joins the lab router (ws); laptops on the lab router"
                          if report.mesh else "every robot's services and the laptops on the lab router"))
    print(f"rates per robot: sim clock 1000 Hz (fixed), hwbridge cycle {r.cycle_hz:g} Hz, "
          f"serial {r.serial_hz:g} Hz, hw/wheels {r.wheels_hz:g} Hz, odom/pose {r.odom_hz:g} Hz")
    print(f"{n} robots alive {report.startup_s:.1f} s after their processes started, each with "
          f"{', '.join(SERVICES)}")
    print(f"window {report.window_s:.1f} s; the driven robots get {speed} m/s (about "
          f"{speed * report.window_s:.2f} m, and on until the deadman): moved (sim/truth) must be within "
          f"{DISTANCE_TOLERANCE:.0%} of asked\n")
    print(f"{'robot':<12} {'cmd/twist sent with':<24} {'sent':>5} {'through':>8} {'moved m':>8} {'asked m':>8} "
          f"{'poses':>6} {'pose Hz':>8} {'configured':>11} {'':>6} {'cycle Hz':>9} {'overruns':>9} {'stalled':>8}")
    for x in report.robots.values():
        pct = 100 * x.rate_hz / x.configured_hz
        print(f"{x.name:<12} {x.role:<24} {x.twists_sent:>5} {x.twists_heard:>8} {x.moved_m:>8.3f} {x.asked_m:>8.3f} "
              f"{x.poses:>6} {x.rate_hz:>8.1f} {x.configured_hz:>9g} Hz {pct:>5.0f} % "
              f"{x.cycle_hz:>9.1f} {x.overruns:>9} {x.stalled_reads:>8}")
    pace = ", ".join(f"{n} {report.robots[n].sim_pace:.1%}" for n in report.driven)
    print(f"the driven robots' simulators ran at (simulated / wall-clock time; below 100 % they fell behind "
          f"and dropped steps): {pace}")
    print(f"processes crashed: {len(report.crashed)}, hwbridge cycles restarted: {len(report.restarted)}")
    cpu = report.cpu
    print("\nCPU over the window, % of one core:")
    print(f"  lab router                  {cpu['router']:6.1f}   (reference: {cpu['router idle']:.1f} idle, "
          f"before the robots joined; {(cpu['router'] - cpu['router idle']) / n:.2f} per robot)")
    print(f"  all robot processes         {cpu['robots']:6.1f}   ({cpu['robots'] / n:.1f} per robot)")
    for service in (*SERVICES, "hwbridge-rt", "robot router"):
        print(f"    {service:<25} {cpu.get(service, 0.0):6.1f}")
    print(f"  the laptops (this process)  {cpu['laptop']:6.1f}")
    print(f"  whole machine, all users    {report.machine_pct:6.1f} % of {os.cpu_count()} CPUs busy")


def main() -> int:
    if "--router-load" in sys.argv:
        import lab_load

        return lab_load.main([a for a in sys.argv[1:] if a != "--router-load"])
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robots", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=10.0, help="measuring window, s")
    defaults = Rates()
    parser.add_argument("--cycle-hz", type=float, default=defaults.cycle_hz, help="hwbridge.rate_hz")
    parser.add_argument("--serial-hz", type=float, default=defaults.serial_hz, help="hwbridge.serial_rate_hz")
    parser.add_argument("--wheels-hz", type=float, default=defaults.wheels_hz, help="hwbridge.wheels_rate_hz")
    parser.add_argument("--odom-hz", type=float, default=defaults.odom_hz, help="odometry.rate_hz")
    parser.add_argument("--direct", action="store_true",
                        help="no robot routers: every robot's services are clients of the lab router")
    args = parser.parse_args()
    if args.robots < 3:
        parser.error("--robots: at least 3 (two driven, one to try with the wrong credentials)")
    print(f"$ {' '.join([Path(sys.executable).name, *sys.argv])}")
    rates = Rates(args.cycle_hz, args.serial_hz, args.wheels_hz, args.odom_hz)
    with tempfile.TemporaryDirectory() as tmp, Lab(Path(tmp), args.robots, rates, mesh=not args.direct) as lab:
        lab.start_router()
        report = asyncio.run(measure(lab, args.seconds, start_timeout=30.0 + 6.0 * args.robots))
    print_report(report)
    failures = report.failures()
    for line in failures:
        print(f"FAIL {line}")
    print("\nall checks passed" if not failures else f"\n{len(failures)} checks failed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

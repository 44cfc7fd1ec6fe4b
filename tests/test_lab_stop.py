"""The lab's emergency stop (docs/lab.md): the TA stops one robot or every robot, may hold them
stopped until released, and may do nothing else.

First the parts, pure: the lab's folder, the names asked, and the access rules as the routers
decide them (`router.permits`). Then one simulated lab for the module, real processes throughout
(`bench/lab_harness.Lab`, ``mesh=True``): the lab router (``icefloe router --lab``, a TA's
credentials file in its folder), three robots each with its own router joined to it; robot 0 runs
``sim``, ``hwbridge``, ``odometry``, ``power``, ``oled`` and ``webapi``, robots 1 and 2 ``sim`` and
``hwbridge``. The TA uses the real command (``icefloe lab stop`` in a process), the owners drive
from sessions of their own as a student's program does, and every effect is read on the robot
itself: the simulator's truth and the board's duty (``sim/control``), hwbridge's targets
(``hw/wheels``), the power-off command, the odometry, the hold it says (``hw/hold``), its log, its
OLED frame and its web page.

About 90-170 s on this shared 2-core machine at load average 9-15 from other work, 5-6 min at 20-25
(the lab starts in 12-26 s).
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import math
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from conftest import ROOT, free_port, wait_for
from test_security import laptop, wildcard_forms

from icefloe import labstop
from icefloe.config import RobotConfig
from icefloe.credentials import Credentials, make, read
from icefloe.errors import EXIT_CONFIG, BadPayload, ConfigError, NotReachable
from icefloe.router import access_control, permits
from icefloe.runtime import MSGPACK, Node
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

sys.path.insert(0, str(ROOT / "bench"))
from lab_harness import Lab

STANDSTILL_S = 1.5
"""From zero duty on the board to the wheels standing, simulated s. bench/stops.py measured the
whole stop (issued -> standstill) at 0.38-0.84 s from 0.2 m/s (docs/hwbridge.md); this is about
twice that, from the slower 0.15 m/s the owners drive at here."""
STILL_S = 0.3
"""Wheels whose counts have not changed for this long (simulated s) stand."""
LAB_TIMEOUT_S = 10.0
"""How long each robot has to confirm a stop here (``[lab] timeout``; 1 s by default; at most 10 s):
on this shared 2-core machine a starved simulator's board answers late (docs/lab.md has the
figures; with the suite beside other work at load 15-19, two of three releases took over 5 s)."""
SETTLE_TICKS = 2
"""Counts a wheel that has just stood may still turn at zero duty, settling (seen once: one count,
0.3 s after the last); a wheel driven at `SPEED` turns hundreds of counts a second."""
SPEED = 0.15
"""m/s the owners' programs drive at ..."""
TURN = 0.75
"""... turning at this, rad/s: circles of 0.2 m, which keep the robots off the lab world's walls."""


# ---------------------------------------------------------------------------- the parts, pure


def ta_file(folder: Path, connect: list[str], user: str = "ta") -> Path:
    """A TA's credentials file as docs/lab.md makes one: robot "*", a user of its own."""
    path, _ = make(folder / f"{user}.credentials", "*", connect)
    path.write_text(path.read_text().replace('user = "*"', f'user = "{user}"'))
    return path


def test_the_labs_folder_names_its_robots_and_its_ta(tmp_path: Path) -> None:
    for robot in ("p1", "p2"):
        make(tmp_path / f"{robot}.credentials", robot)
    make(tmp_path / "lab.credentials", "lab")  # the lab's own login (its localizer): no robot
    ta = ta_file(tmp_path, ["tcp/10.0.0.1:7447"])
    folder = labstop.lab_folder(tmp_path, "lab")
    assert folder.robots == ["p1", "p2"] and folder.ta == [ta]
    config, who = labstop.ta_config(RobotConfig(name="lab"), folder)
    assert (config.zenoh.user, config.zenoh.connect, who) == ("ta", ["tcp/10.0.0.1:7447"], f"ta ({ta})")
    assert labstop.ta_config(RobotConfig(), folder, connect=["tcp/1.2.3.4:7447"])[0].zenoh.connect == \
        ["tcp/1.2.3.4:7447"]
    ta_file(tmp_path, [], user="ta2")
    with pytest.raises(ConfigError, match=r"2 TA credentials files .* say which with --credentials"):
        labstop.ta_config(RobotConfig(), labstop.lab_folder(tmp_path, "lab"))
    with pytest.raises(ConfigError, match="no such folder"):
        labstop.lab_folder(tmp_path / "nowhere", "lab")
    for bad in ("*", "p$*", "**", "p1/cmd", ""):
        with pytest.raises(ConfigError, match="name one robot"):
            labstop.check_names(["p1", bad])


def test_icefloe_lab_refuses_a_bad_argument_in_one_line_before_it_asks_anything(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The command's own entry point, in this process (a Python start per case costs seconds here)."""
    from icefloe.cli import main

    make(tmp_path / "p1.credentials", "p1")
    ta_file(tmp_path, ["tcp/127.0.0.1:1"])  # nobody listens there: nothing may be asked
    for args, wrong in ((["--robot", "p$*"], "robot 'p$*': name one robot"), (["--robot", "**"], "name one robot"),
                        (["--reason", "x" * 61], "--reason"), (["--timeout", "0"], "--timeout"),
                        (["--timeout", "11"], "--timeout")):
        assert main(["lab", "stop", "--lab", str(tmp_path), *args]) == EXIT_CONFIG, args
        out, err = capsys.readouterr()
        assert wrong in err and len(err.strip().splitlines()) == 1 and out == "", (args, out, err)


KEYS_OF_A_ROBOT = (keys.TWIST, keys.WHEELS_CMD, keys.STOP, keys.NAV_PATH, keys.LEDS, keys.OLED_TEXT,
                   keys.MOTION, keys.HALT, keys.LAB_STOP, keys.RELEASE, keys.ODOM_RESET, keys.SHUTDOWN_REQUEST,
                   keys.SIM_CONTROL, keys.HOLD, keys.ODOM_POSE, keys.EXTLOC_POSE)


def allowed(acl: dict, user: str, robot: str) -> set[tuple[str, str]]:
    """Every (message, key name) ``user`` may send on ``robot``'s concrete keys."""
    return {(message, topic.name) for topic in KEYS_OF_A_ROBOT for message in ("put", "delete", "query")
            if permits(acl, user, message, keys.key(robot, topic))}


def test_the_access_rules_give_the_ta_the_stop_and_nothing_else() -> None:
    """The lab router's rules, and a robot's own, as the routers decide them (`permits` does as
    Zenoh does; tests/test_security.py checks that on real routers, and the tests below check the
    effects on real robots)."""
    lab = access_control([("p1", "p1"), ("p2", "p2"), ("*", "ta")])
    robot = access_control([("p1", "p1")], lab_protocols=["ws"])
    stop = {("put", "cmd/stop"), ("query", "lab/stop"), ("query", "sim/control")}
    assert allowed(lab, "ta", "p1") == allowed(lab, "ta", "p2") == stop
    assert allowed(robot, "ta", "p1") == set()  # a robot's own router does not know the TA
    # Every wildcard form of a key the TA may not use is refused, on any robot.
    for topic in KEYS_OF_A_ROBOT:
        for form in wildcard_forms(keys.key("p1", topic)):
            for message in ("put", "delete", "query"):
                if permits(lab, "ta", message, form):
                    assert (message, topic.name) in stop, (message, form)
    assert not permits(lab, "ta", "liveliness_token", keys.alive_key("p1", "fake"))
    assert not permits(lab, "ta", "declare_queryable", keys.key("p1", keys.LAB_STOP))
    # The owner keeps everything of its robot but its lab/** (the TA's) and extloc/** (the lab's),
    # and cmd/release is the owner's own way out; nothing of another robot; the guest nothing.
    for acl in (lab, robot):
        owner = allowed(acl, "p1", "p1")
        assert ("query", "lab/stop") not in owner and ("put", "lab/stop") not in owner
        assert {("query", "cmd/release"), ("put", "cmd/stop"), ("put", "cmd/twist")} <= owner
        assert not permits(acl, "p1", "query", "icefloe/p1/lab/*")
        assert allowed(acl, "guest", "p1") == set()
    assert allowed(lab, "p1", "p2") == set()
    assert permits(lab, "p1", "declare_queryable", keys.key("p1", keys.LAB_STOP))  # hwbridge serves it


# ---------------------------------------------------------------------------- the lab


@dataclass
class StopLab:
    lab: Lab
    ta: Credentials
    ta_path: Path
    powered_off: Path
    page_port: int
    webapi_port: int

    @property
    def names(self) -> list[str]:
        return self.lab.names

    def owner(self, name: str) -> Node:
        """A student's laptop on the lab router with ``name``'s credentials."""
        creds = read(self.lab.credentials_file(name))
        return laptop(self.lab.endpoint, creds.user, creds.password, robot=name)

    def as_ta(self) -> Node:
        return laptop(self.lab.endpoint, self.ta.user, self.ta.password)

    def cli(self, *args: str) -> subprocess.CompletedProcess[str]:
        """``icefloe lab ...`` as the TA types it on the lab machine."""
        return subprocess.run([sys.executable, "-m", "icefloe.cli", "lab", *args, str(self.lab.lab_config)],
                              capture_output=True, text=True, timeout=90, cwd=ROOT)


ROBOT0_SERVICES = ("sim", "hwbridge", "odometry", "power", "oled", "webapi")
OTHER_SERVICES = ("sim", "hwbridge")


@pytest.fixture(scope="module")
def stoplab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StopLab]:
    root = tmp_path_factory.mktemp("labstop")
    flag, webapi_port, page_port = root / "powered-off", free_port(), free_port()

    def robot0_toml(i: int, name: str) -> str:
        return (f'[power]\npoweroff_command = ["touch", "{flag}"]\n\n'
                f'[webapi]\nhost = "127.0.0.1"\nport = {webapi_port}\n') if i == 0 else ""

    with Lab(root, robots=3, mesh=True, services=OTHER_SERVICES, extra_toml=robot0_toml) as lab:
        ta_path = ta_file(lab.lab_dir, [lab.endpoint])
        with lab.lab_config.open("a") as f:
            f.write(f'\n[lab]\nfolder = "{lab.lab_dir}"\ntimeout = {LAB_TIMEOUT_S}\npage_host = "127.0.0.1"\n'
                    f"page_port = {page_port}\n")
        lab.start_router()
        assert "TA account ta" in lab.router.log.read_text()
        first, *others = lab.names
        lab.start_robot(first, services=ROBOT0_SERVICES)
        for name in others:
            lab.start_robot(name)
        stop_lab = StopLab(lab, read(ta_path), ta_path, flag, page_port, webapi_port)
        asyncio.run(_wait_ready(stop_lab))
        yield stop_lab
    assert lab.killed == [], f"these did not stop on SIGINT: {lab.killed}"


async def _wait_ready(stop_lab: StopLab) -> None:
    """Every service of every robot seen alive through the lab router, each simulator answering."""
    want = {keys.alive_key(stop_lab.names[0], s) for s in ROBOT0_SERVICES}
    want |= {keys.alive_key(name, s) for name in stop_lab.names[1:] for s in OTHER_SERVICES}
    async with stop_lab.as_ta() as ta:
        deadline = time.monotonic() + 120
        while not want <= set(await ta.alive("*")):
            assert time.monotonic() < deadline, f"not alive: {want - set(await ta.alive('*'))}\n" + \
                "\n".join(stop_lab.lab.dead())
            await asyncio.sleep(0.5)
        for name in stop_lab.names:
            await sim_state(ta, name)


async def sim_state(node: Node, robot: str, timeout: float = 60.0) -> m.SimState:
    """The robot's simulator's state (``sim/control`` read, as the TA or its owner); waits for a
    simulator that does not answer yet."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return await node.query(keys.SIM_CONTROL, m.SimControl(), timeout=5.0, robot=robot)
        except NotReachable:
            assert time.monotonic() < deadline, f"{robot}'s simulator does not answer"
            await asyncio.sleep(0.3)


class Program:
    """A student's program: the owner's session puts ``cmd/twist`` ten times a second until stopped."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.sent = 0
        self._task = asyncio.create_task(self._run())

    async def _run(self) -> None:
        twist = self.node.publisher(keys.TWIST)
        while True:
            twist.put(self.node.command(m.Twist, v=SPEED, w=TURN))
            self.sent += 1
            await asyncio.sleep(0.1)

    async def stop(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task
        self.node.publisher(keys.STOP).put(self.node.command(m.Stop))


async def reset_worlds(ta: Node, robots: list[str]) -> None:
    """Every robot back at the origin of its world, at rest (the TA's `sim/control`)."""
    for robot in robots:
        await sim_state(ta, robot)
        await ta.query(keys.SIM_CONTROL, m.SimControl(action="reset"), timeout=5.0, robot=robot)


async def moving(ta: Node, robot: str, timeout: float = 30.0) -> None:
    """Until the robot's wheels truly turn."""
    deadline = time.monotonic() + timeout
    while max((s := await sim_state(ta, robot)).speed_left, s.speed_right) < 0.5 * SPEED:
        assert time.monotonic() < deadline, f"{robot} does not move: {s}"
        await asyncio.sleep(0.1)


async def standing(ta: Node, robot: str, asked: float, timeout: float = 30.0) -> m.SimState:
    """Until the robot's wheels stand (no count for `STILL_S` of simulated time); checks that the
    board's duty went to zero after ``asked`` (the simulator's time when the stop was asked) and
    the wheels stood within `STANDSTILL_S` of it."""
    deadline = time.monotonic() + timeout
    while True:
        s = await sim_state(ta, robot)
        if s.zero_duty_since >= 0 and s.sim_time - s.counts_changed >= STILL_S:
            break
        assert time.monotonic() < deadline, f"{robot} did not stop: {s}"
        await asyncio.sleep(0.1)
    assert s.zero_duty_since >= asked, f"{robot}: zero duty since {s.zero_duty_since}, before the stop at {asked}"
    assert s.counts_changed - s.zero_duty_since <= STANDSTILL_S, \
        f"{robot}: stood {s.counts_changed - s.zero_duty_since:.3f} s after the board's zero duty"
    return s


async def stays_still(ta: Node, robot: str, seconds: float = 1.0) -> None:
    """For ``seconds`` of the robot's simulated time: no duty on the board, and the wheels do not
    turn (at most `SETTLE_TICKS` counts), while its owner's program keeps driving."""
    await ta.query(keys.SIM_CONTROL, m.SimControl(action="mark"), timeout=5.0, robot=robot)
    start = await sim_state(ta, robot)
    while (s := await sim_state(ta, robot)).sim_time < start.sim_time + seconds:
        await asyncio.sleep(0.1)
    assert s.peak_duty == 0.0, f"{robot}: duty {s.peak_duty} while held"
    turned = max(abs(s.ticks_left - start.ticks_left), abs(s.ticks_right - start.ticks_right))
    assert turned <= SETTLE_TICKS, f"{robot} moved while held: {turned} counts"


async def hold_of(node: Node, robot: str) -> m.Hold:
    """The robot's next ``hw/hold`` (hwbridge says it at each change and once a second)."""
    sub = node.subscribe(keys.HOLD, robot=robot)
    try:
        return await asyncio.wait_for(anext(sub), 5.0)
    finally:
        sub.close()


def lines_of(done: subprocess.CompletedProcess[str]) -> dict[str, str]:
    """``robot -> its line`` of ``icefloe lab``'s output."""
    return {line.split(":")[0]: line for line in done.stdout.splitlines() if ": " in line}


# ---------------------------------------------------------------------------- the TA stops, holds, releases


@pytest.mark.slow
@pytest.mark.timeout(300)
async def test_the_ta_stops_every_robot_holds_one_or_all_and_a_held_robot_ignores_its_owner(
        stoplab: StopLab) -> None:
    r0, r1, r2 = stoplab.names
    async with stoplab.as_ta() as ta, contextlib.AsyncExitStack() as stack:
        owners = {name: await stack.enter_async_context(stoplab.owner(name)) for name in stoplab.names}
        log = owners[r0].subscribe(keys.LOG, latest=False, maxsize=1000, robot=r0)

        await ta_stop(ta, stoplab, "release")  # whatever an earlier test left
        await reset_worlds(ta, stoplab.names)

        # 1. Every owner runs a timed motion; the TA's plain stop ends each (as cmd/stop does).
        motions = [asyncio.ensure_future(node.query(keys.MOTION, node.command(
            m.Motion, left=0.5 * SPEED, right=1.5 * SPEED, duration=30.0), timeout=40.0)) for node in owners.values()]
        for name in stoplab.names:
            await moving(ta, name)
        asked = {name: (await sim_state(ta, name)).sim_time for name in stoplab.names}
        done = stoplab.cli("stop")
        assert done.returncode == 0, done.stdout + done.stderr
        said = lines_of(done)
        for name in stoplab.names:
            assert "confirmed in" in said[name] and "held" not in said[name], done.stdout
        assert "3 of 3 robots stopped and confirmed" in done.stdout
        for name in stoplab.names:
            await standing(ta, name, asked[name])
        for motion in motions:  # cut short by the stop, and said so
            assert not (await motion).completed

        # 2. The students' programs drive on and on; the TA holds robot 0 only.
        programs = [Program(node) for node in owners.values()]
        for name in stoplab.names:
            await moving(ta, name)
        asked = (await sim_state(ta, r0)).sim_time
        done = stoplab.cli("stop", "--robot", r0, "--hold", "--reason", "see me at the desk")
        assert done.returncode == 0 and f"{r0}: confirmed in" in done.stdout and ", held" in done.stdout, done.stdout
        await standing(ta, r0, asked)
        await stays_still(ta, r0)  # its owner's twists keep coming: refused
        for name in (r1, r2):  # the others drive on
            assert (await sim_state(ta, name)).speed_right > 0.5 * SPEED
        hold = await hold_of(owners[r0], r0)
        assert hold.held and hold.reason == "see me at the desk" and not hold.owner_may_release

        # What the robot says while held: its log, its OLED, its web page.
        lines: list[str] = []
        await wait_for_line(log, lines, "held stopped by the lab's TA (see me at the desk): motion commands are "
                                        "refused until the lab's TA releases it")
        await wait_for_line(log, lines, "cmd/twist: not applied: the robot is held stopped by the lab's TA")
        await oled_shows_the_hold(owners[r0], r0, hold)
        await page_shows_the_hold(stoplab)

        # 3. The owner may not release it: cmd/release is refused, and the TA's lab/stop too.
        with pytest.raises(BadPayload, match="refused: the robot is held stopped by the lab's TA"):
            await owners[r0].query(keys.RELEASE, owners[r0].command(m.Release), timeout=5.0)
        with pytest.raises(NotReachable):
            await owners[r0].query(keys.LAB_STOP, owners[r0].command(m.LabStop, action="release"), timeout=2.0)
        assert (await hold_of(ta, r0)).held

        # 4. Every robot held at once (the same call as the command's, from the TA's session here);
        #    then robot 1 released: its program drives it again.
        asked = {name: (await sim_state(ta, name)).sim_time for name in (r1, r2)}
        answers = await ta_stop(ta, stoplab, "hold")
        assert [(a.robot, a.confirmed, a.held) for a in answers] == [(n, True, True) for n in stoplab.names], answers
        for name in (r1, r2):
            await standing(ta, name, asked[name])
        await asyncio.gather(*(stays_still(ta, name) for name in stoplab.names))
        [answer] = await ta_stop(ta, stoplab, "release", [r1])
        assert answer.confirmed and not answer.held, answer
        await moving(ta, r1)
        assert not (await hold_of(ta, r1)).held

        # 5. A hold the owners may release: robot 2's owner does, and its program drives it again.
        [answer] = await ta_stop(ta, stoplab, "hold", [r2], owner_may_release=True)
        assert answer.confirmed and answer.held, answer
        assert (await hold_of(ta, r2)).owner_may_release
        released = await owners[r2].query(keys.RELEASE, owners[r2].command(m.Release), timeout=5.0)
        assert not released.held
        await moving(ta, r2)

        # 6. Every hold released (robot 0's too): it drives on its owner's next twist. (From the TA's
        #    session here, as `icefloe lab release` does: each run of the command is Python starting.)
        answers = await ta_stop(ta, stoplab, "release")
        assert [(a.confirmed, a.held) for a in answers] == [(True, False)] * 3, answers
        assert answers[1].detail == "was not held" and "(was not held)" in answers[1].line(), answers
        await moving(ta, r0)
        for program in programs:
            await program.stop()
        for name in stoplab.names:
            await standing(ta, name, -1.0)


async def ta_stop(ta: Node, stoplab: StopLab, action: str, robots: list[str] | None = None,
                  owner_may_release: bool = False) -> list[labstop.Answer]:
    """What `icefloe lab stop` does (`labstop.stop`), from the TA's session in this process."""
    request = ta.command(m.LabStop, action=action, owner_may_release=owner_may_release, timeout=LAB_TIMEOUT_S)
    return await labstop.stop(ta, request, robots or (), [] if robots else stoplab.names)


async def wait_for_line(log: Any, lines: list[str], text: str, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not any(text in line for line in lines):
        assert time.monotonic() < deadline, f"no log line with {text!r}: {lines[-10:]}"
        with contextlib.suppress(TimeoutError):
            lines.append((await asyncio.wait_for(anext(log), 1.0)).text)


async def oled_shows_the_hold(node: Node, robot: str, hold: m.Hold) -> None:
    """The OLED service's frame is the hold's screen, whichever screen was chosen."""
    from icefloe.services.oled.frame import Frame
    from icefloe.services.oled.screens import Status, render

    want = render(0, Status(hold=hold)).pack()
    frames = node.subscribe(keys.OLED_FRAME, robot=robot)
    deadline = time.monotonic() + 10
    while (frame := await asyncio.wait_for(anext(frames), 5.0)).pixels != want:
        assert time.monotonic() < deadline, f"the OLED does not show the hold:\n{Frame.unpack(frame.pixels).ascii()}"
    frames.close()


async def page_shows_the_hold(stoplab: StopLab) -> None:
    """The robot's web page (its web API, read as the guest) says it is held and will not drive."""
    from browser import chromium

    async with chromium(stoplab.lab.root / "robot-page-profile") as context:
        page = await context.new_page()
        await page.goto(f"http://127.0.0.1:{stoplab.webapi_port}/")
        await page.wait_for_selector("#hold:not([hidden])", timeout=60_000)  # Chromium starts slowly on a busy machine
        assert "held stopped by the lab's TA: see me at the desk" in await page.inner_text("#hold")
        assert "driving is refused" in await page.inner_text("#drive-state")


# ---------------------------------------------------------------------------- the lab's page, teleop's key


@pytest.mark.slow
@pytest.mark.timeout(300)
async def test_the_labs_page_and_teleops_key_hold_every_robot(stoplab: StopLab) -> None:
    """The lab's page (``python -m icefloe.services.labpage --config lab.toml``, as the TA's browser
    sees it) holds every robot with its button and releases them with another; the ``!`` key of
    the TA's ``icefloe teleop`` holds them all too. The owners' programs drive all along."""
    from browser import chromium
    from lab_harness import Proc
    from terminal import Terminal

    lab = stoplab.lab
    page = Proc("labpage", [sys.executable, "-m", "icefloe.services.labpage", "--config", str(lab.lab_config)],
                lab.root / "labpage.log")
    term: Terminal | None = None
    async with stoplab.as_ta() as ta, contextlib.AsyncExitStack() as stack:
        try:
            await ta_stop(ta, stoplab, "release")  # whatever an earlier test left
            await reset_worlds(ta, stoplab.names)
            owners = [await stack.enter_async_context(stoplab.owner(name)) for name in stoplab.names]
            programs = [Program(node) for node in owners]
            for name in stoplab.names:
                await moving(ta, name)
            await wait_for(lambda: "the lab's page on" in page.log.read_text() or not page.alive(), 60)
            assert page.alive(), page.tail()
            login = base64.b64encode(f"{stoplab.ta.user}:{stoplab.ta.password}".encode()).decode()
            async with chromium(lab.root / "lab-page-profile") as context:
                browser = await context.new_page()
                await browser.set_extra_http_headers({"Authorization": f"Basic {login}"})
                await browser.goto(f"http://127.0.0.1:{stoplab.page_port}/")
                await browser.wait_for_function(  # every robot listed, alive
                    "document.querySelectorAll('#robots tbody td.ok').length >= 3", timeout=60_000)
                await browser.fill("#reason", "hands off, please")
                asked = {name: (await sim_state(ta, name)).sim_time for name in stoplab.names}
                await browser.click("#hold-all")
                await browser.wait_for_function("document.querySelector('#summary').className !== ''",
                                                timeout=60_000)
                summary = await browser.inner_text("#summary")
                assert summary == "3 of 3 robots held stopped and confirmed", summary
                for name in stoplab.names:  # held (the first test checks that a held robot stays still)
                    await standing(ta, name, asked[name])
                    assert (await hold_of(ta, name)).reason == "hands off, please"
                await browser.wait_for_function(
                    "document.querySelectorAll('#robots tbody td.held').length === 3", timeout=30_000)
                await browser.click("#release-all")
                await browser.wait_for_function(
                    "document.querySelector('#summary').textContent.includes('released')", timeout=60_000)
                assert await browser.inner_text("#summary") == "3 of 3 robots released and confirmed"
            for name in stoplab.names:
                await moving(ta, name)

            # The TA's teleop: its ! key holds every robot alive on the bus.
            term = await asyncio.to_thread(
                Terminal, [sys.executable, "-m", "icefloe.cli", "teleop", "--config", str(lab.lab_config),
                           "--credentials", str(stoplab.ta_path), "--robot", stoplab.names[0]], cwd=ROOT)
            await asyncio.to_thread(term.wait_for, "driving", 30)
            asked = {name: (await sim_state(ta, name)).sim_time for name in stoplab.names}
            term.send("!")
            await asyncio.to_thread(term.wait_for, "robots held stopped and confirmed", 30)
            assert "lab stop: 3 of 3 robots held stopped and confirmed" in term.text, term.text
            for name in stoplab.names:
                assert f"lab stop: {name}: confirmed in" in term.text, term.text
            for name in stoplab.names:
                await standing(ta, name, asked[name])
                assert (await hold_of(ta, name)).reason == "teleop's ! key"
            term.ctrl_c()
            assert await asyncio.to_thread(term.wait, 15) == 0, term.text
            answers = await ta_stop(ta, stoplab, "release")
            assert [(a.confirmed, a.held) for a in answers] == [(True, False)] * 3, answers
            for program in programs:
                await program.stop()
        finally:
            if term is not None:
                term.kill()
            page.interrupt()
            assert page.wait(15.0), page.tail()
    print(f"\nthe lab's page: {summary}")


# ---------------------------------------------------------------------------- a robot off the network


@pytest.mark.slow
@pytest.mark.timeout(300)
async def test_a_robot_whose_router_is_down_is_named_not_forgotten(stoplab: StopLab) -> None:
    r0, r1, r2 = stoplab.names
    lab = stoplab.lab
    router = next(p for p in lab.procs[r2] if p.name.endswith("/router"))
    router.interrupt()
    assert router.wait(15.0)
    try:
        done = stoplab.cli("stop")
        assert done.returncode == 1, done.stdout + done.stderr
        said = lines_of(done)
        assert "confirmed in" in said[r0] and "confirmed in" in said[r1], done.stdout
        assert f"{r2}: NOT confirmed" in said[r2], done.stdout
        assert f"2 of 3 robots stopped and confirmed; NOT confirmed: {r2}" in done.stdout
    finally:  # its router again: the robot's services and the lab link come back by themselves
        lab.procs[r2].remove(router)
        lab.procs[r2].insert(0, lab._start_robot_router(r2))
        async with laptop(lab.endpoint) as guest:
            deadline = time.monotonic() + 60
            while keys.alive_key(r2, "hwbridge") not in await guest.alive(r2):
                assert time.monotonic() < deadline, "robot 2 did not come back"
                await asyncio.sleep(0.5)


# ---------------------------------------------------------------------------- hostile


@dataclass
class Targets:
    """Robot 0's commanded wheel targets (``hw/wheels``), as hwbridge applies them."""

    low: float = math.inf
    samples: int = 0

    def see(self, wheels: m.Wheels) -> None:
        self.low = min(self.low, wheels.target_left, wheels.target_right)
        self.samples += 1


@pytest.mark.slow
@pytest.mark.timeout(300)
async def test_the_tas_credentials_stop_and_do_nothing_else_and_nobody_else_stops(stoplab: StopLab) -> None:
    r0, r1, _r2 = stoplab.names
    async with stoplab.as_ta() as ta, stoplab.owner(r0) as owner, stoplab.owner(r1) as neighbour, \
            laptop(stoplab.lab.endpoint) as guest:
        await ta_stop(ta, stoplab, "release")  # whatever an earlier test left
        await reset_worlds(ta, stoplab.names)
        poses = owner.subscribe(keys.ODOM_POSE)
        pose_before = await asyncio.wait_for(anext(poses), 10)
        await ta.query(keys.SIM_CONTROL, m.SimControl(action="mark"), timeout=5.0, robot=r0)
        start = await sim_state(ta, r0)

        # 1. The TA's credentials: drive, reset, power off, release, forge; by the key and by every
        #    wildcard form. None of it may move, reset, power off or hold robot 0 (or any robot).
        attempts = 0
        replies: list[str] = []
        pending = []
        forged = ((keys.TWIST, m.Twist(v=0.3, w=0.0)), (keys.WHEELS_CMD, m.WheelSpeeds(left=0.3, right=0.3)),
                  (keys.CAR, m.CarDrive(v=0.3, steer=0.2)),
                  (keys.NAV_PATH, m.NavPath(points=[m.Waypoint(x=1.0, y=0.0)])),
                  (keys.HOLD, m.Hold(stamp=1, held=True)), (keys.ODOM_POSE, m.Pose(stamp=1, x=999.0, y=0.0, theta=0.0)))
        for topic, payload in forged:
            for form in wildcard_forms(keys.key(r0, topic)):
                ta.session.put(form, codec.encode(payload), encoding=MSGPACK)
                ta.session.delete(form)
                attempts += 2
        for topic, request in ((keys.ODOM_RESET, m.PoseReset(x=1000.0)), (keys.SHUTDOWN_REQUEST, m.ShutdownRequest()),
                               (keys.MOTION, m.Motion(left=0.3, right=0.3, duration=1.0)), (keys.HALT, m.Halt()),
                               (keys.RELEASE, m.Release())):
            for form in wildcard_forms(keys.key(r0, topic)):
                pending.append((form, ta.session.get(form, payload=codec.encode(request), encoding=MSGPACK,
                                                     timeout=3.0)))
                attempts += 1
        # lab/stop and cmd/stop on wildcards pass the lab router (they are the TA's keys), and every
        # robot drops them: a hold asked that way holds nothing.
        for form in wildcard_forms(keys.key(r0, keys.LAB_STOP)):
            if form != keys.key(r0, keys.LAB_STOP):
                pending.append((form, ta.session.get(form, payload=codec.encode(m.LabStop(action="hold")),
                                                     encoding=MSGPACK, timeout=3.0)))
                attempts += 1
        token = ta.session.liveliness().declare_token(keys.alive_key(r0, "fake"))
        await asyncio.to_thread(lambda: [replies.extend(f"{form}: {r.ok or r.err}" for r in got)
                                         for form, got in pending])
        await asyncio.sleep(1.5)
        assert replies == [], f"the TA's queries got answers: {replies[:5]}"
        after = await sim_state(ta, r0)
        assert after.peak_duty == 0.0 and (after.ticks_left, after.ticks_right) == (start.ticks_left,
                                                                                      start.ticks_right)
        assert math.hypot(after.x - start.x, after.y - start.y) < 0.002
        assert not stoplab.powered_off.exists(), "the TA powered robot 0 off"
        pose_after = await asyncio.wait_for(anext(poses), 10)
        assert abs(pose_after.x - pose_before.x) < 0.01, f"odometry reset by the TA: {pose_after}"
        assert not (await hold_of(owner, r0)).held and not (await hold_of(owner, r1)).held
        assert keys.alive_key(r0, "fake") not in await owner.alive("*")
        token.undeclare()

        # 2. Robot 0's owner drives; the guest and robot 1's owner put cmd/stop and ask lab/stop
        #    (hold), cmd/halt and cmd/release in every form: hwbridge's targets never drop to zero.
        program = Program(owner)
        await moving(ta, r0)
        targets = Targets()
        watch = asyncio.create_task(follow(owner.subscribe(keys.WHEELS, latest=False, maxsize=10_000), targets))
        await wait_for(lambda: targets.samples > 0)
        pending = []
        for attacker in (guest, neighbour):
            for _round in range(3):
                for form in wildcard_forms(keys.key(r0, keys.STOP)):
                    attacker.session.put(form, codec.encode(m.Stop()), encoding=MSGPACK)
                for topic, request in ((keys.LAB_STOP, m.LabStop(action="hold")), (keys.HALT, m.Halt(rest=False)),
                                       (keys.RELEASE, m.Release())):
                    for form in wildcard_forms(keys.key(r0, topic)):
                        pending.append((form, attacker.session.get(form, payload=codec.encode(request),
                                                                   encoding=MSGPACK, timeout=2.0)))
                await asyncio.sleep(0.3)
        await asyncio.to_thread(lambda: [replies.extend(f"{form}: {r.ok or r.err}" for r in got)
                                         for form, got in pending])
        await asyncio.sleep(1.0)
        watch.cancel()
        assert targets.samples > 20 and targets.low > 0.25 * SPEED, \
            f"robot 0's targets fell to {targets.low} while the guest and its neighbour sent stops"
        assert replies == [], f"the attackers' queries got answers: {replies[:5]}"
        assert not (await hold_of(owner, r0)).held
        # The TA's own cmd/stop on robot 0's key does stop it: it cuts its owner's timed motion short.
        await program.stop()
        await standing(ta, r0, -1.0)  # so that moving, below, is the motion's doing
        motion = asyncio.ensure_future(owner.query(keys.MOTION, owner.command(
            m.Motion, left=0.5 * SPEED, right=1.5 * SPEED, duration=30.0), timeout=40.0))
        await moving(ta, r0)
        asked = (await sim_state(ta, r0)).sim_time
        ta.publisher(keys.STOP, robot=r0).put(ta.command(m.Stop))
        cut = await motion
        assert not cut.completed and "cmd/stop" in cut.reason, cut
        await standing(ta, r0, asked)
        program = Program(owner)
        await moving(ta, r0)

        # 3. The TA holds robot 0; its owner tries to release it by every form of lab/stop (the
        #    router refuses the key, the services the wildcards) and by cmd/release: still held.
        [answer] = await ta_stop(ta, stoplab, "hold", [r0])
        assert answer.confirmed and answer.held, answer
        pending = [(form, owner.session.get(form, payload=codec.encode(m.LabStop(action="release")),
                                            encoding=MSGPACK, timeout=2.0))
                   for form in wildcard_forms(keys.key(r0, keys.LAB_STOP))]
        got = await asyncio.to_thread(lambda: [f"{f}: {r.ok or r.err}" for f, rs in pending for r in rs])
        assert got == [], got
        with pytest.raises(BadPayload, match="refused"):
            await owner.query(keys.RELEASE, owner.command(m.Release), timeout=5.0)
        assert (await hold_of(owner, r0)).held
        await stays_still(ta, r0)
        [answer] = await ta_stop(ta, stoplab, "release", [r0])
        assert answer.confirmed and not answer.held, answer
        await moving(ta, r0)
        await program.stop()
    assert stoplab.lab.dead() == [], stoplab.lab.dead()
    print(f"\nthe TA's credentials: {attempts} attempts on {r0}, none moved, reset, powered off or held it")


async def follow(sub: Any, targets: Targets) -> None:
    async for wheels in sub:
        targets.see(wheels)

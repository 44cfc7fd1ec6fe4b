"""The hostile suite: a student tries to drive, stop, reset, power off or impersonate a robot
that is not theirs, over Zenoh and HTTP, on the robot's router and through the lab mesh.

One lab for the module, real processes throughout (`bench/lab_harness.Lab`, ``mesh=True``):
a lab router (``icefloe router --lab``), robot V with its own router joined to it and real
``sim``, ``hwbridge``, ``odometry``, ``power``, ``info`` and ``webapi`` services, and robot O
whose router alone joins the lab (its owner is the attacker next door). Every attack is
checked on the robot itself: the simulator's truth (no motion), the power-off command (never
run), what V's own sessions receive (no forged message, no query), the tokens V's owner sees.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import math
import os
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp
import msgspec
import pytest
import zenoh
from conftest import ROOT, Robot, free_port, wait_for

from icefloe import config as config_mod
from icefloe.client import AsyncRobot
from icefloe.config import private_dir
from icefloe.credentials import GUEST_PASSWORD, GUEST_USER, Credentials, read
from icefloe.errors import EXIT_CONFIG, ConfigError, NotReachable
from icefloe.graph import read as read_graph
from icefloe.runtime import MSGPACK, Node
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

sys.path.insert(0, str(ROOT / "bench"))
from lab_harness import Lab

VICTIM_SERVICES = ("sim", "hwbridge", "odometry", "power", "info", "webapi")
STILL_M = 0.002
"""A robot nobody may drive moves less than this (the simulator adds no noise), m."""
QUERY_S = 5.0
"""How long an attacker's query waits for answers (all of them wait at once), s."""


# ---------------------------------------------------------------------------- the lab


@dataclass
class Mesh:
    lab: Lab
    victim: str
    other: str
    powered_off: Path
    """The victim's power.poweroff_command touches this file."""
    http: str
    """Base URL of the victim's web API."""

    @property
    def lab_router(self) -> str:
        return self.lab.endpoint

    def robot_router(self, name: str) -> str:
        return self.lab.endpoints[name]

    def owner(self, name: str) -> Credentials:
        return read(self.lab.credentials_file(name))


@pytest.fixture(scope="module")
def mesh(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Mesh]:
    root = tmp_path_factory.mktemp("security")
    flag, port = root / "powered-off", free_port()

    def victim_toml(i: int, name: str) -> str:
        return (f'[power]\npoweroff_command = ["touch", "{flag}"]\n\n'
                f'[webapi]\nhost = "127.0.0.1"\nport = {port}\n') if i == 0 else ""

    with Lab(root, robots=2, mesh=True, services=VICTIM_SERVICES, extra_toml=victim_toml) as lab:
        lab.start_router()
        victim, other = lab.names
        lab.start_robot(victim)
        lab.start_robot(other, services=[])  # its router only: its owner is our attacker
        mesh = Mesh(lab, victim, other, flag, f"http://127.0.0.1:{port}")
        asyncio.run(_wait_ready(mesh))
        yield mesh
    assert lab.killed == [], f"these did not stop on SIGINT: {lab.killed}"


async def _wait_ready(mesh: Mesh) -> None:
    """Every service of V, and O's router, seen from a guest's laptop on the lab router."""
    want = {keys.alive_key(mesh.victim, s) for s in (*VICTIM_SERVICES, "router")}
    want.add(keys.alive_key(mesh.other, "router"))
    async with laptop(mesh.lab_router) as guest:
        deadline = time.monotonic() + 90
        while not want <= set(await guest.alive("*")):
            assert time.monotonic() < deadline, f"not alive: {want - set(await guest.alive('*'))}\n" + \
                "\n".join(mesh.lab.dead())
            await asyncio.sleep(0.5)
        poses = guest.subscribe(keys.ODOM_POSE, robot=mesh.victim)
        await asyncio.wait_for(poses.__anext__(), 30)


def laptop(endpoint: str, user: str = GUEST_USER, password: str = GUEST_PASSWORD, robot: str = "sim") -> Node:
    """A laptop's session on one router, logged in as ``user`` (the read-only guest by default)."""
    base = config_mod.load(None)
    zenoh_cfg = msgspec.structs.replace(base.zenoh, connect=[endpoint], user=user, password=password)
    return Node("laptop", msgspec.structs.replace(base, name=robot, zenoh=zenoh_cfg), announce=False, retry=False)


def owner_laptop(mesh: Mesh, name: str, endpoint: str) -> Node:
    creds = mesh.owner(name)
    return laptop(endpoint, creds.user, creds.password, robot=name)


class Truth:
    """The simulated robot's true pose, as the simulator publishes it (``sim/truth``)."""

    def __init__(self, node: Node, robot: str) -> None:
        self.latest: m.Truth | None = None
        self._task = asyncio.create_task(self._follow(node.subscribe(keys.TRUTH, robot=robot)))

    async def _follow(self, sub: Any) -> None:
        async for truth in sub:
            self.latest = truth

    async def now(self) -> m.Truth:
        await wait_for(lambda: self.latest is not None, timeout=10)
        assert self.latest is not None
        return self.latest

    async def stands_still(self, timeout: float = 10.0) -> None:
        """Until the robot has not moved for half a second (simulated time: it lags on a busy machine)."""
        deadline = time.monotonic() + timeout
        while True:
            before = await self.now()
            later = before.stamp + 500_000_000
            await wait_for(lambda later=later: self.latest is not None and self.latest.stamp >= later)
            if await self.moved_since(before) < STILL_M:
                return
            assert time.monotonic() < deadline, "the robot did not stop"

    async def moved_since(self, before: m.Truth) -> float:
        after = await self.now()
        return math.hypot(after.x - before.x, after.y - before.y)


# ---------------------------------------------------------------------------- the attack matrix


def wildcard_forms(key: str) -> list[str]:
    """The key itself and every wildcard form of it a student might try: ``*``, ``**`` and a
    ``$*`` chunk in each position, and ``**`` below each prefix (``icefloe/**``, ``**``)."""
    chunks = key.split("/")
    forms = {key}
    for i, chunk in enumerate(chunks):
        for wild in ("*", "**", chunk[:1] + "$*"):
            forms.add("/".join([*chunks[:i], wild, *chunks[i + 1:]]))
        forms.add("/".join([*chunks[:i], "**"]))
    return sorted(str(zenoh.KeyExpr.autocanonize(f)) for f in forms)


def includes(rule: str, key_expr: str) -> bool:
    return zenoh.KeyExpr(rule).includes(zenoh.KeyExpr(key_expr))


COMMAND_QUERIES = (keys.ODOM_RESET, keys.SHUTDOWN_REQUEST, keys.MOTION, keys.HALT, keys.SIM_CONTROL)


def command_request(topic: keys.Topic, n: int) -> m.Message:
    """A request that would do harm if it got through, unique per attempt ``n``."""
    return {
        keys.ODOM_RESET: lambda: m.PoseReset(x=1000.0 + n),
        keys.SHUTDOWN_REQUEST: lambda: m.ShutdownRequest(reason=f"attack {n}"),
        keys.MOTION: lambda: m.Motion(left=0.3, right=0.3, duration=1.0 + n * 1e-4),
        keys.HALT: lambda: m.Stop(),
        keys.SIM_CONTROL: lambda: m.SimControl(action="set_dip", dip=13, volts=float(n)),
    }[topic]()


@dataclass
class Matrix:
    """Every attempt made, and what each attacker's side saw."""

    attempts: list[str] = field(default_factory=list)
    payloads: dict[bytes, str] = field(default_factory=dict)
    """Payload -> the attempt that sent it (each is unique)."""
    replies: dict[str, list[bytes]] = field(default_factory=dict)
    """Query attempt -> the replies it got."""
    received: dict[str, int] = field(default_factory=dict)
    """Subscriber attempt -> samples it got."""
    declared: list[Any] = field(default_factory=list)

    def attempt(self, what: str, payload: bytes | None = None) -> int:
        self.attempts.append(what)
        if payload is not None:
            self.payloads[payload] = what
        return len(self.attempts)


async def attack(matrix: Matrix, name: str, session: zenoh.Session, spare: zenoh.Session,
                 victim: str) -> list[Any]:
    """Everything ``name`` tries against ``victim`` at once; returns the pending queries.

    Subscriptions outside ``icefloe/**`` are declared on ``spare``, a session with no other
    subscription: a session hands every sample it gets to all its own matching subscribers,
    so in ``session`` they would hear what its allowed subscriptions bring in."""
    def n() -> int:
        return len(matrix.attempts)

    for form in wildcard_forms(keys.key(victim, keys.TWIST)):
        payload = codec.encode(m.Twist(v=0.3, w=0.001 * n()))
        matrix.attempt(f"{name}: put {form}", payload)
        session.put(form, payload, encoding=MSGPACK)
        matrix.attempt(f"{name}: delete {form}")
        session.delete(form)
    for form in wildcard_forms(keys.key(victim, keys.CAR)):
        payload = codec.encode(m.CarDrive(v=0.3, steer=0.001 * n()))
        matrix.attempt(f"{name}: put {form}", payload)
        session.put(form, payload, encoding=MSGPACK)
    for form in wildcard_forms(keys.key(victim, keys.ODOM_POSE)):
        payload = codec.encode(m.Pose(stamp=n(), x=1000.0 + n(), y=0.0, theta=0.0))
        matrix.attempt(f"{name}: put {form}", payload)
        session.put(form, payload, encoding=MSGPACK)
    pending = []
    for topic in COMMAND_QUERIES:
        for form in wildcard_forms(keys.key(victim, topic)):
            payload = codec.encode(command_request(topic, n()))
            what = f"{name}: query {form}"
            matrix.attempt(what, payload)
            pending.append((what, session.get(form, payload=payload, encoding=MSGPACK, timeout=QUERY_S)))
    for form in wildcard_forms(keys.key(victim, keys.INFO)):
        what = f"{name}: query {form}"
        matrix.attempt(what)
        pending.append((what, session.get(form, timeout=QUERY_S)))
    for topic in (keys.INFO, keys.SNAPSHOT):
        for form in wildcard_forms(keys.key(victim, topic)):
            matrix.attempt(f"{name}: declare queryable {form}")
            forged, own_key = f"forged by {name}".encode(), keys.key(victim, topic)
            matrix.declared.append(session.declare_queryable(
                form, lambda q, forged=forged, own_key=own_key: q.reply(own_key, forged)))
    for form in wildcard_forms(keys.alive_key(victim, "fake")):
        matrix.attempt(f"{name}: liveliness token {form}")
        matrix.declared.append(session.liveliness().declare_token(form))
    for form in wildcard_forms(keys.key(victim, keys.ODOM_POSE)):
        what = f"{name}: declare subscriber {form}"
        matrix.attempt(what)
        matrix.received[what] = 0
        on = session if includes("icefloe/**", form) else spare
        matrix.declared.append(on.declare_subscriber(
            form, lambda _s, what=what: matrix.received.__setitem__(what, matrix.received[what] + 1)))
    return pending


class RobotView:
    """What robot V's own sessions would see: a session with V's credentials on V's router,
    subscribed to and serving all of ``icefloe/V/**``, recording whatever came from an attack."""

    MARKER = b"the owner's marker"

    def __init__(self, node: Node, matrix: Matrix) -> None:
        victim = self._victim = node.robot
        self.samples: list[str] = []
        self.queries: list[str] = []
        self.markers = 0

        def on_sample(s: zenoh.Sample) -> None:
            key, payload = str(s.key_expr), s.payload.to_bytes()
            if payload == self.MARKER:
                self.markers += 1
            elif s.kind == zenoh.SampleKind.DELETE or not keys.is_concrete(key) or payload in matrix.payloads:
                self.samples.append(f"{s.kind} {key} from {matrix.payloads.get(payload, '?')}")

        read_only = [keys.key("*", t) for t in keys.READ_ONLY_QUERIES]

        def on_query(q: zenoh.Query) -> None:
            if any(includes(rule, str(q.key_expr)) for rule in read_only):
                return  # anyone may ask those
            payload = q.payload.to_bytes() if q.payload is not None else b""
            self.queries.append(f"query {q.key_expr} from {matrix.payloads.get(payload, '?')}")

        self._sub = node.session.declare_subscriber(f"icefloe/{victim}/**", on_sample)
        self._queryable = node.session.declare_queryable(f"icefloe/{victim}/**", on_query)

    async def marker_from(self, owner: Node, timeout: float = 30.0) -> None:
        """Until a marker put by ``owner`` (V's owner, on another router) reaches the view; put
        again every half second, as a put nobody has subscribed to yet is dropped."""
        seen, deadline = self.markers, time.monotonic() + timeout
        while self.markers == seen:
            assert time.monotonic() < deadline, "the owner's marker never reached the robot"
            owner.session.put(keys.key(self._victim, "security/marker"), self.MARKER)
            await asyncio.sleep(0.5)

    def close(self) -> None:
        self._sub.undeclare()
        self._queryable.undeclare()


async def tokens(node: Node) -> set[str]:
    """Every liveliness token under ``icefloe/``, raw (without `Node.alive`'s filter)."""
    replies = await asyncio.to_thread(lambda: list(node.session.liveliness().get("icefloe/**", timeout=1.0)))
    return {str(r.ok.key_expr) for r in replies if r.ok is not None}


async def collect(pending: list[tuple[str, Any]], into: dict[str, list[bytes]]) -> None:
    """Wait for every query to end; the payload of each reply (an error reply as ``b"error"``)."""
    def run() -> None:
        for what, replies in pending:
            into[what] = [r.ok.payload.to_bytes() if r.ok is not None else b"error" for r in replies]

    await asyncio.to_thread(run)


@pytest.mark.slow
async def test_zenoh_attacks_are_refused_on_every_router(mesh: Mesh) -> None:
    """Guests and another robot's owner, on V's router, on the lab router and on O's router:
    every wildcard form of put, delete, query, queryable, token and subscriber."""
    v, o = mesh.victim, mesh.other
    other = mesh.owner(o)
    attackers = {
        f"guest on {v}'s router": (mesh.robot_router(v), GUEST_USER, GUEST_PASSWORD),
        "guest on the lab router": (mesh.lab_router, GUEST_USER, GUEST_PASSWORD),
        f"guest on {o}'s router": (mesh.robot_router(o), GUEST_USER, GUEST_PASSWORD),
        f"{o}'s owner on the lab router": (mesh.lab_router, other.user, other.password),
        f"{o}'s owner on {o}'s router": (mesh.robot_router(o), other.user, other.password),
    }
    with pytest.raises(NotReachable):  # another robot's owner cannot even log in on V's router
        async with laptop(mesh.robot_router(v), other.user, other.password):
            pass

    matrix = Matrix()
    async with owner_laptop(mesh, v, mesh.robot_router(v)) as robot, \
            owner_laptop(mesh, v, mesh.lab_router) as owner, contextlib.AsyncExitStack() as stack:
        sessions = {name: await stack.enter_async_context(laptop(ep, user, pw))
                    for name, (ep, user, pw) in attackers.items()}
        spares = {name: await stack.enter_async_context(laptop(ep, user, pw))
                  for name, (ep, user, pw) in attackers.items()}
        truth = Truth(robot, v)
        poses = robot.subscribe(keys.ODOM_POSE)
        # Each attacker's session is wired up once it hears V's poses.
        for node in sessions.values():
            await asyncio.wait_for(node.subscribe(keys.ODOM_POSE, robot=v).__anext__(), 15)
        view = RobotView(robot, matrix)
        await view.marker_from(owner)  # the view's subscription has reached the lab router
        start = await truth.now()
        pending = []
        for name, node in sessions.items():
            pending += await attack(matrix, name, node.session, spares[name].session, v)
        await collect(pending, matrix.replies)

        # A control through the same routers: what V's owner sends on the lab router arrives.
        await view.marker_from(owner)  # the routers have passed on what came before it
        await asyncio.sleep(1.0)  # anything still on its way arrives now
        # The subscriptions included in icefloe/** hear V; the others (outside it) are refused.
        for what, count in matrix.received.items():
            form = what.rsplit(" ", 1)[1]
            if includes("icefloe/**", form):
                assert count > 0, f"{what}: a guest may watch every robot, but heard nothing"
            else:
                assert count == 0, f"{what}: refused subscription got {count} samples"
        after = await truth.now()
        pose = await asyncio.wait_for(poses.__anext__(), 5)
        view.close()
        listed = await tokens(robot)
        infos = await asyncio.to_thread(lambda: [r.ok.payload.to_bytes() if r.ok else b"error"
                                                 for r in robot.session.get(keys.key(v, keys.INFO), timeout=2.0)])
        snapshots = await asyncio.to_thread(lambda: list(robot.session.get(keys.key(v, keys.SNAPSHOT), timeout=1.0)))
        for q in matrix.declared:
            q.undeclare()

    # Nothing reached the robot's own sessions: no put, delete or query (V's view is ACL-level).
    assert view.samples == [], f"{len(view.samples)} forged messages reached {v}: {view.samples[:10]}"
    assert view.queries == [], f"{len(view.queries)} queries reached {v}'s services: {view.queries[:10]}"
    # ... and the robot itself: no motion, no power-off, no reset pose, no forged token or answer.
    assert math.hypot(after.x - start.x, after.y - start.y) < STILL_M
    assert not mesh.powered_off.exists(), "the power-off command ran"
    assert pose.x < 1000.0, f"odometry reset by an attacker: {pose}"
    assert not [t for t in listed if "fake" in t or not keys.is_concrete(t)], listed
    assert infos and all(msgspec.msgpack.decode(i, type=m.RobotInfo).name == v for i in infos), infos
    assert snapshots == []  # no camera runs on V: nobody may answer in its place
    # The attacker's side: command queries got no answer; read-only ones only where included.
    for what, got in matrix.replies.items():
        form = what.rsplit(" ", 1)[1]
        readable = form.endswith("/info") and includes(keys.key("*", keys.INFO), form)
        assert bool(got) == readable, f"{what}: {got}"
    async with aiohttp.ClientSession() as http, http.get(f"{mesh.http}/hat/dip/get") as r:
        assert (await r.text()) != "13"  # sim/control's set_dip never ran
    assert mesh.lab.dead() == [], mesh.lab.dead()
    async with laptop(mesh.robot_router(v)) as guest:  # the admin space is read-only, and readable
        graph = await read_graph(guest.session, timeout=3.0)
    assert graph.routers == 1 and f"{v}/hwbridge" in graph.names().values(), graph
    assert not [d for ds in graph.by_session.values() for d in ds if "fake" in d.key_expr]
    print(f"\nattack matrix: {len(matrix.attempts)} attempts by {len(attackers)} attackers "
          f"({len(matrix.attempts) // len(attackers)} each); none reached {v}")


# ---------------------------------------------------------------------------- the owner, and the services' own checks


@pytest.mark.slow
async def test_the_owner_does_everything_through_the_lab_router(mesh: Mesh, tmp_path: Path) -> None:
    """V's credentials on the lab router: drive, stop, timed motion, reset, ask; V in status and viz."""
    v = mesh.victim
    out = tmp_path / "lab.rrd"
    viz = subprocess.Popen([sys.executable, "-m", "icefloe.services.viz", "--connect", mesh.lab_router,
                            "--save", str(out), "--duration", "8"], cwd=ROOT, text=True,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    status = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "status", "--connect", mesh.lab_router],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT)
    async with AsyncRobot(credentials=mesh.lab.credentials_file(v), connect=mesh.lab_router) as robot, \
            owner_laptop(mesh, v, mesh.robot_router(v)) as view:
        truth = Truth(view, v)
        await robot.ready(keys.ODOM_POSE.name)
        start = await truth.now()
        await robot.set_velocity(0.15, 0.15)  # held until the next command
        await wait_for(lambda: truth.latest and math.hypot(truth.latest.x - start.x, truth.latest.y - start.y) > 0.05)
        await robot.stop()
        await truth.stands_still()
        done = await robot.set_velocity(0.1, 0.1, duration=0.5)  # cmd/motion, answered when over
        assert done is not None and done.completed
        assert (await robot.reset_pose(x=0.5)).x == 0.5
        await wait_for(lambda: robot.pose is not None and abs(robot.pose.x - 0.5) < 0.01)
        info = await robot.node.query(keys.INFO)
        assert info.name == v
    listed, _ = status.communicate(timeout=60)
    line = next(x for x in listed.splitlines() if x.startswith(f"{v}:"))
    assert set(line.split()[1:]) >= {*VICTIM_SERVICES, "router"}, listed
    output, _ = viz.communicate(timeout=60)
    assert f"showing robot {v!r}" in output, output
    from icefloe.services.viz.readback import read_rrd

    assert read_rrd(out).get(f"/robots/{v}/map/odom", {}).get("log_time"), "viz drew no pose of the robot"


@pytest.mark.slow
async def test_wildcards_in_the_owners_own_space_are_dropped_by_the_services(mesh: Mesh) -> None:
    """The access rules let V's owner use wildcards inside icefloe/V/; the services still take
    commands on their own keys only, and the liveliness view lists concrete tokens only."""
    v = mesh.victim
    async with owner_laptop(mesh, v, mesh.lab_router) as owner, \
            owner_laptop(mesh, v, mesh.robot_router(v)) as view:
        truth = Truth(view, v)
        logs = view.subscribe(keys.LOG, latest=False, maxsize=1000)
        lines: list[str] = []
        stamped: list[tuple[int, str]] = []
        follow = asyncio.create_task(_collect_logs(logs, lines, stamped))
        poses = view.subscribe(keys.ODOM_POSE)
        start = await truth.now()
        reset = codec.encode(m.PoseReset(x=777.0))
        for form in (keys.key(v, "odom/*"), keys.key(v, "odom/re$*"), keys.key(v, "power/*"), keys.key(v, "**")):
            replies = await asyncio.to_thread(lambda f=form: list(owner.session.get(f, payload=reset, timeout=1.5)))
            assert all(r.ok is None or b"777" not in r.ok.payload.to_bytes() for r in replies)
        await wait_for(lambda: any("odometry: dropped a message sent to" in line for line in lines))
        twist = codec.encode(m.Twist(v=0.3, w=0.0))
        wild = [keys.key(v, "cmd/*"), keys.key(v, "cmd/**"), keys.key(v, "**"), keys.key(v, "c$*/twist"),
                keys.key(v, "cmd/tw$*")]
        # Until a service's line names `cmd/*` (at least five rounds): each service writes at most six
        # such lines a second (`LimitedLog`), and the wildcard queries above may have spent them.
        named = f"dropped a message sent to icefloe/{v}/cmd/*"
        give_up = time.monotonic() + 30.0
        for round_ in range(10_000):
            if round_ >= 5 and any(named in line for line in lines):
                break
            assert time.monotonic() < give_up, "no service named the wildcard cmd/* it dropped"
            for form in wild:
                owner.session.put(form, twist, encoding=MSGPACK)
                owner.session.put(form.replace("twist", "stop"), codec.encode(m.Stop()), encoding=MSGPACK)
            await asyncio.sleep(0.1)
        token = owner.session.liveliness().declare_token(keys.alive_key(v, "*"))
        await asyncio.sleep(1.0)
        assert await truth.moved_since(start) < STILL_M
        assert (await asyncio.wait_for(poses.__anext__(), 5)).x < 700
        assert not mesh.powered_off.exists()
        assert keys.alive_key(v, "*") in await tokens(view)  # the access rules let it through ...
        assert keys.alive_key(v, "*") not in await view.alive()  # ... the liveliness view does not list it
        assert all(keys.alive_of(t) for t in await view.alive("*"))
        token.undeclare()
        follow.cancel()
    dropped = [line for line in lines if "dropped a message sent to" in line]
    assert any("icefloe/" + v + "/cmd/*" in line for line in dropped), dropped  # the line names the key
    assert any("odom/*" in line or "odom/re$*" in line for line in dropped), dropped
    for service in VICTIM_SERVICES:  # rate-limited: <= 10 lines a second each
        stamps = sorted(t for t, line in stamped if line.startswith(f"{service}: dropped"))
        assert all(b - a >= 1e9 for a, b in zip(stamps, stamps[10:], strict=False)), service


async def _collect_logs(sub: Any, into: list[str], stamped: list[tuple[int, str]]) -> None:
    async for log in sub:
        into.append(f"{log.service}: {log.text}")
        stamped.append((log.stamp, into[-1]))


async def test_the_attack_forms_reach_a_robot_without_access_control(robot: Robot) -> None:
    """The control for the matrix: without access control every form of it reaches the robot's
    subscribers (so the matrix is no test of forms Zenoh drops anyway); typed subscriptions,
    as every service reads commands, still take only the put on their own key."""
    async with robot.node("service") as service, robot.node("student") as student:
        raw = service.subscribe_raw(keys.key(robot.name, "**"))
        typed = service.subscribe(keys.TWIST)
        forms = wildcard_forms(keys.key(robot.name, keys.TWIST))
        exact = forms.index(keys.key(robot.name, keys.TWIST))
        got: set[str] = set()
        deadline = time.monotonic() + 30
        while len(got) < len(forms):  # again until each has arrived once: the first may find no route yet
            assert time.monotonic() < deadline, sorted(set(forms) - got)
            for n, form in enumerate(forms):
                if form not in got:
                    student.session.put(form, codec.encode(m.Twist(v=0.1, w=float(n))), encoding=MSGPACK)
            with contextlib.suppress(TimeoutError):
                while True:
                    got.add((await asyncio.wait_for(raw.__anext__(), 0.5)).key)
        assert sorted(got) == forms
        assert (await asyncio.wait_for(typed.__anext__(), 5)).w == exact
        with contextlib.suppress(TimeoutError):  # anything else it takes is that same put, sent again
            while True:
                assert (await asyncio.wait_for(typed.__anext__(), 0.5)).w == exact
        assert typed.rejected >= len(forms) - 1


# ---------------------------------------------------------------------------- HTTP

HTTP_COMMANDS = {
    "/robot/set/velocity": {"value": "30,30"}, "/robot/stop": {}, "/robot/hw/reset": {},
    "/robot/pose/reset": {}, "/motor/set/velocity": {"id": "0", "value": "30"}, "/hat/button/get": {},
    "/hat/ledarray/set": {"value": "255"}, "/hat/screen/set": {"value": "2"},
    "/hat/screen/print": {"value": "pwned"}, "/led/set/state": {"id": "2", "value": "1"},
    "/led/set/count": {"id": "3", "value": "100"},
}
HTTP_READS = {"/robot/get/encoder": {}, "/motor/get/encoder": {"id": "0"}, "/battery/get/voltage": {},
              "/battery/get/current": {}, "/hat/dip/get": {}}
def basic(user: str, password: str) -> dict[str, str]:
    """The header of HTTP Basic authentication (RFC 7617)."""
    return {"Authorization": "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode()}


SENT_BY_WEBAPI = ("cmd/", "io/leds", "io/ledarray", "io/text", "io/screen", "odom/reset")


@pytest.mark.slow
async def test_http_changes_need_the_owners_credentials(mesh: Mesh) -> None:
    """No, wrong, a guest's, or another robot's credentials: 401 and nothing on the bus; read
    routes open; the owner's as pibot_client (requests) and PiBot.m (MATLAB's challenge) send them."""
    import requests

    v, own, other = mesh.victim, mesh.owner(mesh.victim), mesh.owner(mesh.other)
    async with owner_laptop(mesh, v, mesh.robot_router(v)) as view:
        truth = Truth(view, v)
        sent: list[str] = []
        sub = view.session.declare_subscriber(
            keys.key(v, "**"), lambda s: sent.append(str(s.key_expr)) if keys.split(str(s.key_expr))[1]
            .startswith(SENT_BY_WEBAPI) else None)
        start = await truth.now()
        async with aiohttp.ClientSession() as http:
            wrong = [{}, basic(own.user, "not the password"), basic("guest", "guest"),
                     basic(other.user, other.password), basic(own.user, ""), basic(own.user + "x", own.password),
                     {"Authorization": "Basic !!not base64"}, {"Authorization": f"Digest {own.password}"}]
            began = time.monotonic()
            for path, params in HTTP_COMMANDS.items():
                for auth in wrong:
                    async with http.get(mesh.http + path, params=params, headers=auth) as r:
                        assert r.status == 401, (path, auth, r.status, await r.text())
                        assert r.headers["WWW-Authenticate"].startswith('Basic realm="icefloe robot'), path
                        assert "message" in await r.json()
            refusing = time.monotonic() - began
            for path, params in HTTP_READS.items():  # what a guest may read over Zenoh, anyone may over HTTP
                async with http.get(mesh.http + path, params=params) as r:
                    assert r.status == 200, (path, await r.text())
            await asyncio.sleep(1.0)
            assert sent == [], f"refused requests sent {sent}"
            assert await truth.moved_since(start) < STILL_M

            # PiBot.m: MATLAB's webread (R2019b..R2025b) asks without credentials, then answers
            # the 401's Basic challenge with the user and password of its weboptions.
            async with http.get(f"{mesh.http}/robot/pose/reset") as first:
                assert first.status == 401 and first.headers["WWW-Authenticate"].split()[0] == "Basic"
            async with http.get(f"{mesh.http}/robot/pose/reset", headers=basic(own.user, own.password)) as r:
                assert r.status == 200 and await r.text() == ""

        # pibot_client.py, unchanged: PiBot(ip=f"{user}:{password}@{host}") makes its URLs
        # http://user:password@host:8080/..., and requests sends them as Basic authentication.
        endpoint = mesh.http.replace("http://", f"http://{own.user}:{own.password}@")

        def pibot() -> list[Any]:
            moved = requests.get(f"{endpoint}/robot/set/velocity?value=30,30")
            led = requests.get(f"{endpoint}/led/set/state?id=2&value=1")
            oled = requests.get(f"{endpoint}/hat/screen/print?value=hello")
            return [moved.status_code, moved.json(), led.status_code, oled.status_code]

        status, state, led, oled = await asyncio.to_thread(pibot)
        assert (status, led, oled) == (200, 200, 200) and set(state) == {"encoder", "pose"}
        await wait_for(lambda: truth.latest and math.hypot(truth.latest.x - start.x, truth.latest.y - start.y) > 0.02)
        stop = await asyncio.to_thread(lambda: requests.get(f"{endpoint}/robot/stop", timeout=5))
        assert stop.status_code == 200 and "encoder" in stop.json()
        sub.undeclare()
    assert any(k.endswith("cmd/wheels") for k in sent) and any(k.endswith("io/leds") for k in sent)
    # [webapi] host = "127.0.0.1": the web API listens on this machine's loopback only.
    port = int(mesh.http.rsplit(":", 1)[1])
    listening = [line.split()[1] for line in Path("/proc/net/tcp").read_text().splitlines()[1:]
                 if line.split()[3] == "0A" and line.split()[1].endswith(f":{port:04X}")]
    assert listening == [f"0100007F:{port:04X}"], listening
    # webapi said so, rate-limited (LimitedLog): at most 3 such lines a second, then a count.
    said = mesh.lab.procs[v][-1].log.read_text().splitlines()
    wrong_lines = [line for line in said if "wrong user or password" in line]
    assert 1 <= len(wrong_lines) <= 3 * (refusing + 2), (refusing, wrong_lines)
    if len(wrong_lines) < len(HTTP_COMMANDS) * (len(wrong) - 1):  # (no header: no line) the rest counted
        assert any("not shown" in line and "wrong login" in line for line in said), said[-20:]


# ---------------------------------------------------------------------------- logins and secrets


@pytest.mark.slow
def test_wrong_logins_cost_the_lab_router_nothing(mesh: Mesh) -> None:
    """100 wrong passwords and 100 unknown users against the lab router: none let in, the router
    keeps running at the same memory (bench/router_logins.py measures it next to right logins)."""
    from common import cpu_seconds
    from router_logins import attempt_logins, rss_kib

    assert mesh.lab.router is not None
    pid, own = mesh.lab.router.pid, mesh.owner(mesh.victim)
    attempt_logins(mesh.lab_router, own.user, "warm-up", 5)  # first-use allocations, not the logins' cost
    cpu0, rss0 = cpu_seconds(pid), rss_kib(pid)
    assert attempt_logins(mesh.lab_router, own.user, "not the password", 100) == 0
    assert attempt_logins(mesh.lab_router, "nobody", "nothing", 100) == 0
    time.sleep(0.5)
    cpu, grown = cpu_seconds(pid) - cpu0, rss_kib(pid) - rss0
    print(f"\n200 wrong logins: lab router CPU {1000 * cpu:.0f} ms, RSS {rss0 / 1024:.1f} -> "
          f"{rss_kib(pid) / 1024:.1f} MiB")
    assert mesh.lab.router.alive()
    assert attempt_logins(mesh.lab_router, own.user, own.password, 1) == 1
    assert grown < 2048, f"the router grew {grown} KiB"
    assert cpu < 2.0


@pytest.mark.slow
async def test_no_secret_leaves_the_robot(mesh: Mesh) -> None:
    """Private run folders, no users file while running; no password in a command line, a log,
    `icefloe config`, the info answer or anything on the bus."""
    v = mesh.victim
    passwords = [mesh.owner(name).password.encode() for name in mesh.lab.names]
    for folder in (mesh.lab.root / "run-lab", *(mesh.lab.root / f"run-{name}" for name in mesh.lab.names)):
        st = folder.stat()
        assert stat.S_IMODE(st.st_mode) == 0o700 and st.st_uid == os.getuid(), folder
        assert not (folder / "zenoh-users").exists(), f"{folder}: the users file outlived the router's start"
    async with owner_laptop(mesh, v, mesh.lab_router) as owner:
        heard: list[bytes] = []
        sub = owner.session.declare_subscriber("icefloe/**", lambda s: heard.append(
            str(s.key_expr).encode() + s.payload.to_bytes()))
        async with aiohttp.ClientSession() as http, \
                http.get(f"{mesh.http}/robot/stop", headers=basic(v, "guess")) as r:  # a wrong login: a log line
            body = await r.read()
            assert r.status == 401 and not [p for p in passwords if p in body]
        info = await owner.query(keys.INFO)
        assert not any(p.decode() in json.dumps(msgspec.to_builtins(info)) for p in passwords)
        await asyncio.sleep(2.0)
        sub.undeclare()
    assert heard and not [h[:80] for h in heard if any(p in h for p in passwords)]
    procs = [p for ps in mesh.lab.procs.values() for p in ps] + [mesh.lab.router]
    for proc in procs:
        assert proc is not None
        cmdline = Path(f"/proc/{proc.pid}/cmdline").read_bytes()
        log = proc.log.read_bytes()
        assert not [p for p in passwords if p in cmdline or p in log], proc.name
    shown = subprocess.run([sys.executable, "-m", "icefloe.cli", "config", str(mesh.lab.configs[v])],
                           capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert shown.returncode == 0 and '"password": "***"' in shown.stdout
    assert not [p for p in passwords if p.decode() in shown.stdout + shown.stderr]


def test_a_link_planted_at_the_users_file_is_not_followed(tmp_path: Path) -> None:
    """Someone made ``<run_dir>/zenoh-users`` a link to a file of theirs: the router neither
    writes through it nor leaves a users file behind, and logins work."""
    from router_logins import attempt_logins, guarded_router

    run, victim = tmp_path / "run", tmp_path / "precious.txt"
    run.mkdir(mode=0o700)
    victim.write_text("not yours\n")
    victim.chmod(0o644)
    (run / "zenoh-users").symlink_to(victim)
    with guarded_router(tmp_path, "linked") as (_router, endpoint, creds):
        assert victim.read_text() == "not yours\n" and stat.S_IMODE(victim.stat().st_mode) == 0o644
        assert not (run / "zenoh-users").exists() and not (run / "zenoh-users").is_symlink()
        assert attempt_logins(endpoint, creds.user, creds.password, 1) == 1


def test_the_run_folder_is_private(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """By default under the user's own runtime folder (or <tmp>/icefloe-<uid>), made 0700; a
    symlink or a folder of another user is refused, and nothing starts."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "xdg"))
    assert config_mod.default_run_dir("r1") == tmp_path / "xdg" / "icefloe" / "r1"
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    monkeypatch.setattr(config_mod.tempfile, "gettempdir", lambda: str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    default = config_mod.default_run_dir("r1")
    assert default == tmp_path / "tmp" / f"icefloe-{os.getuid()}" / "r1"
    private_dir(default)
    for folder in (default, default.parent):  # both ours and closed: nobody can swap r1 for a link
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    loose = tmp_path / "loose"
    loose.mkdir(mode=0o755)
    private_dir(loose)
    assert stat.S_IMODE(loose.stat().st_mode) == 0o700
    (tmp_path / "link").symlink_to(loose)
    with pytest.raises(ConfigError, match="symlink"):
        private_dir(tmp_path / "link")
    if os.getuid() == 0:  # only root can make a folder that belongs to someone else
        theirs = tmp_path / "theirs"
        theirs.mkdir()
        os.chown(theirs, 65534, 65534)
        with pytest.raises(ConfigError, match="belongs to user 65534"):
            private_dir(theirs)
    config = tmp_path / "r.toml"
    config.write_text(f'extends = "sim"\nname = "r1"\nrun_dir = "{tmp_path / "link"}"\n')
    res = subprocess.run([sys.executable, "-m", "icefloe.services.info", "--config", str(config)],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert res.returncode == EXIT_CONFIG and res.stderr.count("\n") == 1 and "symlink" in res.stderr, res.stderr
    up = subprocess.run([sys.executable, "-m", "icefloe.cli", "up", str(config), "--no-viz"], capture_output=True,
                        text=True, cwd=ROOT, timeout=60)  # refused before anything starts
    assert up.returncode == EXIT_CONFIG and up.stdout == "" and "symlink" in up.stderr, up.stdout + up.stderr


def test_a_robot_called_guest_gets_no_router(tmp_path: Path) -> None:
    """Its user would be the public read-only login: everybody would own it."""
    from icefloe import router
    from icefloe.credentials import make

    creds, _ = make(tmp_path / "guest.credentials", "guest")
    config = tmp_path / "guest.toml"
    config.write_text(f'extends = "sim"\nname = "guest"\n[zenoh]\naccess_control = true\ncredentials = "{creds}"\n')
    with pytest.raises(ConfigError, match="may not be 'guest'"):
        router.owners_of(config_mod.load(config))

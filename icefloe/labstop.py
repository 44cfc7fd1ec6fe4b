"""The lab's emergency stop: ask every robot (or some) to stop, hold or release, and hear which did.

The TA's tools share this: ``icefloe lab stop`` and ``release`` (`icefloe.cli.lab`), the lab's
page (``services/labpage``) and the ``!`` key of ``icefloe teleop``. Each robot is asked on its
own key, ``icefloe/<robot>/lab/stop`` (a wildcard reaches no robot: every service takes a command
on its own key only), all at once, with one session; each answers once its board has confirmed
the stop (`LabStopDone`), or within the request's timeout that it has not. A robot that does not
answer is named too: a robot of the lab's folder that is off the network is not forgotten.

Only the lab's TA account may ask ``lab/stop`` (deploy/zenoh/acl/ta.json5, docs/lab.md): the
router drops anyone else's query, and so they hear no answer.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import zenoh

from .config import RobotConfig
from .credentials import TA_ROBOT, read
from .errors import BadPayload, ConfigError
from .schemas import codec, keys
from .schemas import messages as m

if TYPE_CHECKING:
    from .runtime import Node

GRACE_S = 0.25
"""How much longer than the request's ``timeout`` the answers may take on their way back, s."""


@dataclass(frozen=True)
class Answer:
    """What one robot answered to ``lab/stop`` (or that it did not)."""

    robot: str
    confirmed: bool
    """Its board confirmed the stop (zero duty, controller cleared)."""
    held: bool = False
    """It says it is held stopped now."""
    seconds: float | None = None
    """From the request to the answer, s (None: no answer)."""
    detail: str = ""
    """Why it is not confirmed ("" when it is)."""

    def line(self) -> str:
        """One line for a terminal, e.g. ``penguin7: confirmed in 31 ms, held``."""
        held = ", held" if self.held else ""
        if self.confirmed and self.seconds is not None:
            note = f" ({self.detail})" if self.detail else ""
            return f"{self.robot}: confirmed in {self.seconds * 1e3:.0f} ms{held}{note}"
        return f"{self.robot}: NOT confirmed{held}: {self.detail}"


@dataclass(frozen=True)
class LabFolder:
    """The lab's credentials folder (``icefloe router --lab DIR``): its robots and its TA's login."""

    robots: list[str]
    """The robots of the folder's credentials files (not the TA's, not the lab's own)."""
    ta: list[Path]
    """The TA accounts' credentials files (``robot = "*"``)."""


def lab_folder(folder: Path, lab_name: str) -> LabFolder:
    """Read the robots and the TA's files of a lab folder; ``lab_name`` (the lab config's name) is
    the lab's own login (its localizer's), no robot. `ConfigError` names a file that cannot be read."""
    robots, ta = [], []
    folder = folder.expanduser()
    if not folder.is_dir():
        raise ConfigError(f"{folder}: no such folder (the lab's credentials folder, `icefloe router --lab DIR`)")
    for path in sorted(folder.glob("*.credentials")):
        robot = read(path).robot
        if robot == TA_ROBOT:
            ta.append(path)
        elif robot != lab_name:
            robots.append(robot)
    return LabFolder(sorted(set(robots)), ta)


def ta_config(config: RobotConfig, folder: LabFolder | None, credentials: str | None = None,
              connect: Sequence[str] = ()) -> tuple[RobotConfig, str]:
    """``config`` logged in as the TA: the user and password of ``credentials`` (a file), else of the
    folder's TA file; connected to ``connect``, else where that file says, else where ``config``
    does. Returns it and who it logs in as (the file, or why there is none: then the config's own
    login, or the guest's, whose stops the lab router drops)."""
    path = Path(credentials).expanduser() if credentials else None
    if path is None and folder is not None:
        if len(folder.ta) > 1:
            raise ConfigError(f"{folder.ta[0].parent}: {len(folder.ta)} TA credentials files "
                              f"({', '.join(p.name for p in folder.ta)}): say which with --credentials")
        path = folder.ta[0] if folder.ta else None
    if path is None:
        who = config.zenoh.user or "guest"
        zc = msgspec.structs.replace(config.zenoh, connect=list(connect) or config.zenoh.connect)
        return msgspec.structs.replace(config, zenoh=zc), f"{who} (no TA credentials file: give --credentials)"
    creds = read(path)
    zc = msgspec.structs.replace(config.zenoh, user=creds.user, password=creds.password,
                                 connect=list(connect) or creds.connect or config.zenoh.connect)
    return msgspec.structs.replace(config, zenoh=zc), f"{creds.user} ({path})"


async def robots_alive(node: Node) -> list[str]:
    """The robots whose hwbridge is alive on the bus (those that can stop)."""
    found = {keys.alive_of(t) for t in await node.alive("*")}
    return sorted(robot for robot, service in filter(None, found) if service == "hwbridge")


async def stop(node: Node, request: m.LabStop, robots: Sequence[str] = (), known: Sequence[str] = ()) -> list[Answer]:
    """`ask` ``robots`` if any are named; else every robot ``known`` (the lab folder's) at once and,
    as soon as the bus has said which are alive, every other robot alive. Sorted by robot."""
    if robots:
        return sorted(await ask(node.session, robots, request), key=lambda a: a.robot)
    first = asyncio.ensure_future(ask(node.session, known, request))
    try:
        alive = await robots_alive(node)
        more = await ask(node.session, [r for r in alive if r not in known], request)
        return sorted([*await first, *more], key=lambda a: a.robot)
    finally:
        first.cancel()


def check_names(robots: Iterable[str]) -> list[str]:
    """The robot names, each one robot's (`ConfigError` for a wildcard or an empty name)."""
    names = []
    for robot in robots:
        if not robot or "/" in robot or not keys.is_concrete(robot) or any(c in robot for c in "$?#"):
            raise ConfigError(f"robot {robot!r}: name one robot (no wildcard, no '/')")
        names.append(robot)
    return names


async def ask(session: zenoh.Session, robots: Sequence[str], request: m.LabStop) -> list[Answer]:
    """Ask each robot's ``lab/stop`` at once; every robot's `Answer`, in the order given, once all
    answered or ``request.timeout`` (plus `GRACE_S` for the way back) has passed."""
    loop = asyncio.get_running_loop()
    payload = codec.encode(request)
    started = time.monotonic()
    done: dict[str, asyncio.Future[Answer]] = {robot: loop.create_future() for robot in check_names(robots)}

    def settle(robot: str, answer: Answer) -> None:
        future = done[robot]
        if not future.done():
            future.set_result(answer)

    def handlers(robot: str) -> zenoh.handlers.Callback:
        key_expr = keys.key(robot, keys.LAB_STOP)
        heard: list[Answer] = []

        def on_reply(reply: zenoh.Reply) -> None:  # a Zenoh thread
            seconds = time.monotonic() - started
            if reply.ok is None:
                heard.append(Answer(robot, False, seconds=seconds, detail=f"error: {reply.err.payload.to_string()}"))
                return
            try:
                got = codec.decode(reply.ok.payload.to_bytes(), str(reply.ok.encoding), m.LabStopDone, key_expr)
            except BadPayload as exc:
                heard.append(Answer(robot, False, seconds=seconds, detail=str(exc)))
                return
            heard.append(Answer(robot, got.confirmed, got.held, seconds, got.detail))

        def on_end() -> None:  # the query is over: every queryable answered, or the timeout
            seconds = time.monotonic() - started
            if not heard:
                why = (f"no answer within {request.timeout + GRACE_S:g} s" if seconds >= request.timeout
                       else "nobody answers (its router or hwbridge down, off the network, or these are not "
                            "the TA's credentials)")
                answer = Answer(robot, False, seconds=None, detail=why)
            else:
                # Every queryable on the robot's key answered (a program of its owner may serve the
                # key too): confirmed only if all said so; the slowest counts.
                bad = [a for a in heard if not a.confirmed]
                answer = Answer(robot, not bad, any(a.held for a in heard), max(a.seconds or 0.0 for a in heard),
                                (bad or heard)[0].detail)
            loop.call_soon_threadsafe(settle, robot, answer)

        return zenoh.handlers.Callback(on_reply, on_end)

    for robot in done:
        # Every queryable's answer (not the nearest's, nor one per key: a program on the robot may
        # serve the key too), as soon as it comes; at the stop's own priority, ahead of other traffic.
        session.get(keys.key(robot, keys.LAB_STOP), handlers(robot), payload=payload, encoding=codec.MSGPACK,
                    timeout=request.timeout + GRACE_S, target=zenoh.QueryTarget.ALL,
                    consolidation=zenoh.ConsolidationMode.NONE, priority=zenoh.Priority.REAL_TIME,
                    congestion_control=zenoh.CongestionControl.BLOCK)
    return list(await asyncio.gather(*done.values()))


def summary(answers: Sequence[Answer], action: str) -> str:
    """The last line: how many confirmed, and which did not."""
    missing = [a.robot for a in answers if not a.confirmed]
    did = {"stop": "stopped", "hold": "held stopped", "release": "released"}[action]
    head = f"{len(answers) - len(missing)} of {len(answers)} robots {did} and confirmed"
    return head + (f"; NOT confirmed: {', '.join(missing)}" if missing else "")

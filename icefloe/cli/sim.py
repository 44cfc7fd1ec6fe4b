"""The `sim` verbs: a TA's handles on the simulated robot (``sim/control``): place, reset, pause, resume.

    icefloe sim place 0.5 -0.2 1.57     # put the robot there (m, m, rad), at rest
    icefloe sim reset                   # back to the origin, battery full, nothing stalled
    icefloe sim pause | resume          # freeze the world, and let it go
    icefloe sim state                   # where the robot truly is

Only the robot's owner (its credentials) and the lab's TA account may (docs/sim.md).
"""

from __future__ import annotations

import argparse
import math

from ..config import RobotConfig
from ..errors import IcefloeError
from ..runtime import run_async
from ..schemas import keys
from ..schemas import messages as m
from .common import add_bus_arguments, bus_config, cli_node


def describe(state: m.SimState) -> str:
    paused = ", paused" if state.paused else ""
    return (f"truth: x {state.x:.3f} m, y {state.y:.3f} m, theta {state.theta:.3f} rad "
            f"({math.degrees(state.theta):.1f}°){paused}; sim time {state.sim_time:.1f} s")


async def control(args: argparse.Namespace, config: RobotConfig, request: m.SimControl) -> int:
    robot = args.robot or config.name
    if any(c in robot for c in "*$?#"):
        raise IcefloeError(f"--robot {robot!r}: name one robot (a TA's credentials name none: give --robot)")
    async with cli_node(config) as node:
        state = await node.query(keys.SIM_CONTROL, request, timeout=args.timeout, robot=robot)
    print(f"{robot}: {describe(state)}")
    return 0


def _add(verbs: argparse._SubParsersAction, name: str, help_: str, request, *extra: tuple[str, str]) -> None:  # type: ignore[no-untyped-def]
    p = verbs.add_parser(name, help=help_, description=help_[0].upper() + help_[1:] + ".")
    add_bus_arguments(p)
    for arg, arg_help in extra:
        p.add_argument(arg, type=float, help=arg_help)
    p.add_argument("--timeout", type=float, default=5.0, metavar="S", help="wait this long for the simulator's answer")
    p.set_defaults(run=lambda args: run_async(control(args, bus_config(args), request(args))))


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("sim", help="place, reset, pause or resume the simulated robot (a TA's handles)",
                         description="Act on the simulated robot through its sim/control queryable: only its "
                                     "owner and the lab's TA account may (docs/sim.md).")
    sub = p.add_subparsers(dest="sim_verb", metavar="ACTION", required=True,
                           help="place, reset, pause, resume, or state (each has --help)")
    _add(sub, "place", "put the robot at X Y THETA, at rest (only the truth jumps; odometry does not)",
         lambda a: m.SimControl(action="place", x=a.x, y=a.y, theta=a.theta),
         ("x", "x in the world, m"), ("y", "y in the world, m"), ("theta", "heading, rad, counter-clockwise from +x"))
    _add(sub, "reset", "put the world back as it started: robot at the origin, battery full, nothing stalled",
         lambda a: m.SimControl(action="reset"))
    _add(sub, "pause", "freeze the world: the robot stays where it is until resume",
         lambda a: m.SimControl(action="pause"))
    _add(sub, "resume", "let a paused world go on", lambda a: m.SimControl(action="resume"))
    _add(sub, "state", "print where the simulated robot truly is", lambda a: m.SimControl(action="read"))

"""The `lab` verbs: the lab's emergency stop, for its TA (docs/lab.md).

    icefloe lab stop lab.toml                       # stop every robot of the lab, say which confirmed
    icefloe lab stop lab.toml --hold                # ... and hold them stopped until released
    icefloe lab stop lab.toml --robot penguin7 --hold --reason "off the table"
    icefloe lab release lab.toml --robot penguin7   # end the hold (the robot stays stopped)

Which robots: each ``--robot NAME``; else every robot of the lab's credentials folder (``[lab]
folder`` of the lab's config, or ``--lab DIR``) and every robot whose hwbridge is alive on the bus.
As whom: the TA's credentials file of that folder (``robot = "*"``), or ``--credentials FILE``.
Each robot answers once its board has confirmed the stop; one that does not within ``--timeout``
(``[lab] timeout``, 1 s) is named, and the command exits 1.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import msgspec

from .. import labstop
from ..errors import ConfigError
from ..runtime import load_config, run_async
from ..schemas import messages as m
from .common import add_config_argument, cli_node

ACTIONS = {"stop": "stop every robot (or --robot ones) now, and say which confirmed",
           "release": "end the TA's hold of every robot (or --robot ones): they stay stopped, "
                      "and drive again on their next command"}


async def lab(args: argparse.Namespace) -> int:
    config = load_config(args)
    folder_path = args.lab or config.lab.folder
    folder = labstop.lab_folder(Path(folder_path), config.name) if folder_path else None
    session_config, who = labstop.ta_config(config, folder, args.credentials, args.connect or ())
    action = "hold" if getattr(args, "hold", False) else args.action
    fields = {"action": action, "reason": getattr(args, "reason", ""),
              "owner_may_release": getattr(args, "owners_release", False),
              "timeout": config.lab.timeout if args.timeout is None else args.timeout}
    try:
        msgspec.convert(fields, m.LabStop)  # the ranges: a reason of at most 60 characters, 0 < timeout <= 10
    except msgspec.ValidationError as exc:
        raise ConfigError(f"lab {args.action}: {exc}".replace("$.reason", "--reason")
                          .replace("$.timeout", "--timeout")) from None
    robots = labstop.check_names(args.robot or [])
    known = folder.robots if folder is not None else []
    if not robots and folder is None:
        print("no lab folder ([lab] folder, --lab DIR): asking the robots alive on the bus", flush=True)
    async with cli_node(session_config) as node:
        where = ", ".join(session_config.zenoh.connect)
        print(f"lab {action}: {', '.join(robots) or 'every robot'}, as {who}, on {where}", flush=True)
        answers = await labstop.stop(node, node.command(m.LabStop, **fields), robots, known)
    for answer in answers:
        print(answer.line())
    if not answers:
        print("no robot to ask: name one with --robot, or give the lab's folder")
        return 1
    print(labstop.summary(answers, action))
    return 0 if all(a.confirmed for a in answers) else 1


def _add(verbs: argparse._SubParsersAction, action: str) -> argparse.ArgumentParser:
    p = verbs.add_parser(action, help=ACTIONS[action], description=ACTIONS[action][0].upper() + ACTIONS[action][1:]
                         + ". " + __doc__.split("\n\n")[2].replace("\n", " "))
    add_config_argument(p, positional=True)
    p.add_argument("--robot", action="append", metavar="NAME",
                   help="only this robot (repeatable; default: every robot of the lab)")
    p.add_argument("--lab", metavar="DIR", help="the lab's credentials folder (default: [lab] folder of CONFIG)")
    p.add_argument("--credentials", metavar="FILE",
                   help="the TA's credentials file (default: the one in the lab's folder whose robot is \"*\")")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint of the lab router, e.g. tcp/192.168.1.2:7447 (default: the credentials "
                        "file's, else CONFIG's)")
    p.add_argument("--timeout", type=float, metavar="S",
                   help="how long each robot has to confirm, s (default: [lab] timeout, 1)")
    p.set_defaults(run=lambda args: run_async(lab(args)), action=action)
    return p


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("lab", help="the lab's emergency stop: stop, hold or release every robot (the TA's)",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="lab_verb", metavar="ACTION", required=True, help="stop or release (each has --help)")
    stop = _add(sub, "stop")
    stop.add_argument("--hold", action="store_true",
                      help="hold them stopped: every motion command is refused until the TA releases them")
    stop.add_argument("--owners-release", action="store_true",
                      help="with --hold: each robot's owner may release it too (cmd/release)")
    stop.add_argument("--reason", default="", metavar="TEXT",
                      help="what the robots' screens, web pages and logs say (at most 60 characters)")
    _add(sub, "release")


# PYTHON_ARGCOMPLETE_OK
"""The `icefloe` command: one small module per group of verbs, as ros2cli does.

    robot.py       up, router, credentials, config     run and set up a robot
    bus.py         status, echo, hz, pub, query        listen and talk to the bus
    introspect.py  topics, info, services              what is on the bus, who declares it
    teleop.py      teleop                              drive from the keyboard
    lab.py         lab stop, lab release               the lab's emergency stop (its TA's)
    schemas.py     schemas                             the JSON Schemas of the messages
    record.py      record, replay, bag, export         recordings: MCAP files, played back onto the bus
    viz.py         viz                                 the Rerun view of robots (live, or from a recording)
    gateware.py    gateware build, pins                the icoBoard's FPGA design
    snapshot.py    snapshot                            save a frame of the robot's camera
    calibrate.py   calibrate                           calibrate the robot's camera
    score.py       score map, score path               a map or a trajectory against the truth
    scaffold.py    new-service                         a service of your own, ready to run and test
    doctor.py      doctor                              check a robot's health, one line per problem
    completion.py  completion                          shell completion (argcomplete)

A verb module has a ``register(verbs)`` function that adds its sub-parsers, each with
``set_defaults(run=<function of the parsed args returning an exit status>)``. To add a verb
group, write the module and name it in `VERB_MODULES`.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

import argcomplete

from ..errors import EXIT_CONFIG, ConfigError, IcefloeError

VERB_MODULES = ("robot", "bus", "introspect", "teleop", "lab", "record", "viz", "schemas", "gateware", "snapshot",
                "calibrate", "extloc", "score", "grid", "sim", "scaffold", "doctor", "completion")
"""The verb modules of this package, in the order `icefloe --help` lists their verbs."""

EPILOG = """\
A robot is named by its config: a name (sim, penguin1: your own configs in
~/.config/icefloe/robots/ first, then the shipped ones) or a path to a .toml file.
KEY is a name from the key table (odom/pose) on that robot, or a full key
(icefloe/sim/odom/pose). Every bus verb takes --connect tcp/<robot-ip>:7447 and
--credentials FILE. `icefloe VERB --help` explains a verb.
"""


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="icefloe", description="The icefloe robot stack: run a robot, look at its bus, drive it.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    verbs = p.add_subparsers(dest="verb", required=True, metavar="VERB")
    for name in VERB_MODULES:
        importlib.import_module(f"{__name__}.{name}").register(verbs)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    try:
        p = parser()
        argcomplete.autocomplete(p)  # answers the shell's completion request and exits, if that is what this is
        args = p.parse_args(sys.argv[1:] if argv is None else list(argv))
        return int(args.run(args) or 0)
    except ConfigError as exc:
        print(f"icefloe: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    except IcefloeError as exc:
        print(f"icefloe: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `icefloe echo log | head`: the reader is gone, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141

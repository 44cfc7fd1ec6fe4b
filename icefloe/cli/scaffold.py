"""The `new-service` verb: a service of your own, ready to run and test (docs/own-services.md).

    icefloe new-service NAME [--dir DIR]

writes ``DIR/NAME/`` (default: ``./NAME/``) from the template shipped with icefloe
(``deploy/templates/service/``, itself run by icefloe's tests): the service, its test, a robot
config that runs it on the simulated robot, and a README.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from .. import paths
from ..config import RESERVED_NAMES
from ..errors import IcefloeError

TEMPLATE = "example_service"
"""The name the template's files and code use; replaced by yours."""
MODULE_NAME = re.compile(r"[a-z][a-z0-9_]*")


def new_service(args: argparse.Namespace) -> int:
    name = args.name
    if not MODULE_NAME.fullmatch(name) or name in RESERVED_NAMES:
        why = "is one of icefloe's own services" if name in RESERVED_NAMES else \
            "must be lower-case letters, digits and _, starting with a letter (a Python module name)"
        raise IcefloeError(f"new-service: {name!r} {why}")
    folder = Path(args.dir or ".") / name
    if folder.exists():
        raise IcefloeError(f"new-service: {folder} exists already: choose another name or --dir")
    template = paths.packaged("templates", "service")
    folder.mkdir(parents=True)
    for source in sorted(template.iterdir()):
        if source.is_file() and not source.name.startswith("."):
            text = source.read_text().replace(TEMPLATE, name)
            (folder / source.name.replace(TEMPLATE, name)).write_text(text)
    print(f"made {folder}/ with {name}.py, test_{name}.py, robot.toml and README.md. Next:\n\n"
          f"  cd {folder}\n"
          f"  python -m pytest test_{name}.py     # its tests: no robot needed\n"
          f"  icefloe up robot.toml              # the simulated robot, with {name}\n")
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("new-service", help="write a service of your own (Python), its test and a robot config "
                                             "that runs it",
                         description="Write NAME/ with a runnable service in the shape of icefloe's own, its "
                                     "test, and robot.toml, which runs it on the simulated robot.")
    p.add_argument("name", metavar="NAME", help="the service's name: lower-case letters, digits and _")
    p.add_argument("--dir", metavar="DIR", help="where to make NAME/ (default: here)")
    p.set_defaults(run=new_service)

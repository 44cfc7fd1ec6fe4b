"""The `viz` verb: a live Rerun view of the robots on a bus (services/viz)."""

from __future__ import annotations

import argparse

from ..services.viz.__main__ import __doc__ as VIZ_DOC
from ..services.viz.__main__ import add_service_arguments


def viz(args: argparse.Namespace) -> int:
    from ..services.viz.__main__ import start

    start(args)
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("viz", help="a live Rerun view of the robots on a bus (needs the viz extra)",
                         description=VIZ_DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_service_arguments(p)
    p.set_defaults(run=viz)

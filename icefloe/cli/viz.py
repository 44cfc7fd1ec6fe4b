"""The `viz` verb: a live Rerun view of the robots on a bus (services/viz), or of a recording."""

from __future__ import annotations

import argparse

from ..services.viz.command import __doc__ as VIZ_DOC
from ..services.viz.command import add_service_arguments


def viz(args: argparse.Namespace) -> int:
    if args.files:
        from ..services.viz.command import show_recording

        return show_recording(args)
    from ..services.viz.command import start

    start(args)
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("viz", help="a Rerun view of the robots on a bus, or of a recording (needs the viz extra)",
                         description=VIZ_DOC + "    icefloe viz run.mcap                                    "
                         "# a recording (icefloe record), with the time slider\n",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("files", nargs="*", metavar="FILE.mcap",
                   help="show this recording instead of the live bus (several: a split one, in order)")
    add_service_arguments(p)
    p.set_defaults(run=viz)

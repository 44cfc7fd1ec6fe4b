"""The `schemas` verb: the messages' JSON Schemas, for other languages."""

from __future__ import annotations

import argparse


def schemas(args: argparse.Namespace) -> int:
    from ..schemas import export

    if args.check:
        bad = export.stale()
        for name in bad:
            print(f"stale: schemas/json/{name} (run `icefloe schemas`)")
        return 1 if bad else 0
    print(f"wrote {len(export.write())} schemas to {export.JSON_DIR}")
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("schemas", help="regenerate the JSON Schemas in schemas/json from the message Structs")
    p.add_argument("--check", action="store_true", help="only check they are current; exit 1 if stale")
    p.set_defaults(run=schemas)

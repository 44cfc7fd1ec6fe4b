"""The `schemas` verb: the messages' JSON Schemas, for other languages."""

from __future__ import annotations

import argparse
from pathlib import Path


def schemas(args: argparse.Namespace) -> int:
    from ..schemas import export

    if args.check:
        bad = export.stale()
        for name in bad:
            print(f"stale: schemas/json/{name} (run `icefloe schemas`)")
        if bad:
            made = ", ".join(sorted(export.made_by())) or "nothing"
            print(f"{len(bad)} stale: the checked-in schemas say {made!r}; this is {export.MADE_BY.split(' with ')[1]}"
                  " (the lock's msgspec makes them: deploy/requirements)")
        return 1 if bad else 0
    out = Path(args.out) if args.out else export.JSON_DIR
    print(f"wrote {len(export.write(out))} schemas to {out}")
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("schemas", help="regenerate the JSON Schemas in schemas/json from the message Structs",
                         description="Write one JSON Schema per message: into the package's schemas/json "
                                     "(in a checkout), or into --out DIR (e.g. for a program in another language).")
    p.add_argument("--check", action="store_true", help="only check they are current; exit 1 if stale")
    p.add_argument("--out", metavar="DIR", help="write them into DIR instead of the package's schemas/json")
    p.set_defaults(run=schemas)

"""The `completion` verb: shell code that completes icefloe's verbs, options, robot names and keys.

    eval "$(.venv/bin/icefloe completion bash)"     # in ~/.bashrc (zsh, fish, tcsh alike)

The completing itself is argcomplete's: the shell runs ``icefloe`` with ``_ARGCOMPLETE`` set, and
`icefloe.cli.main` answers from the argument parser (keys from the key table, configs by name).
"""

from __future__ import annotations

import argparse

SHELLS = ("bash", "zsh", "fish", "tcsh", "powershell")


def completion(args: argparse.Namespace) -> int:
    import argcomplete

    print(argcomplete.shellcode(["icefloe"], shell=args.shell))
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("completion", help="print shell code that completes icefloe's verbs, options and keys",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("shell", nargs="?", default="bash", choices=SHELLS, help="the shell (default bash)")
    p.set_defaults(run=completion)

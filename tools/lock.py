"""Make the lock: ``uv.lock`` and its exports in ``deploy/requirements/`` (docs/DEVELOPING.md, "The lock").

    .venv/bin/python tools/lock.py              after editing pyproject.toml's dependencies: the lock
                                                follows, changing no version it need not change
    .venv/bin/python tools/lock.py --upgrade    every package to its newest release within the ranges
    .venv/bin/python tools/lock.py --upgrade-package NAME   that one package to its newest (a security fix)
    .venv/bin/python tools/lock.py --check      exit 1 if uv.lock or an export is not what it should
                                                be (no network; tests/test_lock.py runs it)

``uv.lock`` is one resolution for every machine in pyproject.toml's ``[tool.uv] environments``
(Linux on x86_64 and aarch64, every Python from 3.11). pip reads none of it, so each extra is
exported as a pip requirements file with every file's hash (``deploy/requirements/<extra>.txt``,
``base.txt`` for no extra, ``<group>.txt`` for the dependency groups): what deploy/setup.sh, the
robot install and the box's wheelhouse install from, and what ``icefloe doctor`` compares with.
"""

from __future__ import annotations

import argparse
import difflib
import subprocess
import sys
import tomllib
from pathlib import Path

from uv import find_uv_bin

ROOT = Path(__file__).resolve().parent.parent
OUT = Path("deploy/requirements")
"""Where the exports go, relative to the checkout (shipped in the wheel as ``icefloe/share/requirements``)."""


def exports() -> dict[str, list[str]]:
    """Export file name -> the ``uv export`` options that select it: base, one per extra, one per group."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    out = {"base.txt": []}
    out.update({f"{extra}.txt": ["--extra", extra] for extra in pyproject["project"]["optional-dependencies"]})
    out.update({f"{group}.txt": ["--only-group", group] for group in pyproject["dependency-groups"]})
    return out


def uv(*args: str, capture: bool = False) -> subprocess.CompletedProcess[str]:
    return subprocess.run([find_uv_bin(), *args], cwd=ROOT, text=True,
                          stdout=subprocess.PIPE if capture else None, stderr=subprocess.PIPE if capture else None)


def export(options: list[str]) -> str:
    """The text of one export, from uv.lock as it is (``--frozen``: nothing resolved, no network)."""
    command = ["export", "--frozen", "--no-header", "--no-emit-project", "--no-default-groups", *options]
    r = uv(*command, capture=True)
    if r.returncode != 0:
        sys.exit(f"lock: uv {' '.join(command)} failed: {r.stderr.strip()}")
    return (f"# The lock's versions for pip, with every file's hash: made from uv.lock by tools/lock.py\n"
            f"# (uv {' '.join(command)}). Do not edit: docs/DEVELOPING.md, \"The lock\".\n{r.stdout}")


def check() -> int:
    """0 when uv.lock satisfies pyproject.toml and every export is what uv.lock makes; else 1, naming why."""
    problems = []
    r = uv("lock", "--check", "--offline", "--no-progress", "--color", "never", capture=True)
    if r.returncode != 0:
        problems.append("uv.lock is not what pyproject.toml asks for (a dependency changed): "
                        "run .venv/bin/python tools/lock.py")
    wanted = exports()
    have = {p.name for p in (ROOT / OUT).glob("*.txt")}
    for extra in sorted(have - set(wanted)):
        problems.append(f"{OUT / extra}: no extra or group of that name: remove it (tools/lock.py does)")
    for name, options in wanted.items():
        path = ROOT / OUT / name
        before = path.read_text() if path.exists() else ""
        after = export(options)
        if before != after:
            diff = list(difflib.unified_diff(before.splitlines(), after.splitlines(), lineterm="", n=0))[2:8]
            problems.append(f"{OUT / name} differs from uv.lock's export: run .venv/bin/python tools/lock.py\n    "
                            + "\n    ".join(diff))
    for line in problems:
        print(f"lock: {line}", file=sys.stderr)
    if not problems:
        print(f"lock: uv.lock matches pyproject.toml; {len(wanted)} exports in {OUT} match uv.lock")
    return 1 if problems else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--upgrade", action="store_true", help="take every package's newest release within the ranges")
    what.add_argument("--upgrade-package", metavar="NAME", action="append", default=[],
                      help="take this package's newest release within the ranges (repeat for more)")
    what.add_argument("--check", action="store_true", help="change nothing: exit 1 if the lock or an export is stale")
    args = parser.parse_args()
    if args.check:
        return check()
    upgrade = ["--upgrade"] if args.upgrade else [a for n in args.upgrade_package for a in ("--upgrade-package", n)]
    r = uv("lock", *upgrade)
    if r.returncode != 0:
        return r.returncode
    (ROOT / OUT).mkdir(parents=True, exist_ok=True)
    wanted = exports()
    for stale in (ROOT / OUT).glob("*.txt"):
        if stale.name not in wanted:
            stale.unlink()
    for name, options in wanted.items():
        (ROOT / OUT / name).write_text(export(options))
    print(f"lock: uv.lock and {len(wanted)} exports in {OUT}; review `git diff uv.lock`, then run ./tests/run.sh")
    return 0


if __name__ == "__main__":
    sys.exit(main())

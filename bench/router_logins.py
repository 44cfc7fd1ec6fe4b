"""Wrong logins against a guarded router: what do they cost it?

    .venv/bin/python bench/router_logins.py [--logins 100]

Starts a robot's router with access control (``icefloe.router``, a fresh credentials file,
a loopback port) as its own process, and measures its CPU time and resident memory
(``/proc/<pid>``) around each of three runs of N logins, one after the other:

* N logins with the robot's user and a wrong password (first, on the router as it started);
* N logins as a user the router does not know;
* reference: N right logins (the robot's own user and password), each session closed again.

Every login is a fresh Zenoh session from this process (TCP connect, Zenoh's handshake, the
user/password challenge). The router must stay up and refuse every wrong one; the figures
say what a student hammering it with bad passwords costs it, next to what the same number
of good logins costs. ``tests/test_security.py`` runs `attempt_logins` against a lab router.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import zenoh
from common import cpu_seconds, free_port
from lab_harness import ROOT, SIM_CONFIG

from icefloe import credentials


def rss_kib(pid: int) -> int:
    """Resident memory of a process, KiB (VmRSS of /proc/<pid>/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for {pid}")


def attempt_logins(endpoint: str, user: str, password: str, n: int) -> int:
    """Open (and close) ``n`` client sessions as ``user``; returns how many the router let in."""
    accepted = 0
    for _ in range(n):
        zc = zenoh.Config()
        zc.insert_json5("mode", '"client"')
        zc.insert_json5("scouting/multicast/enabled", "false")
        zc.insert_json5("connect/endpoints", json.dumps([endpoint]))
        zc.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        zc.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
        try:
            session = zenoh.open(zc)
        except zenoh.ZError:
            continue
        accepted += 1
        session.close()
    return accepted


def measure(pid: int, endpoint: str, user: str, password: str, n: int) -> dict[str, float]:
    """Logins, router CPU seconds and RSS growth (KiB) over one run of ``n`` logins."""
    cpu0, rss0, t0 = cpu_seconds(pid), rss_kib(pid), time.monotonic()
    accepted = attempt_logins(endpoint, user, password, n)
    time.sleep(0.5)  # let the router finish with the last connection
    return {"accepted": accepted, "seconds": time.monotonic() - t0, "cpu_s": cpu_seconds(pid) - cpu0,
            "rss_kib": rss_kib(pid), "rss_growth_kib": rss_kib(pid) - rss0}


@contextlib.contextmanager
def guarded_router(root: Path, name: str) -> Iterator[tuple[subprocess.Popen[str], str, credentials.Credentials]]:
    """A robot's router with access control (``icefloe.router``, run folder ``root/run``, a new
    credentials file, a loopback port), running until the block ends: (process, endpoint, credentials)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    creds_path, _ = credentials.make(root / f"{name}.credentials", name, [endpoint])
    config = root / f"{name}.toml"
    config.write_text(f'extends = "{SIM_CONFIG}"\nname = "{name}"\nrun_dir = "{root / "run"}"\n\n'
                      f'[zenoh]\nlisten = ["{endpoint}"]\nconnect = ["{endpoint}"]\n'
                      f'access_control = true\ncredentials = "{creds_path}"\n')
    router = subprocess.Popen([sys.executable, "-m", "icefloe.router", "--config", str(config)], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert router.stdout is not None
        line = router.stdout.readline()
        if "listening on" not in line:
            raise RuntimeError(f"the router did not start: {line}{router.stdout.read()}")
        yield router, endpoint, credentials.read(creds_path)
    finally:
        router.terminate()
        router.wait(10)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--logins", type=int, default=100)
    args = parser.parse_args()
    print(f"$ {' '.join([Path(sys.executable).name, *sys.argv])}")
    with tempfile.TemporaryDirectory() as tmp, guarded_router(Path(tmp), "bench") as (router, endpoint, creds):
        time.sleep(1.0)
        start = rss_kib(router.pid)
        runs = {  # the wrong ones first: they get the router cold, with any first-use growth
            "wrong password": measure(router.pid, endpoint, creds.user, "not the password", args.logins),
            "unknown user": measure(router.pid, endpoint, "nobody", "nothing", args.logins),
            "right password (reference)": measure(router.pid, endpoint, creds.user, creds.password, args.logins),
        }
        alive = router.poll() is None
        still_in = attempt_logins(endpoint, creds.user, creds.password, 1) == 1
    print(f"router RSS at start: {start / 1024:.1f} MiB; {args.logins} logins per run, one after the other\n")
    print(f"{'logins':<28} {'let in':>7} {'took s':>7} {'router CPU ms':>14} {'per login ms':>13} "
          f"{'router RSS MiB':>15} {'RSS growth KiB':>15}")
    for name, r in runs.items():
        print(f"{name:<28} {r['accepted']:>7.0f} {r['seconds']:>7.2f} {1000 * r['cpu_s']:>14.0f} "
              f"{1000 * r['cpu_s'] / args.logins:>13.2f} {r['rss_kib'] / 1024:>15.1f} {r['rss_growth_kib']:>15.0f}")
    wrong_in = runs["wrong password"]["accepted"] + runs["unknown user"]["accepted"]
    ok = alive and still_in and wrong_in == 0 and runs["right password (reference)"]["accepted"] == args.logins
    print(f"\nrouter {'still up' if alive else 'DIED'}; the right password still "
          f"{'works' if still_in else 'FAILS'}; wrong logins let in: {wrong_in:.0f}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

"""CPU use of the simulator process, per board kind (goal: under 25 % of one core, no camera).

    .venv/bin/python bench/sim_cpu.py [--seconds 20]

For each case it starts a Zenoh router and ``python -m icefloe.services.sim`` as
real processes, lets them settle, and reads the sim process's user + system
CPU time from ``/proc/<pid>/stat`` over the measuring window. Cases:

* ``penguinpi``: the PenguinPi model behind its pseudo-terminal, nobody talking to it.
* ``icoboard``: the icoBoard v2 model behind its socket, idle.
* ``icoboard + 1 kHz host``: this script exchanges a v2 TRANSMIT frame every
  millisecond over the socket, as hwbridge does (the host's own CPU is not counted).

Reference, measured in the same run: a bare Python thread that only sleeps to a
1 ms deadline, the floor cost of any Python process that wakes 1000 times a second.

It also prints the round-trip times of the 1 kHz host's exchanges (what
hwbridge waits for in each cycle), next to the same datagrams sent to a bare
Python echo process: the cost of the socket and of waking another process.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from common import cpu_percent, free_port

ROOT = Path(__file__).resolve().parent.parent

REFERENCE = """
import time
period, deadline = 0.001, time.monotonic()
while True:
    deadline += period
    delay = deadline - time.monotonic()
    if delay > 0:
        time.sleep(delay)
"""


def host_1khz(path: str, stop: threading.Event, rtts: list[float]) -> None:
    """Drive the icoBoard socket as hwbridge does: START, then a TRANSMIT every millisecond.

    Appends each exchange's round-trip time (s) to ``rtts``.
    """
    from icefloe.wire.icoboard import Op, Wire

    wire = Wire(2)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("")
    sock.settimeout(1.0)
    sock.connect(path)
    sock.send(wire.request(Op.START, seq=0))
    sock.recv(64)
    seq, deadline = 0, time.monotonic()
    while not stop.is_set():
        seq += 1
        frame = wire.request(Op.TRANSMIT, seq=seq, duties=[8000, 8000])
        t0 = time.perf_counter()
        sock.send(frame)
        sock.recv(64)
        rtts.append(time.perf_counter() - t0)
        deadline += 0.001
        delay = deadline - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    sock.send(wire.request(Op.EXIT, seq=seq + 1))
    sock.close()


ECHO = """
import socket, sys
sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
sock.bind(sys.argv[1])
while True:
    data, sender = sock.recvfrom(4096)
    sock.sendto(data, sender)
"""


def percentiles_us(rtts: list[float]) -> str:
    """p50 / p99 / max of round-trip times, as text in µs."""
    ordered = sorted(rtts)
    if not ordered:
        return "no exchanges"
    pick = [ordered[int(q * (len(ordered) - 1))] for q in (0.5, 0.99)] + [ordered[-1]]
    return " / ".join(f"{1e6 * t:.0f}" for t in pick) + f" µs (p50 / p99 / max, {len(ordered)})"


def echo_reference(seconds: float, tmp: Path) -> list[float]:
    """Round trips at 1 kHz to a bare Python datagram echo process: the socket's own cost."""
    path = tmp / "echo.sock"
    echo = subprocess.Popen([sys.executable, "-c", ECHO, str(path)])
    try:
        while not path.exists():
            time.sleep(0.01)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind("")
        sock.connect(str(path))
        rtts: list[float] = []
        deadline = time.monotonic()
        end = deadline + seconds
        while deadline < end:
            t0 = time.perf_counter()
            sock.send(b"\x03" * 7)
            sock.recv(64)
            rtts.append(time.perf_counter() - t0)
            deadline += 0.001
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        sock.close()
        return rtts
    finally:
        echo.kill()
        echo.wait()


def run_case(name: str, extra_toml: str, seconds: float, tmp: Path,
             rtts: list[float] | None = None) -> float:
    port = free_port()
    run_dir = tmp / name.replace(" ", "_")
    run_dir.mkdir()
    config = run_dir / "robot.toml"
    config.write_text(
        f'extends = "{ROOT / "deploy" / "robots" / "sim.toml"}"\nname = "bench"\n'
        f'run_dir = "{run_dir}"\n{extra_toml}\n[sim]\nseed = 1\ncamera = false\n\n'
        f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n')
    cmd = [sys.executable, "-m"]
    log = open(run_dir / "log.txt", "wb")  # noqa: SIM115 - closed below
    router = subprocess.Popen([*cmd, "icefloe.router", "--config", str(config)], stdout=log,
                              stderr=log)
    time.sleep(1.0)
    sim = subprocess.Popen([*cmd, "icefloe.services.sim", "--config", str(config)], stdout=log,
                           stderr=log)
    stop = threading.Event()
    try:
        started = time.monotonic()
        while b"simulating a" not in (run_dir / "log.txt").read_bytes():  # imports, session
            log.flush()
            if time.monotonic() - started > 30 or sim.poll() is not None:
                raise SystemExit(f"the sim process ({name}) did not start:\n"
                                 + (run_dir / "log.txt").read_text(errors="replace"))
            time.sleep(0.1)
        time.sleep(1.0)  # first steps
        if rtts is not None:
            thread = threading.Thread(target=host_1khz,
                                      args=(str(run_dir / "icoboard.sock"), stop, rtts))
            thread.start()
            time.sleep(0.5)
        percent = cpu_percent(sim.pid, seconds)
        if sim.poll() is not None:
            log.flush()
            raise SystemExit(f"the sim process ({name}) exited during the measurement:\n"
                             + (run_dir / "log.txt").read_text(errors="replace"))
        return percent
    finally:
        stop.set()
        time.sleep(0.1)
        for proc in (sim, router):
            proc.send_signal(2)
            proc.wait(10)
        log.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="measuring window per case")
    parser.add_argument("--only", choices=["penguinpi", "icoboard"], help="measure one board kind")
    args = parser.parse_args()
    print(f"$ {' '.join([Path(sys.executable).name, *sys.argv])}")
    print(f"{os.cpu_count()} CPUs; {args.seconds:.0f} s window per case\n")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        ref = subprocess.Popen([sys.executable, "-c", REFERENCE])
        time.sleep(0.5)
        reference = cpu_percent(ref.pid, args.seconds)
        ref.kill()
        ref.wait()
        rows = [("reference: bare Python 1 kHz sleep loop", reference)]
        ico = '[board]\nkind = "icoboard"\nprotocol = 2\n'
        rtts: list[float] = []
        if args.only != "icoboard":
            rows.append(("sim process, penguinpi", run_case(
                "penguinpi", '[board]\nkind = "penguinpi"\n', args.seconds, tmp)))
        if args.only != "penguinpi":
            rows.append(("sim process, icoboard", run_case("icoboard", ico, args.seconds, tmp)))
            rows.append(("sim process, icoboard + 1 kHz host",
                         run_case("icoboard + 1 kHz host", ico, args.seconds, tmp, rtts)))
        echo = echo_reference(min(args.seconds, 5.0), tmp) if rtts else []
    for name, pct in rows:
        print(f"{name:45s} {pct:6.1f} % of one core")
    print("\ngoal: sim process under 25 % of one core (without the camera)\n")
    if not rtts:
        return
    print("exchange round trip, host <-> simulated icoBoard v2:")
    print(f"  {percentiles_us(rtts)}")
    print("reference: the same datagrams to a bare Python echo process:")
    print(f"  {percentiles_us(echo)}")


if __name__ == "__main__":
    main()

"""Lag and CPU of viz against the demo robot (goals: lag p99 < 50 ms, viz CPU < 30 % of one core).

    .venv/bin/python bench/viz_lag.py [--seconds 20]

Starts a Zenoh router on a free loopback port, the demo robot
(``python -m icefloe.services.viz.demo``) and viz with ``--save out.rrd --duration N``,
all as real processes. Figures:

* viz lag: for every row of the recording (but ``oled``, which has no stamp and is logged
  at arrival time), ``log_time - stamp``: from the moment the message was stamped to
  viz's Rerun log call, read back with ``services/viz/readback.py``.
* reference, measured in the same run: a raw zenoh-python subscriber in this process,
  on the same keys, measuring ``time.time_ns() - stamp`` in its callback: what the bus
  itself costs on this machine, with no asyncio, no decimation and no Rerun.
* viz CPU: user + system time of the viz process from ``/proc/<pid>/stat`` over the
  measuring window (after it has started showing the robot), as % of one core.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgspec
import zenoh
from common import cpu_seconds, free_port

ROOT = Path(__file__).resolve().parent.parent
GOAL_P99_MS = 50.0
GOAL_CPU_PERCENT = 30.0


def summary_ms(lags_ns: list[int]) -> str:
    """p50 / p99 / max of lags, as text in ms."""
    ordered = sorted(lags_ns)
    if not ordered:
        return "no samples"
    pick = [ordered[int(q * (len(ordered) - 1))] for q in (0.5, 0.99)] + [ordered[-1]]
    return " / ".join(f"{t / 1e6:6.1f}" for t in pick) + f" ms  ({len(ordered)} samples)"


def p99(lags_ns: list[int]) -> float:
    ordered = sorted(lags_ns)
    return ordered[int(0.99 * (len(ordered) - 1))] / 1e6 if ordered else float("inf")


class Stamped(msgspec.Struct):
    """Just the stamp of any stamped message (msgspec skips the other fields)."""

    stamp: int = 0


def raw_subscriber(config_path: Path, robot: str, lags: list[int]) -> zenoh.Session:
    """The reference: a plain zenoh-python session recording receive lag for viz's stamped keys."""
    from icefloe import config as config_mod
    from icefloe.runtime import zenoh_config
    from icefloe.schemas import keys
    from icefloe.services.viz.app import STREAMS

    config = config_mod.load(config_path)
    session = zenoh.open(zenoh_config(config, connect=config.zenoh.connect))
    decoder = msgspec.msgpack.Decoder(Stamped)

    def on_sample(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        stamp = decoder.decode(sample.payload.to_bytes()).stamp
        if stamp:
            lags.append(now - stamp)

    for stream in STREAMS:
        if stream.topic is not keys.OLED_FRAME:  # no stamp
            session.declare_subscriber(keys.key(robot, stream.topic), on_sample)
    return session


def wait_for_text(path: Path, text: str, proc: subprocess.Popen[bytes], timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while text not in path.read_text(errors="replace"):
        if proc.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"no {text!r} in {path}:\n{path.read_text(errors='replace')}")
        time.sleep(0.1)


def viz_lags(rrd: Path, robot: str) -> list[int]:
    from icefloe.services.viz.readback import read_rrd

    lags = []
    for entity, columns in read_rrd(rrd).items():
        if not entity.startswith(f"/robots/{robot}/") or entity.endswith("/oled"):
            continue
        for stamp, log_time in zip(columns.get("stamp", []), columns.get("log_time", []), strict=True):
            if stamp is not None and log_time is not None:
                lags.append(log_time - stamp)
    return lags


def run(seconds: float, tmp: Path) -> None:
    port, robot = free_port(), "bench"
    config = tmp / "robot.toml"
    config.write_text(
        f'extends = "{ROOT / "deploy" / "robots" / "sim.toml"}"\nname = "{robot}"\nrun_dir = "{tmp}"\n\n'
        f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n')
    rrd = tmp / "out.rrd"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    logs = {name: tmp / f"{name}.log" for name in ("router", "demo", "viz")}
    procs: list[subprocess.Popen[bytes]] = []

    def start(name: str, *args: str) -> subprocess.Popen[bytes]:
        with open(logs[name], "wb") as log:
            procs.append(subprocess.Popen([sys.executable, "-m", *args], stdout=log, stderr=subprocess.STDOUT,
                                          env=env, cwd=ROOT))
        return procs[-1]

    ref_lags: list[int] = []
    try:
        router = start("router", "icefloe.router", "--config", str(config))
        deadline = time.monotonic() + 15
        while socket.socket().connect_ex(("127.0.0.1", port)) != 0:
            if router.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"router did not listen:\n{logs['router'].read_text()}")
            time.sleep(0.05)
        demo = start("demo", "icefloe.services.viz.demo", "--config", str(config))
        duration = seconds + 30  # start-up (imports, session) comes first, the window after it
        viz = start("viz", "icefloe.services.viz", "--config", str(config), "--robot", robot,
                    "--save", str(rrd), "--duration", f"{duration:g}")
        wait_for_text(logs["viz"], "showing robot", viz)
        session = raw_subscriber(config, robot, ref_lags)
        time.sleep(1.0)  # first messages
        ref_lags.clear()
        c0, t0 = cpu_seconds(viz.pid), time.monotonic()
        time.sleep(seconds)
        c1, t1 = cpu_seconds(viz.pid), time.monotonic()
        session.close()
        if viz.poll() is not None or demo.poll() is not None:
            raise SystemExit(f"viz or the demo exited during the window:\n{logs['viz'].read_text()}"
                             f"\n{logs['demo'].read_text()}")
        viz.send_signal(2)  # stop early; viz flushes the .rrd on SIGINT
        if viz.wait(30) != 0:
            raise SystemExit(f"viz failed:\n{logs['viz'].read_text()}")
    finally:
        for proc in reversed(procs):
            if proc.poll() is None:
                proc.send_signal(2)
                proc.wait(10)

    cpu = 100.0 * (c1 - c0) / (t1 - t0)
    lags = viz_lags(rrd, robot)
    print(f"lag, stamp -> viz's rr.log (log_time - stamp):  {summary_ms(lags)}   "
          f"goal p99 < {GOAL_P99_MS:.0f} ms: {'met' if p99(lags) < GOAL_P99_MS else 'NOT MET'}")
    print(f"reference, stamp -> raw zenoh callback:         {summary_ms(ref_lags)}")
    print(f"viz CPU over {t1 - t0:.1f} s: {cpu:5.1f} % of one core   "
          f"goal < {GOAL_CPU_PERCENT:.0f} %: {'met' if cpu < GOAL_CPU_PERCENT else 'NOT MET'}")
    print("(percentiles: p50 / p99 / max; viz's rows are the whole recording, from start-up on)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="measuring window")
    args = parser.parse_args()
    print(f"$ {' '.join([Path(sys.executable).name, *sys.argv])}")
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; {args.seconds:.0f} s window\n")
    with tempfile.TemporaryDirectory() as tmp:
        run(args.seconds, Path(tmp))


if __name__ == "__main__":
    main()

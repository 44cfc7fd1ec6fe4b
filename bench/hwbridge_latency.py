"""Benchmark: hwbridge's real-time cycle under a flooded bus, next to cyclictest.

    .venv/bin/python bench/hwbridge_latency.py            # 60 s, 10 kHz flood
    .venv/bin/python bench/hwbridge_latency.py --seconds 10 --flood-hz 0

What runs (all real processes):

* the robot's Zenoh router and hwbridge (icoBoard protocol v2, 1 kHz);
* a board: `icefloe.sim.icoboard.IcoBoardModel` (the simulator's device model)
  behind hwbridge's datagram socket, in a process of its own, over a "world"
  whose encoder advances one count per exchange, so every count on the wire
  names the exchange that sampled it. It timestamps every frame it receives;
* a flooder publishing ``io/ledarray`` (an input hwbridge subscribes to) at
  ``--flood-hz``;
* ``cyclictest`` (Debian rt-tests) at the same SCHED_FIFO priority, at the
  same time, on the other CPU: the machine's own limit, in the same run.

What it prints:

* wake-up latency p50/p99/p99.9/max and overruns of the cycle over the window,
  from the cycle's own histogram (read from its shared memory), and the same
  for cyclictest;
* command-to-wire delay: ``cmd/stop`` published -> the first TRANSMIT frame
  with zero duties arriving at the board, p50/p99;
* encoder sample -> ``hw/wheels`` received on the bus, p50/p99.

Not a test: figures depend on the machine. Record them in docs/hwbridge.md.
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import contextlib
import multiprocessing as mp
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

from common import read_state, robot_config

ROOT = Path(__file__).resolve().parent.parent
SLOTS = 1 << 17
"""Sample-time slots: one per encoder count (one count per exchange: 131 s at 1 kHz)."""
MAX_STOPS = 1 << 14
PERIOD_US = 1000
"""The cycle's period at 1 kHz: a wake-up this late has missed a period."""


# --------------------------------------------------------------------------- the board process


class CountingWorld:
    """A world whose encoders advance one count per exchange (the board process bumps `n`)."""

    def __init__(self) -> None:
        self.n = 0

    def set_duty(self, left: float, right: float) -> None:
        pass

    def counts(self) -> tuple[int, int]:
        return self.n, self.n


def board_process(config_path: str, sample_ns, zero_ns, zero_count, ready) -> None:
    """Serve hwbridge's exchanges with the simulator's icoBoard model; record timings."""
    from icefloe import config as config_mod
    from icefloe.sim.icoboard import IcoBoardModel
    from icefloe.wire.icoboard import Op, Wire

    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(70))  # a board answers at once
    config = config_mod.load(config_path)
    wire = Wire.for_board(config.board)
    world = CountingWorld()
    model = IcoBoardModel(world, wire)
    path = config.board.sim_socket
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    ready.set()
    driving = False
    while True:
        frame, sender = sock.recvfrom(512)
        now = time.monotonic_ns()
        if frame[:1] == bytes([Op.TRANSMIT]):
            world.n += 1
            count = model.counts()[0]
            if 0 <= count < SLOTS:
                sample_ns[count] = now  # v2 samples just before replying
            duties = frame[2:6]
            if any(duties):
                driving = True
            elif driving:  # the first zero-duty frame after driving: a stop reached the wire
                driving = False
                if zero_count.value < MAX_STOPS:
                    zero_ns[zero_count.value] = now
                    zero_count.value += 1
        reply = model.exchange(frame, now * 1e-9)
        with contextlib.suppress(OSError):
            sock.sendto(reply, sender)


# --------------------------------------------------------------------------- the flooder


def flood_process(config_path: str, rate_hz: float) -> None:
    """Publish io/ledarray at ``rate_hz`` (in bursts every millisecond) until killed."""

    from icefloe import config as config_mod
    from icefloe.runtime import raw_session
    from icefloe.schemas import codec, keys
    from icefloe.schemas import messages as m

    config = config_mod.load(config_path)
    session = raw_session(config)
    pub = session.declare_publisher(keys.key(config.name, keys.LEDARRAY))
    payload = codec.encode(m.LedArray(mask=0x5A5A))
    sent, start = 0, time.monotonic()
    while True:
        due = int((time.monotonic() - start) * rate_hz)
        while sent < due:
            pub.put(payload)
            sent += 1
        time.sleep(0.001)


def hop_process(config_path: str, hop_ns, hop_count, ready) -> None:
    """Reference: a raw zenoh-python subscriber to ``cmd/stop`` that takes the time in its
    callback. Its delay is the bus's share of command -> wire, measured in the same run."""
    import zenoh

    from icefloe import config as config_mod
    from icefloe.runtime import raw_session
    from icefloe.schemas import keys

    config = config_mod.load(config_path)
    session = raw_session(config)

    def on_sample(_sample: zenoh.Sample) -> None:
        if hop_count.value < MAX_STOPS:
            hop_ns[hop_count.value] = time.monotonic_ns()
            hop_count.value += 1

    session.declare_subscriber(keys.key(config.name, keys.STOP), on_sample)
    ready.set()
    while True:
        time.sleep(1.0)


# --------------------------------------------------------------------------- figures


def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def hist_percentiles(counts: list[int], width_us: float = 1.0) -> dict[str, float]:
    """p50/p99/p99.9 in µs (upper bin edges) from 1-µs bins."""
    total = sum(counts)
    out = {}
    for name, q in (("p50", 0.5), ("p99", 0.99), ("p99.9", 0.999)):
        running = 0
        for i, c in enumerate(counts):
            running += c
            if c and running >= q * total:
                out[name] = (i + 1) * width_us
                break
    return out


def parse_cyclictest(text: str) -> dict[str, float]:
    """Percentiles, max and overflows from ``cyclictest -q -h N`` output."""
    counts: list[int] = []
    for line in text.splitlines():
        match = re.match(r"^(\d+)\s+(\d+)", line)
        if match:
            counts.append(int(match.group(2)))
    figures = hist_percentiles(counts)
    figures["late"] = float(sum(counts[PERIOD_US:]))  # plus the overflows, added below
    for key in ("Max Latencies", "Histogram Overflows", "Total"):
        match = re.search(rf"# {key}:\s+(\d+)", text)
        if match:
            figures[key] = float(match.group(1))
    figures["late"] += figures.get("Histogram Overflows", 0.0)
    return figures


# --------------------------------------------------------------------------- main


async def measure(config_path: Path, args: argparse.Namespace, rec: SimpleNamespace):
    from icefloe import config as config_mod
    from icefloe.runtime import Node
    from icefloe.schemas import codec, keys
    from icefloe.schemas import messages as m
    from icefloe.services.hwbridge.control import HIST_BINS, hist_bin, percentiles
    from icefloe.services.hwbridge.shm import Shared, block_name

    config = config_mod.load(config_path)
    async with Node("bench", config) as node:
        raw = node.subscribe_raw(keys.key(config.name, keys.WHEELS), maxsize=100_000)
        await asyncio.wait_for(anext(raw), 20)
        shared = Shared.attach(block_name(config.name))
        state0, hist0 = read_state(shared), list(shared.hist)
        cpus = sorted(os.sched_getaffinity(0))
        other_cpu = cpus[0] if len(cpus) > 1 else cpus[-1]
        cyclic = subprocess.Popen(
            ["cyclictest", "-m", "-q", "-p", str(config.hwbridge.priority), "-i", "1000",
             "-D", str(args.seconds), "-h", "2000", "-a", str(other_cpu), "-t", "1"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) \
            if shutil.which("cyclictest") else None
        wheels_pub, stop_pub = node.publisher(keys.WHEELS_CMD), node.publisher(keys.STOP)
        stops: list[float] = []
        wheel_lat: list[float] = []
        # hwbridge's ticks are 0 at the RECEIVE its handshake makes, just before the first
        # TRANSMIT; the first TRANSMIT (the first recorded count) is then ticks 1.
        base = first_count(rec.sample_ns) - 1
        wall_offset = time.time() - time.monotonic()
        stamp_lat: list[float] = []
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            for _ in range(3):
                wheels_pub.put(m.WheelSpeeds(left=0.2, right=0.2))
                await asyncio.sleep(0.02)
            stops.append(time.monotonic_ns())
            stop_pub.put(m.Stop())
            await asyncio.sleep(0.04)
            while raw.pending():
                sample = await anext(raw)
                w = codec.decode(sample.payload, sample.encoding, m.Wheels)
                count = w.ticks_left + base
                if 0 <= count < SLOTS and rec.sample_ns[count]:
                    wheel_lat.append(sample.received * 1e9 - rec.sample_ns[count])
                # Cross-check on another clock: hwbridge's own stamp (taken right after the
                # exchange) -> received.
                stamp_lat.append((sample.received + wall_offset) * 1e9 - w.stamp)
        state1, hist1 = read_state(shared), list(shared.hist)
        shared.close()
        cyclic_out = cyclic.communicate()[0] if cyclic else ""
    delta = [b - a for a, b in zip(hist0, hist1, strict=True)]
    assert len(delta) == HIST_BINS and hist_bin(0) == 0
    p50, p99, p999, pmax = percentiles(delta, (0.5, 0.99, 0.999, 1.0))
    wire = delays(stops, rec.zero_ns, rec.zero_count.value)
    hop = delays(stops, rec.hop_ns, rec.hop_count.value)
    # Per stop: wire minus the reference's hop ~ what hwbridge adds after the bus delivered it.
    share = [w - h for w, h in zip(wire, hop, strict=True)] if len(wire) == len(hop) else []
    cycles = state1["cycles"] - state0["cycles"]
    return {
        "cycles": cycles, "overruns": state1["overruns"] - state0["overruns"],
        "late": sum(delta[hist_bin(PERIOD_US * 1000):]),
        "p50": p50 * 1e6, "p99": p99 * 1e6, "p99.9": p999 * 1e6, "max": pmax * 1e6,
        "timeouts": state1["timeouts"] - state0["timeouts"],
        "kicks": state1["kicks"] - state0["kicks"], "stamp": stamp_lat,
        "wire": wire, "hop": hop, "share": share, "wheels": wheel_lat, "cyclic": parse_cyclictest(cyclic_out),
        "cyclic_cpu": other_cpu, "rt_cpu": cpus[-1],
    }


async def measure_penguinpi(config_path: Path, args: argparse.Namespace) -> dict:
    """PenguinPi (the simulator's firmware model on a pty): exchange rate and cycle latency."""
    from icefloe import config as config_mod
    from icefloe.runtime import Node
    from icefloe.schemas import keys
    from icefloe.schemas import messages as m
    from icefloe.services.hwbridge.control import percentiles
    from icefloe.services.hwbridge.shm import Shared, block_name

    config = config_mod.load(config_path)
    async with Node("bench", config) as node:
        loops = node.subscribe(keys.LOOP, latest=False)
        await asyncio.wait_for(anext(loops), 30)
        shared = Shared.attach(block_name(config.name))
        state0, hist0 = read_state(shared), list(shared.hist)
        twist = node.publisher(keys.TWIST)
        rates: list[float] = []
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            twist.put(m.Twist(v=0.1, w=0.0))
            await asyncio.sleep(0.05)
            while loops.pending():
                rates.append((await anext(loops)).link_rate)
        state1, hist1 = read_state(shared), list(shared.hist)
        shared.close()
    delta = [b - a for a, b in zip(hist0, hist1, strict=True)]
    p50, p99, p999, pmax = percentiles(delta, (0.5, 0.99, 0.999, 1.0))
    errors = {k: state1[k] - state0[k] for k in ("crc_errors", "timeouts", "unmatched",
                                                  "garbage_bytes")}
    return {"cycles": state1["cycles"] - state0["cycles"],
            "overruns": state1["overruns"] - state0["overruns"],
            "p50": p50 * 1e6, "p99": p99 * 1e6, "p99.9": p999 * 1e6, "max": pmax * 1e6,
            "rates": rates, "errors": errors}


def first_count(sample_ns) -> int:
    """The encoder count of the first TRANSMIT exchange (hwbridge's unwrapped ticks start there)."""
    return next(i for i in range(SLOTS) if sample_ns[i])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=int, default=60)
    parser.add_argument("--flood-hz", type=float, default=10_000)
    parser.add_argument("--wheels-hz", type=float, default=100.0,
                        help="hwbridge.wheels_rate_hz: rate of hw/wheels (0 = every cycle)")
    parser.add_argument("--penguinpi", action="store_true",
                        help="run the simulated PenguinPi instead: serial exchange rate achieved")
    args = parser.parse_args()
    if args.penguinpi:
        return penguinpi_main(args)
    tmp = Path(tempfile.mkdtemp(prefix="hwbridge-bench-"))
    config_path = robot_config(tmp, f"bench{os.getpid()}",
                               f'[board]\nkind = "icoboard"\nbackend = "sim"\nprotocol = 2\n'
                               f'sim_socket = "{tmp}/board.sock"\n[hwbridge]\nwheels_rate_hz = {args.wheels_hz}\n')
    ctx = mp.get_context("spawn")
    rec = SimpleNamespace(  # what the helper processes record, in shared memory
        sample_ns=ctx.Array("q", SLOTS, lock=False), zero_ns=ctx.Array("q", MAX_STOPS, lock=False),
        zero_count=ctx.Value("q", 0, lock=False), hop_ns=ctx.Array("q", MAX_STOPS, lock=False),
        hop_count=ctx.Value("q", 0, lock=False))
    ready = ctx.Event()
    board = ctx.Process(target=board_process, args=(str(config_path), rec.sample_ns, rec.zero_ns,
                                                    rec.zero_count, ready), daemon=True)
    board.start()
    ready.wait(10)
    procs = []
    logs = []

    def start(*cmd: str, name: str) -> None:
        log = open(tmp / f"{name}.log", "wb")  # noqa: SIM115 - closed at the end
        logs.append(log)
        procs.append(subprocess.Popen([sys.executable, *cmd], stdout=log, stderr=subprocess.STDOUT,
                                      cwd=ROOT))

    start("-m", "icefloe.router", "--config", str(config_path), name="router")
    time.sleep(1.0)
    start("-m", "icefloe.services.hwbridge", "--config", str(config_path), name="hwbridge")
    ready = ctx.Event()
    hop = ctx.Process(target=hop_process, args=(str(config_path), rec.hop_ns, rec.hop_count, ready),
                      daemon=True)
    hop.start()
    ready.wait(10)
    helpers = [board, hop, *start_flooder(config_path, args.flood_hz)]
    try:
        r = asyncio.run(measure(config_path, args, rec))
    finally:
        stop_all(procs, logs, helpers)
    c = r["cyclic"]
    print(f"hwbridge latency bench: {args.seconds} s at 1 kHz, bus flood {args.flood_hz:g} msg/s "
          f"on io/ledarray; logs in {tmp}")
    print(f"{'':28}{'p50':>8}{'p99':>8}{'p99.9':>8}{'max':>8}   (µs)")
    print(f"{'hwbridge cycle wake-up':28}{r['p50']:8.0f}{r['p99']:8.0f}{r['p99.9']:8.0f}"
          f"{r['max']:8.0f}   {r['cycles']} cycles, {r['late']} woke >= 1 period late, {r['overruns']} overruns, "
          f"{r['timeouts']} board timeouts (CPU {r['rt_cpu']})")
    if c:
        print(f"{'cyclictest (same prio)':28}{c.get('p50', 0):8.0f}{c.get('p99', 0):8.0f}"
              f"{c.get('p99.9', 0):8.0f}{c.get('Max Latencies', 0):8.0f}   "
              f"{c.get('Total', 0):.0f} cycles, {c.get('late', 0):.0f} woke >= 1 period late "
              f"(CPU {r['cyclic_cpu']})")
    else:
        print("cyclictest: not installed (apt-get install rt-tests)")
    row("command -> wire (cmd/stop)", r["wire"],
        f"{len(r['wire'])} stops, {r['kicks']} sent between periods")
    row("  reference: bus hop only", r["hop"], "cmd/stop -> a raw zenoh-python callback")
    row("  difference, per stop", r["share"], "wire - hop: hwbridge's own share, roughly")
    row("encoder sample -> hw/wheels", r["wheels"], f"{len(r['wheels'])} samples")
    row("  cross-check: cycle stamp", r["stamp"], "hwbridge's stamp -> received (wall clock)")


def start_flooder(config_path: Path, rate_hz: float) -> list[mp.Process]:
    """The bus flood (`flood_process`) in a process of its own; none when ``rate_hz`` is 0."""
    if rate_hz <= 0:
        return []
    flooder = mp.get_context("spawn").Process(target=flood_process, args=(str(config_path), rate_hz),
                                              daemon=True)
    flooder.start()
    return [flooder]


def stop_all(procs: list[subprocess.Popen], logs: list, helpers: list[mp.Process]) -> None:
    """SIGINT the stack's processes, last started first, then end the bench's helpers (the board
    model last of all: hwbridge tells it EXIT on its way out)."""
    for p in reversed(procs):
        p.send_signal(2)
        with contextlib.suppress(subprocess.TimeoutExpired):
            p.wait(10)
    for helper in helpers:
        helper.terminate()
    for log in logs:
        log.close()


def row(name: str, values_ns: list[float], note: str) -> None:
    """One line of delays in ms: p50, p99, max."""
    ms = 1e-6
    print(f"{name:28}{pct(values_ns, 0.5) * ms:8.2f}{pct(values_ns, 0.99) * ms:8.2f}{'':8}"
          f"{max(values_ns, default=0) * ms:8.2f}   ms, {note}")


def delays(starts: list[int], events, count: int) -> list[float]:
    """For each start time, ns to the first recorded event after it."""
    times = sorted(events[i] for i in range(count))
    out = []
    for t in starts:
        i = bisect.bisect_right(times, t)
        if i < len(times):
            out.append(times[i] - t)
    return out


def penguinpi_main(args: argparse.Namespace) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="hwbridge-bench-ppi-"))
    config_path = robot_config(tmp, f"bench{os.getpid()}")
    procs, logs = [], []
    for module in ("icefloe.router", "icefloe.services.sim", "icefloe.services.hwbridge"):
        log = open(tmp / f"{module.rsplit('.', 1)[-1]}.log", "wb")  # noqa: SIM115
        logs.append(log)
        procs.append(subprocess.Popen([sys.executable, "-m", module, "--config", str(config_path)],
                                      stdout=log, stderr=subprocess.STDOUT, cwd=ROOT))
        time.sleep(1.0)
    helpers = start_flooder(config_path, args.flood_hz)
    try:
        r = asyncio.run(measure_penguinpi(config_path, args))
    finally:
        stop_all(procs, logs, helpers)
    rates = r["rates"]
    print(f"hwbridge PenguinPi bench: {args.seconds} s, cycle 1 kHz, serial exchanges asked at "
          f"200 Hz, bus flood {args.flood_hz:g} msg/s; logs in {tmp}")
    print(f"cycle wake-up (µs): p50 {r['p50']:.0f}  p99 {r['p99']:.0f}  p99.9 {r['p99.9']:.0f}  "
          f"max {r['max']:.0f};  {r['cycles']} cycles, {r['overruns']} overruns")
    if rates:
        print(f"MULTI_SET_VEL_GET_ENC exchanges per second (hw/loop link_rate): "
              f"mean {sum(rates) / len(rates):.1f}, min {min(rates):.1f}, max {max(rates):.1f}")
    print(f"link errors in the window: {r['errors']}")


if __name__ == "__main__":
    main()

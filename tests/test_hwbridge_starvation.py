"""hwbridge on a starved machine: a cycle held in the middle of a write, a bus process under a CPU
hog, a cycle that dies.

The shared memory between hwbridge's two processes is a seqlock: a reader that finds a write in
progress tries again. A cycle without SCHED_FIFO (a laptop, a lab of robots on one machine) can be
descheduled in the middle of a write for longer than a reader spins; the read is then put off and
counted (``hw/loop`` ``stalled_reads``), never raised. A cycle that is gone makes hwbridge stop the
board and exit, so that its supervisor starts both afresh.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import ROOT, processes_naming, robot_config, wait_for
from test_hwbridge_helpers import driving, sim_state, start_stack

from icefloe import config as config_mod
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.hwbridge.shm import (
    CMD_SLOT,
    OFF_CMD,
    OFF_CMD_SEQ,
    OFF_STATE_SEQ,
    READ_TRIES,
    STATE_FIELDS,
    Shared,
    block_name,
)
from icefloe.wire import penguinpi as ppi
from icefloe.wire.penguinpi import Address, MultiOp

HOLD_S = 2.0
"""How long the cycle stays stopped mid-write: four deadman periods."""


# ---------------------------------------------------------------------------- helpers


def process_state(pid: int) -> str:
    """The state letter of /proc/<pid>/stat: R running, S sleeping, T stopped, ..."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]


def threads(pid: int) -> list[int]:
    return [int(t.name) for t in Path(f"/proc/{pid}/task").iterdir()]


@contextlib.contextmanager
def held_mid_write(rt_pid: int, shared: Shared) -> Iterator[None]:
    """The cycle stopped (SIGSTOP) in the middle of writing its state, as a starved machine leaves a
    descheduled writer: its sequence number odd. Resumed (SIGCONT) on exit.

    The stop lands wherever the cycle is, most likely asleep between periods; then the sequence
    number is made odd here, which is the first thing the cycle does when it writes.
    """
    os.kill(rt_pid, signal.SIGSTOP)
    deadline = time.monotonic() + 5.0
    while process_state(rt_pid) != "T":
        assert time.monotonic() < deadline, "the cycle did not stop"
        time.sleep(0.001)
    seq = shared._word(OFF_STATE_SEQ)
    if not seq & 1:
        shared._set_word(OFF_STATE_SEQ, seq + 1)
    try:
        yield
    finally:
        if not seq & 1:
            shared._set_word(OFF_STATE_SEQ, seq)  # as it was: the cycle's own write goes on from there
        os.kill(rt_pid, signal.SIGCONT)


@contextlib.contextmanager
def cpu_hog(pid: int, hogs: int = 3) -> Iterator[None]:
    """``hogs`` busy processes on one CPU, and every thread of process ``pid`` moved onto it too:
    the process gets about 1/(hogs + 1) of a CPU."""
    cpu = min(os.sched_getaffinity(0))
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(hogs)]
    moved = {}
    try:
        for proc in busy:
            os.sched_setaffinity(proc.pid, {cpu})
        for tid in threads(pid):
            with contextlib.suppress(OSError):
                moved[tid] = os.sched_getaffinity(tid)
                os.sched_setaffinity(tid, {cpu})
        yield
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
        for tid, cpus in moved.items():
            with contextlib.suppress(OSError):  # a thread that ended meanwhile
                os.sched_setaffinity(tid, cpus)


async def rt_pid_of(robot: str) -> int:
    """The pid of a robot's real-time cycle, from its state (read again if a read is put off)."""
    shared = Shared.attach(block_name(robot))
    try:
        for _ in range(100):
            if (state := shared.read_state()) is not None and state["pid"]:
                return int(state["pid"])
            await asyncio.sleep(0.01)
    finally:
        shared.close()
    raise AssertionError("no state from the cycle")


async def until_at_rest(node: Node, timeout: float) -> m.SimState:
    """The simulated robot's state once both wheels truly turn slower than 5 mm/s."""
    deadline = time.monotonic() + timeout
    while abs((state := await sim_state(node)).speed_left) > 0.005 or abs(state.speed_right) > 0.005:
        assert time.monotonic() < deadline, f"the wheels did not stop: {state}"
        await asyncio.sleep(0.05)
    return state


# ---------------------------------------------------------------------------- the seqlock alone


def test_a_state_read_that_finds_a_write_in_progress_is_put_off_and_counted() -> None:
    shared = Shared.create()
    try:
        shared.write_state([0] * len(STATE_FIELDS))
        seq = shared._word(OFF_STATE_SEQ)
        shared._set_word(OFF_STATE_SEQ, seq + 1)         # the cycle stopped half-way
        t0 = time.perf_counter()
        assert shared.read_state() is None
        spent = time.perf_counter() - t0
        assert shared.stalled_reads == 1
        assert spent < 0.05, f"{READ_TRIES} tries took {spent * 1e3:.1f} ms"  # gives the CPU back soon
        shared._set_word(OFF_STATE_SEQ, seq + 2)         # the write finished
        assert shared.read_state() is not None
    finally:
        shared.close()


def test_a_commands_write_in_progress_leaves_the_cycle_the_last_complete_one() -> None:
    """The bus process stopped half-way through the write after a stop (its slot's number odd,
    half its fields new): the cycle reads the stop, at once, every time; nothing is put off."""
    shared = Shared.create()
    try:
        shared.write_commands(0.3, 0.3, 100, False, 0, 0)
        shared.write_commands(0.0, 0.0, 100, True, 0, 1)      # a stop, written whole
        version = shared._word(OFF_CMD_SEQ)
        writing = OFF_CMD + ((version + 1) % 2) * CMD_SLOT    # the next write's slot
        shared._set_word(writing, shared._word(writing) + 1)  # ... begun, and stopped half-way
        shared._set_word(writing + 8, 0x7FF0_0000_0000_0000)  # (0.3 m/s's slot: now +inf)
        for _ in range(1000):
            assert shared.read_commands() == (0.0, 0.0, 100, 1, 0, 1)
        assert shared.stalled_reads == 0
        # Only a slot being rewritten under the reader on every try puts the read off. A writer
        # rewrites the published slot only after publishing a newer version (the cycle then reads
        # that one), so a reader that holds a copy of this version keeps it: `read_commands`
        # does not read the slot again while the version stands. One that has not read it yet
        # must copy the slot, and gives up for now.
        published = OFF_CMD + (version % 2) * CMD_SLOT
        shared._set_word(published, shared._word(published) + 1)
        assert shared.read_commands() == (0.0, 0.0, 100, 1, 0, 1) and shared.stalled_reads == 0
        fresh = Shared.attach(shared.name)
        try:
            assert fresh.read_commands() is None and fresh.stalled_reads == 1
        finally:
            fresh.close()
    finally:
        shared.close()


def test_commands_read_while_written_from_threads_are_whole_and_never_put_off() -> None:
    """Writers on two threads (as Zenoh's and the event loop's are), Python switching between
    threads every microsecond, so mid-write: every read is one complete write."""
    shared = Shared.create()
    lock = threading.Lock()
    done = threading.Event()
    interval = sys.getswitchinterval()
    writers: list[threading.Thread] = []

    def write(sign: float) -> None:
        i = 0
        while not done.is_set():
            i += 1
            with lock:  # one writer at a time, as `Bridge.sync`
                shared.write_commands(sign * i, -sign * i, i, i % 2 == 0, i, i)

    try:
        shared.write_commands(0.0, 0.0, 0, False, 0, 0)
        sys.setswitchinterval(1e-6)
        writers += [threading.Thread(target=write, args=(sign,)) for sign in (1.0, -1.0)]
        for w in writers:
            w.start()
        reads = 0
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            got = shared.read_commands()
            assert got is not None
            left, right, fresh, stop, epoch, stop_seq = got
            assert left == -right and abs(left) == fresh == epoch == stop_seq and stop == (fresh % 2 == 0), got
            reads += 1
        assert shared.stalled_reads == 0 and reads > 1000
    finally:
        done.set()
        sys.setswitchinterval(interval)
        for w in writers:
            w.join()
        shared.close()


# ---------------------------------------------------------------------------- real processes


@pytest.mark.slow
async def test_a_cycle_held_mid_write_and_a_cpu_hog_crash_nothing(robot) -> None:
    async with robot.node() as node:
        _sim, hw = await start_stack(robot, node)
        rt_pid = await rt_pid_of(robot.name)
        shared = Shared.attach(block_name(robot.name))
        try:
            async with driving(node, v=0.2):
                await asyncio.sleep(1.0)                 # driving at 0.2 m/s
            with cpu_hog(hw.popen.pid):
                with held_mid_write(rt_pid, shared):
                    # The student's twists stopped; the cycle cannot run its deadman, the bus
                    # process cannot read the state. It keeps trying, with back-off.
                    await asyncio.sleep(HOLD_S)
                    assert hw.alive(), hw.output
                wheels = node.subscribe(keys.WHEELS, latest=False, maxsize=1000)
                loops = node.subscribe(keys.LOOP, latest=False, maxsize=100)
                # Resumed: its first period finds the last command older than the deadman.
                first = await asyncio.wait_for(anext(wheels), 10.0)
                assert (first.target_left, first.target_right) == (0.0, 0.0)
                await until_at_rest(node, 10.0)

                async def counted() -> m.LoopStats:
                    async for stats in loops:
                        if stats.stalled_reads > 0:
                            return stats
                    raise AssertionError("hw/loop ended")

                stats = await asyncio.wait_for(counted(), 10.0)
                assert hw.alive(), hw.output
            # Everything recovers: the same two processes drive the robot again.
            start = await sim_state(node)
            async with driving(node, v=0.2):
                await asyncio.sleep(1.5)
            end = await sim_state(node)
            assert end.x - start.x > 0.1, (start, end)
            assert hw.alive() and await rt_pid_of(robot.name) == rt_pid
            assert "Traceback" not in hw.output, hw.output
            print(f"stalled reads counted in hw/loop: {stats.stalled_reads}")
        finally:
            shared.close()


@pytest.mark.slow
async def test_a_dead_cycle_stops_the_penguinpi_and_hwbridge_exits(robot) -> None:
    async with robot.node() as node:
        _sim, hw = await start_stack(robot, node)
        rt_pid = await rt_pid_of(robot.name)
        async with driving(node, v=0.2):                 # the student goes on sending twists
            await asyncio.sleep(1.0)
            assert (await sim_state(node)).speed_left > 0.1
            os.kill(rt_pid, signal.SIGKILL)              # the real-time process only
            await wait_for(lambda: not hw.alive(), timeout=15)
            # The PenguinPi keeps its last demand for ever unless told: the bus process told it
            # (MULTI_ALL_STOP), and nothing drives it after that.
            state = await until_at_rest(node, 5.0)
            await asyncio.sleep(0.5)
            still = await sim_state(node)
        assert hw.popen.returncode == 4, hw.output
        assert "real-time process exited with status -9; the board was told to stop" in hw.output
        assert still.last_frame == ppi.encode_frame(Address.AD_MULTI, MultiOp.MULTI_ALL_STOP), still
        assert abs(still.x - state.x) < 0.005, (state, still)


@pytest.mark.slow
def test_a_dead_cycle_stops_the_wheels_and_icefloe_up_restarts_hwbridge(tmp_path: Path) -> None:
    cfg_path = robot_config(tmp_path, "rtgone", 'services = ["sim", "hwbridge"]')
    cfg = config_mod.load(cfg_path)
    log = tmp_path / "up.log"
    with open(log, "w") as out:
        up = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "up", str(cfg_path), "--no-viz"],
                              stdout=out, stderr=subprocess.STDOUT, cwd=ROOT, start_new_session=True)

    async def scenario() -> None:
        async with Node("tester", cfg) as node:
            await wait_for(lambda: "board link up" in log.read_text(), timeout=30)
            rt_pid = await rt_pid_of(cfg.name)
            async with driving(node, v=0.2):
                await asyncio.sleep(1.0)
                moving = await sim_state(node)
                assert moving.speed_left > 0.1, moving
                os.kill(rt_pid, signal.SIGKILL)          # the real-time process only
                await wait_for(lambda: "exited with code 4; restarting" in log.read_text(), timeout=15)
                # icefloe up started hwbridge again, with a new cycle: the twists drive again.
                await wait_for(lambda: log.read_text().count("board link up") >= 2, timeout=30)
                await asyncio.sleep(1.0)
                again = await sim_state(node)
            assert again.speed_left > 0.1, again

    try:
        asyncio.run(scenario())
        text = log.read_text()
        assert "real-time process exited with status -9; the board was told to stop" in text, text
        up.send_signal(signal.SIGINT)
        assert up.wait(30) == 0
        assert processes_naming(str(cfg_path)) == []
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
            up.wait()

"""hwbridge's real-time process: the periodic cycle that talks to the board.

Started by the bus process (``__main__.py``) as ``python -m
icefloe.services.hwbridge.rt --shm NAME`` with the robot config as JSON on
stdin. It never imports Zenoh: a Zenoh callback thread can hold the GIL for
milliseconds, so the cycle lives in a process of its own and exchanges data
with the bus process only through shared memory (`shm.Shared`).

Each period (``hwbridge.rate_hz``, 1 kHz by default):

1. sleep until an *absolute* deadline: libc ``clock_nanosleep(CLOCK_MONOTONIC,
   TIMER_ABSTIME)`` through ctypes (Python's ``time.sleep`` is relative, so its
   error would accumulate); record the wake-up latency in a fixed histogram;
2. read the commands (seqlock), apply stop latch, deadman, speed limit and
   acceleration limit (`control`);
3. run one board exchange (`board.Board.cycle`: never waits on the link);
   zero targets (a stop, the deadman, or a command of zero speed) put the board
   in its stopped state: zero duty, controller cleared;
4. publish the state (seqlock), with the number of the latest latched stop the
   board has confirmed (``stop_confirmed``), and forward at most one
   LED/text/screen command.

A cycle that ends after the next deadline is an overrun: it is counted and the
missed deadlines are skipped, not caught up in a burst.

A stop does not wait for the period: when the bus process latches ``cmd/stop``
it sends this process ``SIGUSR1``, which ends the sleep early, and the cycle
sends the stop to the board at once (`Cycle.stop_now`), unless the next
period is due within an eighth of a period. Motion commands wait for the next period.

At rest the cycle rests: once the robot has stood for ``hwbridge.rest_after_s`` (zero targets,
zero duty confirmed by the board, the encoders unchanged: `control.RestGate`) it runs at
``hwbridge.rest_rate_hz`` (50 Hz) and says so in the shared memory's rest word. The bus side
then sends SIGUSR1 for the first motion command it writes (`Bridge.wake`), and the cycle runs
its next period at once, at the full rate (`Cycle.wake`): a command from rest waits no longer
than one from a running cycle. A stop at rest needs no period (the wheels are at zero duty,
confirmed) and is confirmed at once. A wheel turned by hand, or the board's confirmation lost,
ends the rest at the next rest period. The longer sleep is not an overrun; ``hw/loop`` shows
the rate the cycle ran at.

Where the OS allows it: ``SCHED_FIFO`` at ``hwbridge.priority``, ``mlockall``,
pinned to ``hwbridge.cpu``; what is withheld is one warning line, and the cycle carries on. The garbage
collector is disabled and every object made during setup is frozen; the cycle
itself creates only short-lived objects that reference counting frees at once.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import ctypes.util
import gc
import math
import os
import signal
import sys
import time

import msgspec

from icefloe.config import RobotConfig
from icefloe.errors import BoardError, BoardMismatch

from .board import MSG_ERROR, MSG_INFO, MSG_WARNING, Board, Say, make_board
from .control import STOP_LATCHED, STOP_NONE, RestGate, SlewLimiter, gate, hist_bin
from .shm import Shared

CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1
MCL_CURRENT, MCL_FUTURE = 1, 2
PR_SET_PDEATHSIG = 1
RETRY_NS = 1_000_000_000
"""After the board link is lost, try to reopen it once a second."""
KICK_GUARD_FRACTION = 8
"""A stop within period / 8 of the next deadline waits for it (`Cycle.stop_now`)."""
EXIT_MISMATCH = 3
"""Exit status when the board is not the one the config describes (do not restart)."""
PUBLISH_PERIODS = 10
"""The state is written at once when there is news for the bus side (a new encoder sample, a stop,
a stop confirmed, the link up or down), else every 10th period (10 ms at 1 kHz: the loop
statistics, battery, buttons). Writing it every period was a fifth of the cycle's own work."""


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class AbsoluteTimer:
    """Sleeps until an absolute CLOCK_MONOTONIC time, in ns.

    Uses libc ``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, ...)``; the
    argument struct is allocated once. Where libc has no clock_nanosleep, falls
    back to ``time.sleep`` of the remaining time (``self.kind`` says which).
    """

    def __init__(self) -> None:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        self._ts = _Timespec()
        self._ref = ctypes.byref(self._ts)
        try:
            self._sleep = libc.clock_nanosleep
            self._sleep.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Timespec),
                                    ctypes.c_void_p]
            self._sleep.restype = ctypes.c_int
            self.kind = "clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME) via ctypes"
        except AttributeError:
            self._sleep = None
            self.kind = "time.sleep (relative; no clock_nanosleep in libc)"

    def sleep_until(self, deadline_ns: int) -> None:
        """Return at or after ``deadline_ns`` (early only if a signal arrives)."""
        if self._sleep is None:
            remaining = deadline_ns - time.monotonic_ns()
            if remaining > 0:
                time.sleep(remaining * 1e-9)
            return
        self._ts.tv_sec, self._ts.tv_nsec = divmod(deadline_ns, 1_000_000_000)
        self._sleep(CLOCK_MONOTONIC, TIMER_ABSTIME, self._ref, None)  # EINTR: the caller checks


def make_realtime(priority: int, cpu: int, say: Say) -> None:
    """SCHED_FIFO, mlockall and CPU pinning, each where permitted. What is withheld (a laptop, a
    container, a unit without LimitRTPRIO/LimitMEMLOCK) is said in ONE warning line, and the cycle
    runs anyway."""
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    withheld = []
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError, ValueError) as exc:
        withheld.append(f"SCHED_FIFO priority {priority} ({getattr(exc, 'strerror', None) or exc})")
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        withheld.append(f"mlockall ({os.strerror(ctypes.get_errno())})")
    try:
        cpus = sorted(os.sched_getaffinity(0))
        target = cpus[-1] if cpu < 0 else cpu
        os.sched_setaffinity(0, {target})
    except (OSError, AttributeError, ValueError) as exc:
        withheld.append(f"pinning to CPU {cpu} ({getattr(exc, 'strerror', None) or exc})")
    if withheld:
        say(MSG_WARNING, f"real time withheld here: {', '.join(withheld)}; the cycle runs anyway, "
                         "expect more latency (docs/deploy.md#real-time-kernels)")
    # If the bus process dies, the kernel sends us SIGTERM: we stop the wheels and exit.
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


class Cycle:
    """The periodic loop: commands in, one board exchange, state out."""

    def __init__(self, config: RobotConfig, shared: Shared, board: Board | None = None) -> None:
        hw = config.hwbridge
        self.config = config
        self.shared = shared
        self.period_ns = round(1e9 / hw.rate_hz)
        """The period now: ``rate_hz``'s, or ``rest_rate_hz``'s while the cycle rests."""
        self.awake_period_ns = self.period_ns
        self.rest_period_ns = round(1e9 / hw.rest_rate_hz) if hw.rests else 0
        self.rest = RestGate(round(hw.rest_after_s * 1e9)) if hw.rests else None
        """When the cycle may rest (None: it never does, ``hwbridge.rest_rate_hz``)."""
        self.rests = 0
        """Rests begun since start (the shared memory's rest word holds the current one's number)."""
        self.deadman_ns = round(hw.deadman_s * 1e9)
        self.max_speed = hw.max_wheel_speed
        self.board = board or make_board(config, self.say)
        self.slew = (SlewLimiter(hw.max_accel), SlewLimiter(hw.max_accel))
        self.stopping = False
        self.kicked = False
        """Set by SIGUSR1: the bus process latched a stop (`stop_now`)."""
        self.kicks = 0
        """Stops sent to the board between two periods."""
        self.link_up = False
        self.mismatch = False
        self._next_retry = 0
        self._link_warned = False
        self._epoch = 0
        self._last_wake = 0
        self._last_dt = 1.0 / hw.rate_hz
        self._parent = os.getppid()
        # Loop statistics (the histogram itself lives in shared memory).
        self.cycles = self.overruns = self.period_sum = self.period_max = self.latency_max = 0
        self.stop_reason = 0
        self.confirmed = 0
        """The latest latched stop (by number) the board has confirmed."""
        self.io_dropped = 0
        self.target_left = self.target_right = 0.0
        self._started = time.monotonic()
        self._pid = os.getpid()
        """This process's id, for the state (read once: `os.getpid` is a system call each time)."""
        self._published = (-1, -1, -1, False)
        """(exchanges, stop_reason, confirmed, link_up) as last written (`_publish_news`)."""
        self._publish_due = 0
        """`cycles` at which the state is written even without news."""

    def say(self, kind: int, text: str) -> None:
        self.shared.push_message(kind, text)

    # ------------------------------------------------------------------ one period

    def step(self, now_ns: int) -> None:
        """Everything a period does after waking up at ``now_ns`` (CLOCK_MONOTONIC)."""
        commands = self.shared.read_commands()
        if commands is None:  # no complete write to be had on any try (`read_commands`): stop for this period
            left = right = 0.0
            fresh_ns, stop, epoch, stop_seq = 0, 1, self._epoch, self.confirmed
        else:
            left, right, fresh_ns, stop, epoch, stop_seq = commands
        if epoch != self._epoch:
            self._epoch = epoch
            self.period_max = self.latency_max = 0
        self.stop_reason = gate(fresh_ns, bool(stop), now_ns, self.deadman_ns)
        stopped = self.stop_reason != 0
        if stopped or not (math.isfinite(left) and math.isfinite(right)):
            stopped = True
            self.slew[0].reset()
            self.slew[1].reset()
            self.target_left = self.target_right = 0.0
        else:
            # The bus side already clamped and logged; this is the last line of defence.
            limit = self.max_speed
            left = limit if left > limit else -limit if left < -limit else left
            right = limit if right > limit else -limit if right < -limit else right
            self.target_left = self.slew[0].step(left, self._last_dt)
            self.target_right = self.slew[1].step(right, self._last_dt)
            # Zero speed is a stop for the board too: zero duty, not "hold zero" on an integrator.
            stopped = self.target_left == 0.0 and self.target_right == 0.0
        self._board_step(now_ns, stopped)
        self._confirm(stop, stop_seq)
        self._forward_io()
        if self.rest is not None:
            self._rest(now_ns, stopped, fresh_ns)
        self._publish_news()

    def _rest(self, now_ns: int, stopped: bool, fresh_ns: int) -> None:
        """Rest, or wake, as the period's evidence says (`control.RestGate`)."""
        b = self.board
        was = self.rest.resting
        if self.rest.update(now_ns, stopped, self.link_up and b.stop_confirmed, fresh_ns,
                            b.ticks_left, b.ticks_right) == was:
            return
        if was:  # a wheel turned by hand, the link or the confirmation lost
            self._set_period(0)
            return
        self.rests += 1
        self._set_period(self.rests)
        # The bus side wakes a resting cycle for each motion command; one written after this
        # period read the commands and before the rest word said so was not woken for: look.
        if self.shared.commands_pending():
            self.kicked = True

    def _set_period(self, rest: int) -> None:
        """Run at the rest period (``rest``: the rest's number) or the awake one (0), and say so."""
        self.period_ns = self.rest_period_ns if rest else self.awake_period_ns
        self.board.rest_period_ns = self.rest_period_ns if rest else 0
        self.shared.set_rest(rest)

    def wake(self, now_ns: int) -> bool:
        """A kick (SIGUSR1) while resting: True if a motion command came, so the next period runs
        now, at the awake rate. A stop needs no period: the wheels are at zero duty, confirmed
        (that is what resting means), so it is confirmed at once, as the next period would."""
        commands = self.shared.read_commands()
        if commands is not None and commands[2] == self.rest.fresh_ns:  # no new motion command
            confirmed = self.confirmed
            self._confirm(commands[3], commands[5])
            if self.confirmed != confirmed:
                self._publish()
            self.rests += 1  # rests on under a new number: the bus side may wake it again
            self.shared.set_rest(self.rests)
            return False
        self.rest.wake()
        self._set_period(0)
        self._last_wake = now_ns - self.period_ns  # the ramp's first step is one period's, not the rest's
        return True

    def _confirm(self, stop: int, stop_seq: int) -> None:
        """Report stop ``stop_seq`` confirmed once the board is verified at rest duty."""
        if stop and self.link_up and self.board.stop_confirmed:
            self.confirmed = max(self.confirmed, stop_seq)

    def stop_now(self, now_ns: int, deadline_ns: int) -> None:
        """Send a freshly latched stop to the board now, between two periods.

        Only a stop takes this path, and only when the wheels were being driven:
        it adds at most one exchange per stop, and a motion command can never
        make the cycle run early. Within an eighth of a period (125 µs at
        1 kHz) of the next deadline the stop waits for it, so that the extra
        exchange does not make the period late.
        """
        if not self.link_up or deadline_ns - now_ns < self.period_ns // KICK_GUARD_FRACTION:
            return  # no board to tell, or the period, due in a moment, tells it
        commands = self.shared.read_commands()
        # no complete write to be had: stop, as `step` does (and confirm no new number)
        stop, stop_seq = (1, self.confirmed) if commands is None else (commands[3], commands[5])
        if not stop or self.stop_reason != STOP_NONE:
            return  # no stop latched, or the wheels are stopped already
        self.stop_reason = STOP_LATCHED
        self.slew[0].reset()
        self.slew[1].reset()
        self.target_left = self.target_right = 0.0
        self.kicks += 1
        # Stop waiting for the board's reply half the guard before the deadline.
        self._board_step(now_ns, True, deadline_ns - self.period_ns // (2 * KICK_GUARD_FRACTION))
        self._confirm(stop, stop_seq)
        self._publish()

    def _forward_io(self) -> None:
        item = self.shared.pop_io()
        if item is not None:
            if self.link_up:
                self.board.io(*item)
            else:
                self.io_dropped += 1

    def _board_step(self, now_ns: int, stopped: bool, until_ns: int = 0) -> None:
        board = self.board
        if not self.link_up:
            if now_ns < self._next_retry:
                return
            self._next_retry = now_ns + RETRY_NS
            try:
                board.open(now_ns)
            except BoardMismatch as exc:
                self.mismatch = True
                self.stopping = True
                self.say(MSG_ERROR, f"refusing to run: {exc}")
                return
            except BoardError as exc:
                if not self._link_warned:
                    self.say(MSG_WARNING, f"board link down: {exc}; retrying every second")
                    self._link_warned = True
                return
            self.link_up = True
            self._link_warned = False
            self.say(MSG_INFO, f"board link up: {board.name}")
        try:
            board.cycle(now_ns, self.target_left, self.target_right, stopped, until_ns)
        except BoardError as exc:
            self.link_up = False
            self._next_retry = now_ns + RETRY_NS
            self.say(MSG_WARNING, f"board link lost: {exc}; retrying every second")
            self._link_warned = True
            board.stop_lost()
            board.close()

    def _publish_news(self) -> None:
        """`_publish` if there is news for the bus side (`PUBLISH_PERIODS`)."""
        exchanges, reason, confirmed, link_up = self._published
        if (self.board.exchanges != exchanges or self.stop_reason != reason or self.confirmed != confirmed
                or self.link_up != link_up or self.cycles >= self._publish_due):
            self._publish()

    def _publish(self) -> None:
        b = self.board
        self._published = (b.exchanges, self.stop_reason, self.confirmed, self.link_up)
        self._publish_due = self.cycles + PUBLISH_PERIODS
        self.shared.write_state((
            b.stamp, b.sample_ns, b.ticks_left, b.ticks_right, b.exchanges, int(self.link_up),
            b.speed_left, b.speed_right, self.target_left, self.target_right,
            b.duty_left, b.duty_right,
            self.cycles, self.overruns, self.period_sum, self.period_max, self.latency_max,
            self._epoch, self.stop_reason, b.crc_errors, b.timeouts, b.unmatched,
            b.garbage_bytes, b.board_errors,
            b.battery_voltage, b.battery_current, self._started,
            b.battery_ns, b.button_presses, b.dip, b.late, b.lost, self.io_dropped, 0,
            self._pid, int(self.mismatch), b.watchdog, self.kicks, self.shared.stalled_reads,
            self.confirmed,
        ))

    # ------------------------------------------------------------------ the loop

    def run(self, timer: AbsoluteTimer) -> None:
        hist = self.shared.hist
        deadline = time.monotonic_ns() + self.period_ns
        self._last_wake = deadline - self.period_ns
        while not self.stopping:
            if self.kicked:  # SIGUSR1 woke us early, or came while we were busy
                self.kicked = False
                now = time.monotonic_ns()
                if self.rest is not None and self.rest.resting:
                    if self.wake(now):
                        deadline = now  # a motion command: its period now, not at the rest's end
                else:
                    self.stop_now(now, deadline)
            timer.sleep_until(deadline)
            woke = time.monotonic_ns()
            if woke < deadline:
                continue  # a signal woke us early: a stop to send, or time to exit
            latency = woke - deadline
            hist[hist_bin(latency)] += 1
            if latency > self.latency_max:
                self.latency_max = latency
            elapsed = woke - self._last_wake
            self._last_wake = woke
            self._last_dt = elapsed * 1e-9
            self.period_sum += elapsed
            if elapsed > self.period_max:
                self.period_max = elapsed
            self.cycles += 1
            self.step(woke)
            if self.cycles % 500 == 0 and os.getppid() != self._parent:
                self.say(MSG_WARNING, "bus process is gone: stopping")
                break
            period = self.period_ns  # the rest's while resting: its longer sleep is no overrun
            deadline += period
            end = time.monotonic_ns()
            if end > deadline:
                missed = (end - deadline) // period + 1
                self.overruns += missed
                deadline += missed * period

    def shutdown(self) -> None:
        """Stop the wheels (EXIT / MULTI_ALL_STOP) and release the link.

        A link lost in the last second (the retry not yet due) is opened once more for it:
        `stop_lost` zeroed the duty, but only EXIT leaves the icoBoard stopped, and the stop
        that `stop_lost` sent may itself not have arrived.
        """
        board = self.board
        if not self.link_up and not self.mismatch:
            with contextlib.suppress(BoardError):
                board.open(time.monotonic_ns())
        board.stop()
        board.close()
        self._publish()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="hwbridge real-time cycle (started by hwbridge)")
    parser.add_argument("--shm", required=True, help="name of the shared-memory block")
    args = parser.parse_args(argv)
    config = msgspec.json.decode(sys.stdin.buffer.read(), type=RobotConfig)
    shared = Shared.attach(args.shm)
    cycle = Cycle(config, shared)

    def on_signal(signum: int, frame: object) -> None:
        cycle.stopping = True

    def on_kick(signum: int, frame: object) -> None:
        cycle.kicked = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGUSR1, on_kick)  # before the first state write: see Bridge.kick
    hw = config.hwbridge
    make_realtime(hw.priority, hw.cpu, cycle.say)
    timer = AbsoluteTimer()
    cycle.say(MSG_INFO, f"cycle at {hw.rate_hz:g} Hz, timer: {timer.kind}, board: {cycle.board.name}")
    gc.collect()
    gc.disable()  # no collector pauses inside the cycle; nothing there makes reference cycles
    gc.freeze()
    try:
        cycle.run(timer)
    finally:
        cycle.shutdown()
        shared.close()
    return EXIT_MISMATCH if cycle.mismatch else 0


if __name__ == "__main__":
    sys.exit(main())

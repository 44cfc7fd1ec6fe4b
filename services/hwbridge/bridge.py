"""hwbridge's bus side: bus messages -> shared-memory commands, shared-memory state -> bus.

`Bridge` owns the command half of the shared memory (`shm.Shared`): wheel
targets, the time the applied motion command was issued (the real-time cycle
applies the deadman against it), the stop latch with its number, and the I/O
ring. It validates and clamps every input, with a log line naming the key and
the value, and decides with `ordering.CommandOrder` whether a motion command
may still drive: not if it was issued before a stop, or is older than the
deadman. It reads the state half to publish ``hw/wheels``, ``hw/loop``,
``hw/battery``, ``io/buttons`` and ``io/dip``, to learn when the board has
confirmed a stop (``stop_confirmed``), and forwards the cycle's messages to
``log``. The lab's ``lab/stop`` may hold the robot stopped (`hold.HoldState`):
then every motion command is refused until the hold is released.

Commands and stops come in on Zenoh's threads (``__main__``), so that nothing
queued in the event loop can reorder them; one lock guards the command state.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import threading
import time
from collections.abc import Awaitable
from pathlib import Path

from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, NotConfirmed
from icefloe.logs import LimitedLog
from icefloe.motion.car import VirtualCar
from icefloe.motion.car import Wheels as CarWheels
from icefloe.motion.diffdrive import limit_wheels, twist_to_wheels
from icefloe.ordering import CommandOrder, Origin
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .control import HIST_BINS, MotionProfile, percentiles
from .hold import HoldState
from .shm import IO_LED, IO_LEDARRAY, IO_SCREEN, IO_TEXT, MSG_BOARD, MSG_ERROR, MSG_WARNING, STATE_FIELDS, Shared

MOTION_STEP_S = 0.02
"""A timed motion re-sends its targets at 50 Hz (which also feeds the deadman)."""
HALTED_SPEED = 0.005
"""``cmd/halt`` answers once both measured speeds are below this, m/s."""
HALT_TIMEOUT_S = 3.0
CONFIRM_TIMEOUT_S = 3.0
"""A stop the board has not confirmed within this long is reported as not confirmed, s (it
normally takes one exchange on the icoBoard, ~25 ms on the PenguinPi: docs/hwbridge.md)."""
CONFIRM_POLL_S = 0.001
"""How often a waiting confirmation looks at the cycle's state, s."""


class Bridge:
    """Commands in, state out, for one robot; ``shared`` is the block the cycle attaches to."""

    def __init__(self, config: RobotConfig, shared: Shared, log: logging.Logger,
                 hold_file: Path | None = None) -> None:
        """``hold_file``: where a hold of the lab's TA is kept across restarts (`HoldState`)."""
        self.config = config
        self.shared = shared
        self.log = log
        self.limited = LimitedLog(log)
        """Lines about bad or clamped input, a few per second per kind."""
        self.max_speed = config.hwbridge.max_wheel_speed
        self.deadman_ns = round(config.hwbridge.deadman_s * 1e9)
        self.order = CommandOrder(self.deadman_ns)
        self.car_model = VirtualCar(config.car, config.geometry.track, self.max_speed, time.monotonic())
        """The virtual car of ``cmd/car`` (lock held to touch it)."""
        self.car_since = -1
        """`changes` when the last ``cmd/car`` drove: the car drives while no change came since."""
        self.left = self.right = 0.0
        self.fresh_ns = 0
        """CLOCK_MONOTONIC ns at which the applied motion command was issued (0 = none yet)."""
        self.stopped = False
        self.stop_seq = 0
        """Stops latched so far; the cycle reports the latest the board has confirmed."""
        self.released = 0
        """`stop_seq` when a motion command last released the latch."""
        self.changes = 0
        """Commands and stops applied so far (a timed motion steps only while it is the latest)."""
        self.dropped = 0
        """Motion commands refused by the ordering rules (`ordering.CommandOrder`)."""
        self.epoch = 0
        self.rt_pid: int | None = None
        """The running real-time process (set by its supervisor), for `kick`."""
        self.woken = 0
        """The number of the cycle's last rest that a motion command woke it from (`wake`)."""
        self._lock = threading.Lock()
        """Commands and stops arrive on Zenoh threads and the event loop: one writer at a time."""
        self._loop = asyncio.get_running_loop()
        self.car_commanded = asyncio.Event()
        """Set when a ``cmd/car`` drives: the car's loop, idle, waits for it (``__main__.car_loop``)."""
        self._motion: asyncio.Future[str] | None = None
        """Set while a timed motion runs; resolved with the reason it was cut short."""
        self._waiting: list[tuple[int, asyncio.Future[dict]]] = []
        """Stop numbers waited for (`confirmed`), and their futures: one task watches them all."""
        self._watcher: asyncio.Task[None] | None = None
        self.hold = HoldState(hold_file)
        """The lab's hold (``lab/stop``): while held, every motion command is refused."""
        self.hold_changes = 0
        """Holds and releases so far (``hw/hold`` is published at each)."""
        if self.hold.held:  # kept by the hwbridge before this one: the robot stays held
            self.stop("held by the lab's TA")
            log.warning("the robot is still held stopped by the lab's TA (since before hwbridge restarted); "
                             "motion commands are refused until it is released")
        self.sync()

    def sync(self) -> None:
        """Write the command fields to shared memory (the cycle reads them every period)."""
        with self._lock:
            self.shared.write_commands(self.left, self.right, self.fresh_ns, self.stopped,
                                       self.epoch, self.stop_seq)

    # ------------------------------------------------------------------ commands

    def command(self, left: float, right: float, source: str, origin: Origin) -> bool:
        """A motion command from the bus (wheel speeds, m/s): drive, if `CommandOrder` allows.

        Clamps (logged), releases the stop latch and feeds the deadman with the time the
        command was issued. Safe to call from any thread. Returns whether it drives.
        """
        left, right, clamped = limit_wheels(left, right, self.max_speed)
        if clamped:
            self.limited.warning(f"clamp:{source}", f"{source}: clamped to {self.max_speed} m/s "
                                 f"per wheel (left {left:.3f}, right {right:.3f})")
        with self._lock:
            issued, why = self._admit(origin)
            if not why:
                self._park_car(origin.arrival_ns)
                self._drive(left, right, issued)
                self.changes += 1
        if why:
            self.limited.warning(f"order:{source}", f"{source}: not applied: {why}")
            return False
        self.sync()
        self.wake()
        self._cut(f"another command on {source}")
        return True

    def _admit(self, origin: Origin) -> tuple[int, str]:
        """Whether a motion command may drive (call with the lock held): `CommandOrder`'s rules, then
        the lab's hold. Returns when it was issued (ns) and why not ('' if it may); a refusal is counted."""
        issued, why = self.order.motion(origin)
        if not why and self.hold.held:
            why = self.hold.refusal()
        if why:
            self.dropped += 1
        return issued, why

    def car(self, msg: m.CarDrive, origin: Origin) -> bool:
        """A ``cmd/car``: drive as the virtual car, if `CommandOrder` allows (the same rules as
        every motion command). Clips the steering to ``car.max_steer`` and slows the car for the
        wheels' limit, each with a line. Safe to call from any thread. Returns whether it drives."""
        source = keys.CAR.name
        with self._lock:
            issued, why = self._admit(origin)
            if not why:
                made = self.car_model.command(msg.v, msg.steer, origin.arrival_ns * 1e-9)
                wheels = self.car_model.wheels
                self._drive(wheels.left, wheels.right, issued)
                self.changes += 1
                self.car_since = self.changes
        if why:
            self.limited.warning(f"order:{source}", f"{source}: not applied: {why}")
            return False
        with contextlib.suppress(RuntimeError):  # the loop is closing
            self._loop.call_soon_threadsafe(self.car_commanded.set)
        if made.clipped:
            self.limited.warning(f"clip:{source}", f"{source}: steer {msg.steer:.4g} rad is beyond car.max_steer "
                                 f"({self.config.car.max_steer:g} rad): clipped to {made.steer_target:.3f} rad")
        if wheels.slowed:
            self._say_slowed(wheels)
        self.sync()
        self.wake()
        self._cut(f"another command on {source}")
        return True

    def _say_slowed(self, wheels: CarWheels) -> None:
        self.limited.warning(f"slow:{keys.CAR.name}", f"{keys.CAR.name}: v {wheels.asked:.4g} m/s at steer "
                             f"{self.car_model.steer:.3f} rad needs a wheel beyond hwbridge.max_wheel_speed "
                             f"({self.max_speed:g} m/s): slowed to {wheels.v:.3f} m/s, the turn kept")

    def car_step(self, now_ns: int) -> m.CarState:
        """One step of the virtual car (the event loop, at ``car.state_rate_hz``): the steering turns
        towards its target and the wheels follow it, while the last ``cmd/car`` still drives (no stop,
        no other command since, its deadman not passed); returns its state for ``car/state``."""
        model = self.car_model
        changed = slowed = False
        with self._lock:
            if model.driving:
                lapsed = self.fresh_ns + self.deadman_ns
                if self.changes != self.car_since or self.stopped:
                    model.hold(now_ns * 1e-9)  # not expected: what ended it parked the car already
                elif now_ns > lapsed:
                    model.hold(lapsed * 1e-9)  # the cycle stopped the wheels at the deadman
                elif model.advance(now_ns * 1e-9):
                    wheels = model.wheels
                    self.left, self.right, slowed = wheels.left, wheels.right, wheels.slowed
                    changed = True
            model.advance(now_ns * 1e-9)
            state = model.state(time.time_ns())
        if slowed:
            self._say_slowed(model.wheels)
        if changed:
            self.sync()
            self.wake()
        return state

    def _park_car(self, now_ns: int) -> None:
        """The car stops driving (lock held): a stop or another kind of command came."""
        if self.car_model.driving:
            self.car_model.hold(now_ns * 1e-9)

    def _drive(self, left: float, right: float, issued_ns: int) -> None:
        """New targets (lock held): release the latch, the deadman counts from ``issued_ns``."""
        if self.stopped:
            self.released = self.stop_seq
        self.left, self.right = left, right
        self.stopped = False
        self.fresh_ns = issued_ns

    def twist(self, msg: m.Twist, origin: Origin) -> bool:
        left, right = twist_to_wheels(msg.v, msg.w, self.config.geometry.track)
        return self.command(left, right, keys.TWIST.name, origin)

    def wheels(self, msg: m.WheelSpeeds, origin: Origin) -> bool:
        return self.command(msg.left, msg.right, keys.WHEELS_CMD.name, origin)

    def stop(self, why: str = "cmd/stop", origin: Origin | None = None) -> int:
        """Latch a stop: the wheels stay stopped until a motion command issued after it.

        Safe to call from any thread: ``cmd/stop`` is latched straight from the
        Zenoh callback, without waiting for a busy event loop. Returns the stop's
        number, which `confirmed` waits for (a stop repeated with the same sender and
        seq keeps its first number).
        """
        origin = origin or Origin(time.monotonic_ns())
        with self._lock:
            _issued, number = self.order.stop(origin, self.stop_seq + 1)
            new = number > self.stop_seq
            if new:
                self._park_car(origin.arrival_ns)
                self.stop_seq = number
                self.left = self.right = 0.0
                self.stopped = True
                self.changes += 1
        if new:
            self.sync()
            self.kick()
            self._cut(why)
        return number

    async def confirmed(self, number: int, timeout: float = CONFIRM_TIMEOUT_S) -> dict:
        """The cycle's state once the board has confirmed stop ``number`` (zero duty, controller
        cleared); `NotConfirmed` if a newer motion released it first, or after ``timeout`` s."""
        waiter: asyncio.Future[dict] = asyncio.get_running_loop().create_future()
        self._waiting.append((number, waiter))
        if self._watcher is None or self._watcher.done():
            self._watcher = asyncio.create_task(self._watch())
        try:
            return await asyncio.wait_for(waiter, timeout)
        except TimeoutError:
            state = self.shared.read_state() or dict.fromkeys(STATE_FIELDS, 0)  # None: mid-write
            age = (time.monotonic_ns() - state["sample_ns"]) * 1e-9 if state["sample_ns"] else -1
            raise NotConfirmed(
                f"the board did not confirm the stop within {timeout:g} s (board link "
                f"{'up' if state['link_up'] else 'down'}, last reading {age:.3f} s ago, "
                f"{state['timeouts']} timeouts so far)") from None

    async def _watch(self) -> None:
        """Answer the waiting `confirmed` calls from the cycle's state, every millisecond."""
        while self._waiting:
            state = self.shared.read_state()
            if state is None:  # the cycle is in the middle of a write: look again next time
                await asyncio.sleep(CONFIRM_POLL_S)
                continue
            waiting, self._waiting = self._waiting, []
            for number, waiter in waiting:
                if waiter.done():  # timed out
                    continue
                if state["stop_confirmed"] >= number:
                    waiter.set_result(state)
                elif self.released >= number:
                    waiter.set_exception(NotConfirmed(
                        "a motion command issued after the stop released it before the board "
                        "confirmed it"))
                else:
                    self._waiting.append((number, waiter))
            await asyncio.sleep(CONFIRM_POLL_S)

    def kick(self) -> None:
        """Wake the cycle (SIGUSR1) so it sends a latched stop now, not at its next period."""
        pid = self.rt_pid
        state = None if pid is None else self.shared.read_state()
        # The cycle writes its pid once its SIGUSR1 handler is in place; before that the
        # signal would kill it, and the next period applies the stop anyway (as it does when
        # the cycle is in the middle of writing its state: None).
        if state is None or state["pid"] != pid:
            return
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGUSR1)

    def wake(self) -> None:
        """After a motion command is written: wake the cycle (SIGUSR1) if it rests, so the command
        drives now, not at the end of the rest's period (20 ms at 50 Hz). Once per rest: the cycle
        either wakes, or (a stop, nothing new) rests on under a new number, so a flood of commands
        costs one signal, and a stop never waits on this (a resting robot is stopped already)."""
        rest = self.shared.rest()  # the cycle's handler is in place before it writes this word
        pid = self.rt_pid
        if not rest or rest == self.woken or pid is None:
            return
        self.woken = rest
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGUSR1)

    def _cut(self, why: str) -> None:
        """End a running timed motion (from any thread)."""
        if threading.current_thread() is threading.main_thread():
            self.cut_motion(why)
        else:
            with contextlib.suppress(RuntimeError):  # the loop is closing
                self._loop.call_soon_threadsafe(self.cut_motion, why)

    def cut_motion(self, why: str) -> None:
        if self._motion is not None and not self._motion.done():
            self._motion.set_result(why)

    async def motion(self, msg: m.Motion, origin: Origin) -> m.MotionDone:
        """Run a timed motion; answer when it has ended and the board confirmed the stop, or
        when it is cut short or refused."""
        try:
            profile = MotionProfile(msg.left, msg.right, msg.duration, msg.accel, time.monotonic())
        except ValueError as exc:
            raise BadPayload(f"{keys.MOTION.name}: {exc}") from None
        with self._lock:
            _issued, why = self._admit(origin)
            if not why:
                self._park_car(origin.arrival_ns)
                self.changes += 1
                since = self.changes
        if why:
            self.limited.warning("order:cmd/motion", f"cmd/motion: not run: {why}")
            return m.MotionDone(stamp=time.time_ns(), completed=False, reason=f"refused: {why}")
        self.cut_motion("another cmd/motion")
        cut: asyncio.Future[str] = asyncio.get_running_loop().create_future()
        self._motion = cut
        while True:
            left, right, done = profile.at(time.monotonic())
            if done:
                break
            self.motion_step(left, right, since)
            # The last step ends at the motion's end, not at the next 50 Hz step: that would
            # drive up to 20 ms longer (1 % of a second's motion more, varying).
            step = min(MOTION_STEP_S, max(0.0, profile.end - time.monotonic()))
            try:
                reason = await asyncio.wait_for(asyncio.shield(cut), step)
            except TimeoutError:
                continue
            return m.MotionDone(stamp=time.time_ns(), completed=False, reason=reason)
        self._motion = None
        if cut.done() or since != self.changes:  # cut at its very end
            reason = cut.result() if cut.done() else "another command"
            return m.MotionDone(stamp=time.time_ns(), completed=False, reason=reason)
        try:
            await self.confirmed(self.stop("cmd/motion ended"))
        except NotConfirmed as exc:
            return m.MotionDone(stamp=time.time_ns(), completed=False,
                                reason=f"ended, but the stop was not confirmed: {exc}")
        return m.MotionDone(stamp=time.time_ns(), completed=True, reason="")

    def motion_step(self, left: float, right: float, since: int) -> None:
        """One step of a timed motion, unless a command or stop came since it began (`changes`):
        a stop latched on a Zenoh thread wins over a step that has not yet learnt of it."""
        left, right, _ = limit_wheels(left, right, self.max_speed)
        with self._lock:
            if self.changes != since or self.hold.held:
                return
            self._drive(left, right, time.monotonic_ns())
        self.sync()
        self.wake()

    async def halt(self, msg: m.Halt, number: int) -> m.Wheels:
        """Answer a ``cmd/halt`` whose stop ``number`` is latched: once the board has confirmed
        it, and with ``msg.rest`` once both measured speeds are ~0 too."""
        state = await self.confirmed(number)
        if not msg.rest:
            return self.wheels_message(state)
        deadline = time.monotonic() + HALT_TIMEOUT_S
        last = dict.fromkeys(STATE_FIELDS, 0)
        while time.monotonic() < deadline:
            state = self.shared.read_state()  # None: the cycle is in the middle of a write
            if state is not None:
                last = state
                fresh = state["sample_ns"] > time.monotonic_ns() - 100_000_000
                if (fresh and abs(state["speed_left"]) < HALTED_SPEED
                        and abs(state["speed_right"]) < HALTED_SPEED):
                    return self.wheels_message(state)
            await asyncio.sleep(0.01)
        self.limited.warning("cmd/halt", "cmd/halt: wheels not measured at rest within %.0f s", HALT_TIMEOUT_S)
        return self.wheels_message(last)

    # ------------------------------------------------------------------ the lab's hold

    def lab_stop(self, msg: m.LabStop, origin: Origin) -> Awaitable[m.LabStopDone]:
        """``lab/stop`` (the lab's TA): latch a stop now, hold or release; the answer waits for
        the board's confirmation of that stop, at most ``msg.timeout``.

        Safe to call from any thread (the queryable's Zenoh callback): a hold is in place before
        its stop is latched, so no motion command gets between them; a release latches a stop
        too, so no motion command issued before the release drives after it.
        """
        now = time.time_ns()
        if msg.action == "hold":
            with self._lock:
                new = self.hold.hold(now, msg.reason, msg.owner_may_release)
                self.hold_changes += 1
            number = self.stop(keys.LAB_STOP.name, origin)
            said = f" ({msg.reason})" if msg.reason else ""
            who = "the TA or the robot's owner (cmd/release)" if msg.owner_may_release else "the lab's TA"
            self.limited.warning("hold", "%s by the lab's TA%s: motion commands are refused until %s releases it",
                                 "held stopped" if new else "hold renewed", said, who)
        elif msg.action == "release":
            if not self.hold.held:  # nothing to release: nothing changes (a robot under way drives on)
                return self._not_held()
            number = self.stop(keys.LAB_STOP.name, origin)  # first: nothing issued before the release drives
            self._release("the lab's TA", now)
        else:
            number = self.stop(keys.LAB_STOP.name, origin)
        self._keep_failed()
        return self._lab_answer(number, msg.timeout)

    async def _not_held(self) -> m.LabStopDone:
        return m.LabStopDone(stamp=time.time_ns(), confirmed=True, held=False, detail="was not held")

    async def _lab_answer(self, number: int, timeout: float) -> m.LabStopDone:
        try:
            await self.confirmed(number, timeout)
        except NotConfirmed as exc:
            return m.LabStopDone(stamp=time.time_ns(), confirmed=False, held=self.hold.held, detail=str(exc))
        return m.LabStopDone(stamp=time.time_ns(), confirmed=True, held=self.hold.held)

    def release(self, msg: m.Release, origin: Origin) -> Awaitable[m.Hold]:
        """``cmd/release`` (the robot's owner): end the TA's hold, if the TA allowed it; else an
        error reply naming who may. Not held: answers so. Safe to call from any thread."""
        async def answer(refused: str) -> m.Hold:
            if refused:  # an error reply, and one rate-limited line (the queryable's)
                raise NotConfirmed(f"refused: {refused}")
            return self.hold.message(time.time_ns())

        with self._lock:
            held, refusal = self.hold.held, self.hold.refusal()
            allowed = self.hold.owner_may_release()
        if held and not allowed:
            return answer(refusal)
        if held:
            self.stop(keys.RELEASE.name, origin)  # first: nothing issued before the release drives
            if not self._release("its owner", time.time_ns(), owner=True):
                return answer(self.hold.refusal())  # the TA held it again meanwhile, for the TA alone
            self._keep_failed()
        return answer("")

    def _release(self, by: str, now: int, *, owner: bool = False) -> bool:
        """End the hold (``owner``: only if its owner may); False if that was refused."""
        with self._lock:
            if owner and self.hold.held and not self.hold.owner_may_release():
                return False
            was = self.hold.release(now)
            self.hold_changes += 1
        if was:
            self.limited.warning("release", "released by %s: motion commands issued from now on drive again", by)
        return True

    def _keep_failed(self) -> None:
        """Say once per kind when the hold could not be written to its file (`HoldState`)."""
        if self.hold.error:
            self.limited.error("hold file", "the hold could not be kept in %s (%s): a restarted hwbridge "
                               "would not be held", self.hold.path, self.hold.error)

    # ------------------------------------------------------------------ board I/O

    def _push(self, source: str, kind: int, a: int = 0, b: int = 0, data: bytes = b"") -> None:
        if not self.shared.push_io(kind, a, b, data):
            self.limited.warning(f"{source} full", "%s: board command queue full, dropped", source)

    def led(self, msg: m.Led) -> None:
        if not 1 <= msg.led <= 4:
            self.limited.warning("io/leds", "io/leds: led must be 1..4, got %d; ignored", msg.led)
            return
        ms = round(msg.pulse * 1000)
        if ms > 255:
            self.limited.warning("io/leds pulse", "io/leds: pulse %.3f s is longer than the board's "
                                 "0.255 s; clamped", msg.pulse)
            ms = 255
        # b: ms to pulse (> 0), 0 = on, -1 = off
        self._push("io/leds", IO_LED, msg.led, ms if msg.pulse > 0 else (0 if msg.on else -1))

    def ledarray(self, msg: m.LedArray) -> None:
        if not 0 <= msg.mask <= 0xFFFF:
            self.limited.warning("io/ledarray", "io/ledarray: mask must be 0..65535, got %d; ignored",
                                 msg.mask)
            return
        self._push("io/ledarray", IO_LEDARRAY, msg.mask)

    def screen(self, msg: m.OledScreen) -> None:
        if not 0 <= msg.index <= 255:
            self.limited.warning("io/screen", "io/screen: index must be 0..255, got %d; ignored", msg.index)
            return
        self._push("io/screen", IO_SCREEN, msg.index)

    def text(self, msg: m.OledText) -> None:
        data = msg.text.encode("ascii", "replace")
        for i in range(0, len(data), 64):
            self._push("io/text", IO_TEXT, data=data[i:i + 64])

    # ------------------------------------------------------------------ state -> bus

    def wheels_message(self, s: dict) -> m.Wheels:
        return m.Wheels(stamp=s["stamp"], ticks_left=s["ticks_left"], ticks_right=s["ticks_right"],
                        speed_left=s["speed_left"], speed_right=s["speed_right"],
                        target_left=s["target_left"], target_right=s["target_right"])

    def forward_messages(self) -> None:
        """The cycle's lines (board text, link state, warnings) onto ``log``."""
        lines, lost = self.shared.pop_messages()
        if lost:
            self.log.warning("%d lines from the real-time cycle were lost (too many at once)", lost)
        for kind, text in lines:
            if kind == MSG_BOARD:
                self.log.info("board says: %s", text)
            elif kind == MSG_WARNING:
                self.log.warning("%s", text)
            elif kind == MSG_ERROR:
                self.log.error("%s", text)
            else:
                self.log.info("%s", text)


def realtime_of(pid: int) -> tuple[int, bool]:
    """The ``SCHED_FIFO`` priority (0: not real time) and memory lock of process ``pid``, as the
    kernel has them: what the cycle was granted, whatever it asked for (`rt.make_realtime`)."""
    if pid <= 0:
        return 0, False
    try:
        fifo = os.sched_getscheduler(pid) == os.SCHED_FIFO
        priority = os.sched_getparam(pid).sched_priority if fifo else 0
        with open(f"/proc/{pid}/status") as status:  # VmLck: memory locked by mlockall, kB
            locked = any(line.startswith("VmLck:") and int(line.split()[1]) > 0 for line in status)
    except (OSError, ValueError, IndexError):  # the cycle just exited: nothing to report
        return 0, False
    return priority, locked


class LoopReport:
    """Turns two state snapshots (and the histogram) into one `LoopStats` per interval."""

    def __init__(self, board: str) -> None:
        self.board = board
        self._prev: dict | None = None
        self._prev_t = 0.0
        self._hist = [0] * HIST_BINS

    def make(self, state: dict, hist, now: float, stalled_reads: int = 0,
             dropped: int = 0) -> m.LoopStats | None:
        """``stalled_reads``: the bus process's own count (`Shared.stalled_reads`); the cycle's is in
        ``state``. ``dropped``: motion commands the bus side refused so far (`Bridge.dropped`)."""
        counts = list(hist)
        prev, self._prev = self._prev, state
        delta = [c - p for c, p in zip(counts, self._hist, strict=True)]
        self._hist = counts
        elapsed, self._prev_t = now - self._prev_t, now
        if prev is None or elapsed <= 0:
            return None
        cycles = state["cycles"] - prev["cycles"]
        p50, p99, p999 = percentiles(delta, (0.5, 0.99, 0.999))
        errors = sum(state[k] for k in ("crc_errors", "timeouts", "unmatched", "lost", "late"))
        priority, locked = realtime_of(state["pid"])
        return m.LoopStats(
            stamp=time.time_ns(),
            rate=cycles / elapsed,
            period_mean=(state["period_sum_ns"] - prev["period_sum_ns"]) / cycles * 1e-9
            if cycles else 0.0,
            period_max=state["period_max_ns"] * 1e-9,
            latency_p50=p50, latency_p99=p99, latency_p999=p999,
            latency_max=state["latency_max_ns"] * 1e-9,
            overruns=state["overruns"], cycles=state["cycles"], board=self.board,
            link_errors=errors + state["garbage_bytes"],
            link_rate=(state["exchanges"] - prev["exchanges"]) / elapsed,
            crc_errors=state["crc_errors"], timeouts=state["timeouts"],
            unmatched=state["unmatched"], garbage_bytes=state["garbage_bytes"],
            board_errors=state["board_errors"], stalled_reads=state["stalled_reads"] + stalled_reads,
            late=state["late"], commands_dropped=dropped,
            realtime_priority=priority, memory_locked=locked,
        )

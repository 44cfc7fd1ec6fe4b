"""hwbridge: the robot's wheels and board I/O on the bus, driven by a hard real-time cycle.

This is the bus process. It

* takes ``cmd/twist``, ``cmd/wheels``, ``cmd/car``, ``cmd/stop`` and the ``cmd/motion``,
  ``cmd/halt``, ``lab/stop`` and ``cmd/release`` queries on the Zenoh thread that
  delivers them, in the order they arrive, and orders them by what they carry
  (`ordering`, `bridge.Bridge`); ``lab/stop`` may hold the robot stopped (`hold`);
  collects ``io/leds``, ``io/ledarray``, ``io/text``, ``io/screen`` every 20 ms;
* starts the real-time process (`rt.py`: the cycle, no Zenoh in it) and hands
  it the commands through shared memory; if that process dies, tells the board
  to stop and exits, so that its supervisor (``icefloe up``, systemd) starts
  both afresh;
* publishes ``hw/wheels`` (``hwbridge.wheels_rate_hz``), ``hw/loop`` (1 Hz),
  ``hw/battery``, ``io/buttons`` and ``io/dip`` from the state the cycle writes, and
  ``hw/hold`` at each change and once a second;
* steps the virtual car of ``cmd/car`` (its steering turns at its rate) and publishes
  ``car/state`` (`car_loop`).

Safety lives in the cycle (deadman, stop latch, limits, EXIT/ALL_STOP on
exit), so it holds even when this process is slow or gone.

Run: ``python -m icefloe.services.hwbridge --config sim``.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
import time
from collections.abc import Awaitable, Callable
from typing import Any

import msgspec
import zenoh

from icefloe.config import RobotConfig
from icefloe.errors import EXIT_CONFIG, BadPayload, BoardError, NotConfirmed
from icefloe.ordering import Origin
from icefloe.runtime import MSGPACK, Node, decode_query, run
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

from .board import make_board
from .bridge import Bridge, LoopReport
from .rt import EXIT_MISMATCH
from .shm import IO_SLOTS, Shared, block_name

EXIT_RT_GONE = 4
"""Exit status when the real-time process died: the supervisor restarts hwbridge, which starts a
new cycle on a fresh shared-memory block (the old one may hold a write the dead cycle never finished)."""
HOLD_FILE = "hold.json"
"""The lab's hold, kept in the robot's private run folder across restarts (`hold.HoldState`)."""
STILL_WHEELS_S = 0.1
"""``hw/wheels`` of a still robot (a sample that repeats the last one published: the same counts,
speeds and targets) goes out once per this long, s, not at ``wheels_rate_hz``: odometry reports a
gap after 0.25 s without a sample (``odometry.gap_s``) and the web API waits for a fresh one, and
neither learns anything from a repeat. Every sample that changes goes out as it comes."""
READ_BACKOFF_S = (0.001, 0.1)
"""First and longest wait before reading the cycle's state again after a read was put off
(`Shared.read_state` gave None: the cycle was descheduled in the middle of a write)."""


async def supervise(config: RobotConfig, bridge: Bridge, node: Node) -> int:
    """Run the real-time process until it exits (returns hwbridge's exit status); stop it when we
    are cancelled.

    If it exits by itself, the board refused to run (`EXIT_MISMATCH`: returns `EXIT_CONFIG`), or the cycle is gone
    (killed, crashed): then nothing drives the board, so tell it to stop and return `EXIT_RT_GONE`.
    """
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "icefloe.services.hwbridge.rt", "--shm", bridge.shared.name,
        stdin=asyncio.subprocess.PIPE)
    assert proc.stdin is not None
    proc.stdin.write(msgspec.json.encode(config))
    proc.stdin.close()
    bridge.rt_pid = proc.pid
    try:
        code = await proc.wait()
    except asyncio.CancelledError:
        bridge.rt_pid = None
        await _terminate(proc)
        raise
    bridge.rt_pid = None
    bridge.forward_messages()  # its last words (e.g. why it refused the board)
    if code == EXIT_MISMATCH:
        node.log.error("the board does not match the config; hwbridge stops (see above)")
        return EXIT_CONFIG  # restarting cannot help: icefloe up stops the robot
    stopped = await asyncio.to_thread(stop_board, config)
    node.log.error("real-time process exited with status %s; %s; hwbridge exits (status %d) for its "
                   "supervisor to restart it", code, stopped, EXIT_RT_GONE)
    return EXIT_RT_GONE


def stop_board(config: RobotConfig) -> str:
    """Tell the board to stop the wheels, from the bus process (the cycle is gone); says how it went.

    The same calls the cycle makes on its way out: open the link (PenguinPi: MULTI_ALL_STOP;
    icoBoard: START, RESET), then `Board.stop` (MULTI_ALL_STOP; EXIT). The link is free: the
    kernel closed the dead process's serial port or socket.
    """
    board = make_board(config, lambda _kind, _text: None)
    try:
        board.open(time.monotonic_ns())
    except (BoardError, OSError) as exc:
        return f"could not tell the board to stop ({exc})"
    board.stop()
    board.close()
    return "the board was told to stop"


async def _terminate(proc: asyncio.subprocess.Process) -> None:
    """SIGTERM (the cycle stops the wheels and exits), SIGKILL if it does not within 2 s."""
    if proc.returncode is not None:
        return
    proc.terminate()
    try:
        await asyncio.wait_for(asyncio.shield(proc.wait()), 2.0)
    except TimeoutError:
        proc.kill()
        await proc.wait()


async def publish(config: RobotConfig, bridge: Bridge, node: Node) -> None:
    """State -> bus: hw/wheels at its rate, hw/loop at 1 Hz, battery on each reading, buttons on
    presses, DIP and the lab's hold on change and once a second."""
    hw = config.hwbridge
    wheels_pub = node.publisher(keys.WHEELS)
    loop_pub = node.publisher(keys.LOOP)
    battery_pub = node.publisher(keys.HW_BATTERY)
    buttons_pub = node.publisher(keys.BUTTONS)
    dip_pub = node.publisher(keys.DIP)
    hold_pub = node.publisher(keys.HOLD)
    shared = bridge.shared
    interval = 1.0 / (hw.wheels_rate_hz or hw.rate_hz)
    # While the cycle rests its state changes at most at the rest rate: no use looking more often.
    resting_interval = max(interval, 1.0 / hw.rest_rate_hz) if hw.rests else interval
    last_wheels: tuple[float, ...] = ()
    next_still = 0.0
    report = LoopReport(_board_name(config))
    last_sample = last_battery = last_presses = 0
    last_dip = last_hold = -1
    next_loop = next_hold = time.monotonic()
    backoff = READ_BACKOFF_S[0]
    while True:
        s = shared.read_state()
        if s is None:  # the cycle was descheduled mid-write (a starved machine): let it finish
            await asyncio.sleep(backoff)
            backoff = min(2 * backoff, READ_BACKOFF_S[1])
            continue
        backoff = READ_BACKOFF_S[0]
        if bridge.hold_changes != last_hold or time.monotonic() >= next_hold:  # on change, and each second
            last_hold, next_hold = bridge.hold_changes, time.monotonic() + 1.0
            hold_pub.put(bridge.hold.message(time.time_ns()))
        if not s["rt_started"]:  # the cycle has not written anything yet
            await asyncio.sleep(interval)
            continue
        now = time.monotonic()
        if s["sample_ns"] != last_sample and s["stamp"]:
            last_sample = s["sample_ns"]
            shown = (s["ticks_left"], s["ticks_right"], s["speed_left"], s["speed_right"],
                     s["target_left"], s["target_right"])
            if shown != last_wheels or now >= next_still:  # a repeat: once per STILL_WHEELS_S
                last_wheels, next_still = shown, now + STILL_WHEELS_S
                wheels_pub.put(bridge.wheels_message(s))
        if s["battery_ns"] != last_battery:
            last_battery = s["battery_ns"]
            battery_pub.put(m.BatteryReading(stamp=time.time_ns(), voltage=s["battery_voltage"],
                                             current=s["battery_current"]))
        if s["button_presses"] > last_presses:
            buttons_pub.put(m.Buttons(stamp=time.time_ns(), button=3,
                                      presses=s["button_presses"] - last_presses))
        last_presses = s["button_presses"]
        if s["dip"] >= 0 and (s["dip"] != last_dip or now >= next_loop):  # on change, and each second
            dip_pub.put(m.Dip(stamp=time.time_ns(), value=s["dip"]))  # for subscribers that came later
        last_dip = s["dip"]
        bridge.forward_messages()
        if now >= next_loop:
            next_loop += 1.0
            stats = report.make(s, shared.hist, now, shared.stalled_reads, bridge.dropped)
            bridge.epoch += 1  # the cycle restarts its maxima for the next interval
            bridge.sync()
            if stats is not None:
                loop_pub.put(stats)
        await asyncio.sleep(resting_interval if shared.rest() else interval)


def _board_name(config: RobotConfig) -> str:
    b = config.board
    return f"icoboard-v{b.protocol}" if b.kind == "icoboard" else "penguinpi"


GIL_SWITCH_S = 0.0005
"""Python hands the GIL to a waiting thread after this long (default 5 ms), so a ``cmd/stop``
arriving on a Zenoh thread does not wait behind the event loop for milliseconds."""


async def main(config: RobotConfig) -> int:
    """Returns the exit status: 0 when stopped by a signal, `EXIT_CONFIG` (78) when the board
    does not match the config, `EXIT_RT_GONE` (4) when the real-time process died. (The config's
    values were checked when it was read.)"""
    sys.setswitchinterval(GIL_SWITCH_S)
    async with Node("hwbridge", config) as node:
        shared = Shared.create(block_name(config.name))
        bridge = Bridge(config, shared, node.log, config.runtime_dir / HOLD_FILE)
        inputs = command_inputs(node, bridge)
        try:
            async with asyncio.TaskGroup() as tasks:
                # When the supervisor returns (the board refused, the cycle died), everything else stops too.
                cycle = tasks.create_task(supervise(config, bridge, node))
                others = [tasks.create_task(publish(config, bridge, node)),
                          tasks.create_task(forward_io(node, bridge)),
                          tasks.create_task(car_loop(config, bridge, node))]
                node.log.info("hwbridge up: %s, cycle at %g Hz", _board_name(config),
                              config.hwbridge.rate_hz)

                def stop_the_rest(_cycle: asyncio.Task[None]) -> None:
                    for task in others:
                        task.cancel()

                cycle.add_done_callback(stop_the_rest)
        finally:
            # The supervisor has stopped the cycle (wheels told to stop) before we get here.
            for item in inputs:  # first: their callbacks write to the shared memory
                with contextlib.suppress(Exception):
                    item.undeclare()
            shared.close()
        return cycle.result()


def command_inputs(node: Node, bridge: Bridge) -> list[Any]:
    """``cmd/twist``, ``cmd/wheels``, ``cmd/car``, ``cmd/stop``, ``cmd/motion``, ``cmd/halt``,
    ``lab/stop`` and ``cmd/release``, each taken on the Zenoh thread that delivers it, stamped
    with its arrival time at once.

    The other inputs go through the event loop, which a flood of messages can keep
    busy for tens of milliseconds: a stop must not wait in that queue, and a motion
    command that arrived before a stop must not be handled after it. (The timed
    motion and the wait for a confirmation then run in the event loop.)
    """
    loop = asyncio.get_running_loop()
    running: set[asyncio.Task[None]] = set()

    def subscribe(topic: keys.Topic, handle: Callable[[Any, Origin], object]) -> Any:
        key_expr = node.key(topic)

        def on_sample(sample: zenoh.Sample) -> None:
            arrival = time.monotonic_ns()
            if not node.own_key(key_expr, str(sample.key_expr)):
                return  # a wildcard put (icefloe/*/cmd/stop) is no command for this robot
            try:
                msg = codec.decode(sample.payload.to_bytes(), str(sample.encoding), topic.type, key_expr)
            except BadPayload as exc:
                bridge.limited.warning(f"bad:{topic.name}", f"dropped: {exc}")
                return
            handle(msg, origin(msg, arrival, sample.timestamp))

        return node.session.declare_subscriber(key_expr, on_sample)

    def queryable(topic: keys.Topic, start: Callable[[Any, Origin], Awaitable[m.Message]]) -> Any:
        key_expr = node.key(topic)

        async def answer(query: zenoh.Query, pending: Awaitable[m.Message]) -> None:
            try:
                query.reply(key_expr, codec.encode(await pending), encoding=MSGPACK)
            except (BadPayload, NotConfirmed) as exc:
                bridge.limited.warning(f"query:{topic.name}", f"{topic.name}: {exc}")
                query.reply_err(str(exc))
            except Exception as exc:
                node.log.exception("query %s failed", key_expr)
                query.reply_err(f"{key_expr}: {type(exc).__name__}: {exc}")
            finally:
                query.drop()

        def spawn(query: zenoh.Query, pending: Awaitable[m.Message]) -> None:
            task = asyncio.ensure_future(answer(query, pending))
            running.add(task)
            task.add_done_callback(running.discard)

        def on_query(query: zenoh.Query) -> None:
            arrival = time.monotonic_ns()
            if not node.own_key(key_expr, str(query.key_expr)):
                query.drop()  # no answer: a command is taken on its own key only
                return
            try:
                msg = decode_query(query, topic.type, key_expr)
            except BadPayload as exc:
                bridge.limited.warning(f"bad:{topic.name}", f"rejected query: {exc}")
                query.reply_err(str(exc))
                query.drop()
                return
            pending = start(msg, origin(msg, arrival, None))  # a halt latches its stop here
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(spawn, query, pending)

        return node.session.declare_queryable(key_expr, on_query)

    def halt(msg: m.Halt, o: Origin) -> Awaitable[m.Wheels]:
        return bridge.halt(msg, bridge.stop(keys.HALT.name, o))

    return [subscribe(keys.TWIST, bridge.twist), subscribe(keys.WHEELS_CMD, bridge.wheels),
            subscribe(keys.CAR, bridge.car),
            subscribe(keys.STOP, lambda _msg, o: bridge.stop(keys.STOP.name, o)),
            queryable(keys.MOTION, bridge.motion), queryable(keys.HALT, halt),
            queryable(keys.LAB_STOP, bridge.lab_stop), queryable(keys.RELEASE, bridge.release)]


def origin(msg: m.Command, arrival_ns: int, timestamp: zenoh.Timestamp | None) -> Origin:
    """What a command says about who issued it and when, plus the router's Zenoh timestamp."""
    zenoh_id, zenoh_ns = "", 0
    if timestamp is not None:  # the router's clock (HLC: ns since the epoch, NTP64 inside)
        zenoh_id, zenoh_ns = str(timestamp.get_id()), timestamp.get_time_as_ntp64().as_nanos()
    return Origin.of(arrival_ns, msg.sender, msg.seq, msg.stamp, zenoh_id, zenoh_ns)


CAR_IDLE_S = 1.0
"""``car/state`` while the car stands still and does not steer: once a second (for late subscribers)."""


async def car_loop(config: RobotConfig, bridge: Bridge, node: Node) -> None:
    """The virtual car's steps at ``car.state_rate_hz`` (`Bridge.car_step`: its steering turns at its
    rate, the wheels follow), and ``car/state``: each step while it moves or steers, else once a second.
    A car that neither drives nor steers has no steps to take: the loop then waits for a ``cmd/car``
    (`Bridge.car_commanded`), or a second, instead of waking 50 times a second for nothing."""
    pub = node.publisher(keys.CAR_STATE)
    period = 1.0 / config.car.state_rate_hz
    last: tuple[float, ...] = ()
    quiet_until = 0.0
    while True:
        bridge.car_commanded.clear()  # before the step: a cmd/car after it sets it again
        state = bridge.car_step(time.monotonic_ns())
        now = time.monotonic()
        shown = (state.v, state.steer, state.steer_target, state.x, state.y, state.theta, float(state.driving))
        if shown != last or now >= quiet_until:
            pub.put(state)
            last, quiet_until = shown, now + CAR_IDLE_S
        if state.driving or state.steer != state.steer_target:
            await asyncio.sleep(period)
        else:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(bridge.car_commanded.wait(), max(0.0, quiet_until - now))


IO_PERIOD_S = 0.02
"""LED, screen and text commands are collected every 20 ms."""


async def forward_io(node: Node, bridge: Bridge) -> None:
    """LED, LED-array, screen and text commands to the board, collected once per `IO_PERIOD_S`.

    The board takes one such command per cycle (the PenguinPi far fewer), so nothing is gained
    by handling each message as it comes. Zenoh keeps at most what the board could take (for
    the LED array and the screen only the newest message counts), so a script flooding the
    LEDs costs this process no Python per message, and the motion commands and ``cmd/stop``
    keep the GIL to themselves.
    """
    inputs = [(node.batches(keys.LEDS, IO_PERIOD_S, maxsize=IO_SLOTS), bridge.led),
              (node.batches(keys.LEDARRAY, IO_PERIOD_S, maxsize=1), bridge.ledarray),
              (node.batches(keys.BOARD_SCREEN, IO_PERIOD_S, maxsize=1), bridge.screen),
              (node.batches(keys.BOARD_TEXT, IO_PERIOD_S, maxsize=IO_SLOTS), bridge.text)]
    while True:
        await asyncio.sleep(IO_PERIOD_S)
        for batches, handler in inputs:
            for msg in batches.take():
                handler(msg)


if __name__ == "__main__":
    run(main)

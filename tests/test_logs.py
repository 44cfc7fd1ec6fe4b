"""`LimitedLog`: a few lines per second per kind and in all, a count of the rest, short printable lines."""

from __future__ import annotations

import asyncio
import logging
import re
import threading

import pytest

from icefloe.logs import MAX_KINDS, MAX_TEXT, LimitedLog, printable


class Lines(logging.Handler):
    """The records of one test's logger."""

    def __init__(self, name: str) -> None:
        super().__init__()
        self.records: list[logging.LogRecord] = []
        self.log = logging.getLogger(f"test.logs.{name}")
        self.log.addHandler(self)
        self.log.setLevel(logging.DEBUG)
        self.log.propagate = False

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    @property
    def texts(self) -> list[str]:
        return [r.getMessage() for r in self.records]


@pytest.fixture
def lines(request: pytest.FixtureRequest) -> Lines:
    return Lines(request.node.name)


def test_a_flood_is_a_few_lines_per_kind_then_one_count(lines: Lines) -> None:
    now = [100.0]
    limited = LimitedLog(lines.log, burst=3, limit=6, clock=lambda: now[0])
    shown = [limited.warning("cmd/twist", "dropped: bad %d", i) for i in range(10_000)]
    assert shown[:3] == [True] * 3 and not any(shown[3:])
    assert limited.warning("cmd/stop", "dropped: stop") is True  # another kind has its own lines
    assert lines.texts == ["dropped: bad 0", "dropped: bad 1", "dropped: bad 2", "dropped: stop"]
    now[0] += 1.5  # the period is over: the count comes before the next line
    limited.warning("cmd/twist", "dropped: again")
    assert lines.texts[-2:] == ["9997 more lines like these not shown in 1.5 s: 9997 cmd/twist", "dropped: again"]
    assert limited.held == 9997 and limited.written == 6


def test_a_flood_on_many_kinds_is_limited_in_all(lines: Lines) -> None:
    limited = LimitedLog(lines.log, burst=3, limit=6, clock=lambda: 0.0)
    for i in range(1000):
        limited.warning(f"key {i % 10}", "bad %d", i)
    assert len(lines.records) == 6
    limited.flush()
    assert lines.texts[-1].startswith("994 more lines like these not shown in 0.0 s: 100 key 6, 100 key 7")


def test_the_count_comes_when_the_period_ends_without_more_input(lines: Lines) -> None:
    async def flood() -> None:
        limited = LimitedLog(lines.log, burst=2, period=0.2)
        for i in range(50):
            limited.warning("io/leds", "bad %d", i)
        limited.error("io/text", "worse")
        assert len(lines.records) == 3
        await asyncio.sleep(0.5)  # a timer on this loop reports the 48
        assert re.fullmatch(r"48 more lines like these not shown in \d+\.\d s: 48 io/leds", lines.texts[-1])
        assert lines.records[-1].levelno == logging.WARNING  # the level of what was held back

    asyncio.run(flood())


def test_other_threads_are_counted_and_reported_too(lines: Lines) -> None:
    async def flood() -> None:
        limited = LimitedLog(lines.log, burst=5, period=0.3)
        threads = [threading.Thread(target=lambda: [limited.warning("k", "x") for _ in range(1000)])
                   for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        await asyncio.sleep(0.6)
        assert lines.texts[:5] == ["x"] * 5 and len(lines.texts) == 6
        assert re.fullmatch(r"3995 more lines like these not shown in \d+\.\d s: 3995 k", lines.texts[5])

    asyncio.run(flood())


def test_lines_are_short_and_cannot_forge_other_lines(lines: Lines) -> None:
    limited = LimitedLog(lines.log)
    limited.warning("cmd/twist", "unknown field `%s`", "x" * 100_000)
    limited.warning("cmd/wheels", "unknown field `%s`", "a\n2026-01-01 ERROR icefloe.hwbridge: fake\x1b[31m")
    first, second = lines.texts
    assert len(first) == MAX_TEXT and first.endswith("…")
    assert "\n" not in second and "\x1b" not in second and "\\x0a2026" in second
    assert printable("ok") == "ok"


def test_the_kinds_counted_are_bounded(lines: Lines) -> None:
    limited = LimitedLog(lines.log, burst=1, limit=10 * MAX_KINDS, clock=lambda: 0.0)
    for i in range(10 * MAX_KINDS):
        limited.warning(f"kind {i}", "line %d", i)
    assert len(limited._shown) == MAX_KINDS + 1  # the rest are "other"
    assert len(lines.records) == MAX_KINDS + 1
    limited.flush()
    assert lines.texts[-1] == f"{9 * MAX_KINDS - 1} more lines like these not shown in 0.0 s: " \
                              f"{9 * MAX_KINDS - 1} other"


def test_errors_keep_their_traceback_on_the_lines_shown(lines: Lines) -> None:
    limited = LimitedLog(lines.log, burst=1, clock=lambda: 0.0)
    try:
        raise ValueError("boom")
    except ValueError as exc:
        limited.error("query failed", "query %s failed", "odom/reset", exc_info=exc)
        limited.error("query failed", "query %s failed", "odom/reset", exc_info=exc)
    assert len(lines.records) == 1 and lines.records[0].exc_info is not None
    limited.flush()
    assert lines.texts[-1] == "1 more line like these not shown in 0.0 s: 1 query failed"
    assert lines.records[-1].levelno == logging.ERROR


def test_a_callback_that_always_raises_is_a_few_tracebacks_and_a_count(lines: Lines) -> None:
    """`AsyncRobot.callback_failed`: a student's ``on_pose`` that raises at 50 poses a second."""
    from types import SimpleNamespace

    from icefloe.client import AsyncRobot

    robot = AsyncRobot.__new__(AsyncRobot)  # only its node's LimitedLog is used
    robot.node = SimpleNamespace(limited=LimitedLog(lines.log, clock=lambda: 0.0))

    def on_pose(pose: object) -> None:
        raise ZeroDivisionError

    for _ in range(500):
        robot.callback_failed(on_pose, ZeroDivisionError())
    robot.node.limited.flush()
    assert [r.exc_info is not None for r in lines.records[:3]] == [True] * 3  # with their tracebacks
    assert lines.texts[3:] == ["497 more lines like these not shown in 0.0 s: 497 callback "
                               "test_a_callback_that_always_raises_is_a_few_tracebacks_and_a_count.<locals>.on_pose"]

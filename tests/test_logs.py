"""`LimitedLog`: a few lines per second per kind, a count of the rest, short printable lines."""

from __future__ import annotations

import asyncio
import logging
import threading

import pytest

from icefloe.logs import MAX_KINDS, MAX_TEXT, LimitedLog, printable


class Lines(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    @property
    def texts(self) -> list[str]:
        return [r.getMessage() for r in self.records]


@pytest.fixture
def lines(request: pytest.FixtureRequest) -> Lines:
    handler = Lines()
    log = logging.getLogger(f"test.logs.{request.node.name}")
    log.addHandler(handler)
    log.setLevel(logging.DEBUG)
    log.propagate = False
    handler.log = log  # type: ignore[attr-defined]
    return handler


def test_a_flood_becomes_a_few_lines_and_a_count_per_kind(lines: Lines) -> None:
    now = [100.0]
    limited = LimitedLog(lines.log, burst=3, clock=lambda: now[0])  # type: ignore[attr-defined]
    shown = [limited.warning("cmd/twist", "dropped: bad %d", i) for i in range(10_000)]
    assert shown[:3] == [True] * 3 and not any(shown[3:])
    assert limited.warning("cmd/stop", "dropped: stop") is True  # another kind has its own budget
    assert lines.texts == ["dropped: bad 0", "dropped: bad 1", "dropped: bad 2", "dropped: stop"]
    now[0] += 1.5  # the period is over: the count comes before the next line of the kind
    limited.warning("cmd/twist", "dropped: again")
    assert lines.texts[-2:] == ["cmd/twist: 9997 more like it not shown (in 1.5 s)", "dropped: again"]
    assert limited.held == 9997 and limited.written == 6


def test_the_count_comes_when_the_period_ends_without_more_input(lines: Lines) -> None:
    async def flood() -> None:
        limited = LimitedLog(lines.log, burst=2, period=0.2)  # type: ignore[attr-defined]
        for i in range(50):
            limited.warning("io/leds", "bad %d", i)
        assert len(lines.records) == 2
        await asyncio.sleep(0.5)  # a timer on this loop reports the 48
        assert lines.texts[-1].startswith("io/leds: 48 more like it not shown")
        assert lines.records[-1].levelno == logging.WARNING

    asyncio.run(flood())


def test_other_threads_are_counted_and_reported_too(lines: Lines) -> None:
    async def flood() -> None:
        limited = LimitedLog(lines.log, burst=5, period=0.2)  # type: ignore[attr-defined]
        threads = [threading.Thread(target=lambda: [limited.warning("k", "x") for _ in range(1000)])
                   for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        await asyncio.sleep(0.5)
        assert lines.texts == ["x"] * 5 + ["k: 3995 more like it not shown" + lines.texts[-1].split("shown")[1]]

    asyncio.run(flood())


def test_lines_are_short_and_cannot_forge_other_lines(lines: Lines) -> None:
    limited = LimitedLog(lines.log)  # type: ignore[attr-defined]
    limited.warning("cmd/twist", "unknown field `%s`", "x" * 100_000)
    limited.warning("cmd/wheels", "unknown field `%s`", "a\n2026-01-01 ERROR icefloe.hwbridge: fake\x1b[31m")
    first, second = lines.texts
    assert len(first) == MAX_TEXT and first.endswith("…")
    assert "\n" not in second and "\x1b" not in second and "\\x0a2026" in second
    assert printable("ok") == "ok"


def test_the_kinds_kept_are_bounded(lines: Lines) -> None:
    now = [0.0]
    limited = LimitedLog(lines.log, burst=1, clock=lambda: now[0])  # type: ignore[attr-defined]
    for i in range(10 * MAX_KINDS):
        limited.warning(f"kind {i}", "line %d", i)
    assert len(limited._windows) == MAX_KINDS + 1
    assert len(lines.records) == MAX_KINDS + 1  # the rest share the kind "other"
    now[0] = 2.0
    limited.warning("kind 0", "later")  # periods over: old kinds are forgotten, with their counts
    assert lines.texts[-2:] == [f"other: {9 * MAX_KINDS - 1} more like it not shown (in 2.0 s)", "later"]
    assert list(limited._windows) == ["kind 0"]


def test_errors_keep_their_traceback_on_the_lines_shown(lines: Lines) -> None:
    limited = LimitedLog(lines.log, burst=1, clock=lambda: 0.0)  # type: ignore[attr-defined]
    try:
        raise ValueError("boom")
    except ValueError as exc:
        limited.error("query failed", "query %s failed", "odom/reset", exc_info=exc)
        limited.error("query failed", "query %s failed", "odom/reset", exc_info=exc)
    assert len(lines.records) == 1 and lines.records[0].exc_info is not None
    limited.flush()
    assert lines.texts[-1].startswith("query failed: 1 more like it not shown")
    assert lines.records[-1].levelno == logging.ERROR

"""power: battery filter, thresholds, persistence and the button debounce, as pure logic.

Times are injected, so each edge happens exactly when the test says.
"""

from __future__ import annotations

import pytest

from icefloe.services.power.battery import BadReading, BatteryMonitor
from icefloe.services.power.lines import HoldDetector


def test_first_reading_sets_the_filter_then_it_follows_the_pole() -> None:
    monitor = BatteryMonitor(pole=0.9)
    monitor.update(8.0, 0.5)
    assert monitor.voltage == 8.0 and monitor.current == 0.5
    monitor.update(7.0, 1.5)
    assert monitor.voltage == pytest.approx(0.9 * 8.0 + 0.1 * 7.0)
    assert monitor.current == pytest.approx(0.9 * 0.5 + 0.1 * 1.5)


@pytest.mark.parametrize(("volts", "state"), [(7.4, "ok"), (7.0, "ok"), (6.99, "low"),
                                               (6.5, "low"), (6.49, "critical")])
def test_thresholds(volts: float, state: str) -> None:
    assert BatteryMonitor(pole=0.0).update(volts) == state


def test_critical_must_persist_for_critical_readings_in_a_row() -> None:
    monitor = BatteryMonitor(pole=0.0, critical_readings=3)
    for volts in (7.4, 6.0, 6.0, 7.4, 6.0, 6.0):  # never three in a row
        monitor.update(volts)
        assert not monitor.shutdown_due
    monitor.update(6.0)
    assert monitor.shutdown_due


def test_the_filter_absorbs_a_single_deep_spike() -> None:
    monitor = BatteryMonitor(pole=0.9, critical_readings=1)
    monitor.update(7.4)
    assert monitor.update(0.5) == "low"  # 0.9 * 7.4 + 0.1 * 0.5 = 6.71 V
    assert not monitor.shutdown_due


def test_silence_matters_only_while_low() -> None:
    monitor = BatteryMonitor(pole=0.0)
    monitor.update(7.4, t=10.0)
    assert not monitor.silent_while_low(100.0, silent_s=5.0)  # ok: hwbridge may just be down
    monitor.update(6.8, t=20.0)
    assert not monitor.silent_while_low(24.9, silent_s=5.0)
    assert monitor.silent_while_low(25.0, silent_s=5.0)
    monitor.update(7.2, t=25.0)  # recovered (charging)
    assert not monitor.silent_while_low(60.0, silent_s=5.0)


@pytest.mark.parametrize("volts", [-0.1, 30.5])
def test_implausible_reading_is_rejected_and_changes_nothing(volts: float) -> None:
    monitor = BatteryMonitor(pole=0.0)
    monitor.update(7.4)
    with pytest.raises(BadReading, match=r"outside 0\.\.30 V"):
        monitor.update(volts)
    assert monitor.voltage == 7.4


@pytest.mark.parametrize(("kwargs", "text"), [({"pole": 1.0}, "pole"),
                                               ({"critical_readings": 0}, "critical_readings"),
                                               ({"critical_v": 7.5}, "critical_v")])
def test_bad_settings_are_named(kwargs: dict[str, float], text: str) -> None:
    with pytest.raises(ValueError, match=text):
        BatteryMonitor(**kwargs)  # type: ignore[arg-type]


def replay(detector: HoldDetector, edges: list[tuple[float, int]], until: float,
           step: float = 0.001) -> list[float]:
    """Feed (time, level) edges and poll every `step` s; return the times presses fired."""
    fired, pending, t = [], sorted(edges), 0.0
    while t <= until:
        while pending and pending[0][0] <= t:
            detector.edge(pending.pop(0)[1], t)
        if detector.poll(t):
            fired.append(round(t, 3))
        t = round(t + step, 6)
    return fired


def test_bounce_burst_then_hold_is_one_press() -> None:
    button = HoldDetector(hold_s=0.5, debounce_s=0.02)
    burst = [(1.000, 0), (1.003, 1), (1.006, 0), (1.010, 1), (1.014, 0)]
    # Bounce again while held and on release: still the same one press.
    noise = [(1.300, 1), (1.305, 0), (2.000, 1), (2.004, 0), (2.008, 1)]
    assert replay(button, burst + noise, until=3.0) == [1.805]  # 0.5 s after the last bounce
    assert button.presses == 1


def test_a_burst_alone_or_a_short_press_is_no_press() -> None:
    button = HoldDetector(hold_s=0.5, debounce_s=0.02)
    burst = [(1.000, 0), (1.004, 1), (1.008, 0), (1.012, 1)]
    short = [(2.000, 0), (2.300, 1)]
    assert replay(button, burst + short, until=3.0) == []


def test_two_separate_holds_are_two_presses() -> None:
    button = HoldDetector(hold_s=0.5, debounce_s=0.02)
    edges = [(1.0, 0), (1.7, 1), (2.0, 0), (2.6, 1)]
    assert replay(button, edges, until=3.0) == [1.5, 2.5]


def test_settled_changes_are_the_presses_and_releases_without_bounces() -> None:
    button = HoldDetector(hold_s=0.5, debounce_s=0.02)
    edges = [(1.000, 0), (1.003, 1), (1.006, 0), (1.200, 1), (1.204, 0), (1.207, 1), (2.0, 0), (2.01, 1)]
    changes, pending, t = [], sorted(edges), 0.0
    while t <= 3.0:
        while pending and pending[0][0] <= t:
            button.edge(pending.pop(0)[1], t)
        if (level := button.settled_change(t)) is not None:
            changes.append((round(t, 3), level))
        t = round(t + 0.001, 6)
    # A press 20 ms after its last bounce, a release 20 ms after its last; a 10 ms blip is nothing.
    assert changes == [(1.026, 0), (1.227, 1)]


def test_request_line_needs_its_long_hold() -> None:
    request = HoldDetector(hold_s=15.0)
    assert replay(request, [(0.0, 0), (14.0, 1)], until=20.0, step=0.01) == []
    request = HoldDetector(hold_s=15.0)
    assert replay(request, [(1.0, 0)], until=20.0, step=0.01) == [16.0]


def test_a_level_other_than_0_or_1_is_rejected() -> None:
    with pytest.raises(ValueError, match="0 or 1"):
        HoldDetector(hold_s=0.5).edge(2, 0.0)


SCENARIOS = [
    [(1.000, 0), (1.003, 1), (1.006, 0), (1.010, 1), (1.014, 0), (1.300, 1), (1.305, 0), (2.000, 1),
     (2.004, 0), (2.008, 1)],
    [(1.000, 0), (1.004, 1), (1.008, 0), (1.012, 1), (2.000, 0), (2.300, 1)],
    [(1.0, 0), (1.7, 1), (2.0, 0), (2.6, 1)],
    [(1.000, 0), (1.003, 1), (1.006, 0), (1.200, 1), (1.204, 0), (1.207, 1), (2.0, 0), (2.01, 1)],
    [(0.5, 0)],  # held and never released
]


def observe(button: HoldDetector, edges: list[tuple[float, int]], lazy: bool) -> tuple[list, int]:
    """Presses and settled changes seen when polling every 1 ms, or (``lazy``) only while the
    detector is not `idle` (as the service does); and how many polls that took."""
    seen, pending, t, polls = [], sorted(edges), 0.0, 0
    while t <= 3.0:
        while pending and pending[0][0] <= t:
            button.edge(pending.pop(0)[1], t)
        if not (lazy and button.idle):
            polls += 1
            if button.poll(t):
                seen.append(("press", round(t, 3)))
            if (level := button.settled_change(t)) is not None:
                seen.append((level, round(t, 3)))
        t = round(t + 0.001, 6)
    return seen, polls


@pytest.mark.parametrize("edges", SCENARIOS)
def test_polling_only_while_not_idle_sees_the_same_presses(edges: list[tuple[float, int]]) -> None:
    """The power service sleeps while both of its lines are idle (nothing to poll between
    presses): it must see exactly what polling all the time sees."""
    always, every = observe(HoldDetector(hold_s=0.5, debounce_s=0.02), edges, lazy=False)
    lazily, polls = observe(HoldDetector(hold_s=0.5, debounce_s=0.02), edges, lazy=True)
    assert lazily == always
    assert polls < every / 2  # and most of the time it did not poll at all


def test_a_detector_at_rest_is_idle() -> None:
    button = HoldDetector(hold_s=0.5, debounce_s=0.02)
    assert button.idle
    button.edge(0, 1.0)
    assert not button.idle

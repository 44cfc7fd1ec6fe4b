"""The angle helpers (icefloe/angles.py): the range every heading on the bus is in."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icefloe.angles import wrap_angle, wrap_angles

CASES = [
    (0.0, 0.0), (math.pi, math.pi), (-math.pi, math.pi), (3 * math.pi, math.pi),
    (1.5 * math.pi, -0.5 * math.pi), (-1.5 * math.pi, 0.5 * math.pi), (2 * math.pi + 0.1, 0.1),
    (-7.0, -7.0 + 2 * math.pi), (3 * math.pi / 2, -math.pi / 2),
]


@pytest.mark.parametrize(("a", "expected"), CASES)
def test_wrap_angle_is_in_minus_pi_to_pi(a: float, expected: float) -> None:
    assert wrap_angle(a) == pytest.approx(expected, abs=1e-12)
    assert -math.pi < wrap_angle(a) <= math.pi


def test_pi_stays_pi_and_minus_pi_becomes_pi_exactly() -> None:
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi


def test_wrap_angles_wraps_an_array_as_wrap_angle_wraps_each() -> None:
    a = np.array([a for a, _ in CASES] + list(np.linspace(-20.0, 20.0, 101)))
    wrapped = wrap_angles(a)
    assert np.all((wrapped > -math.pi) & (wrapped <= math.pi))
    assert wrapped == pytest.approx([wrap_angle(float(v)) for v in a], abs=1e-12)

"""Angles: the one place they are wrapped.

Every heading on the bus is counter-clockwise positive and wrapped to (-pi, pi] (DESIGN.md,
"Units"); every estimator, the simulator and the scoring wrap with these, so they agree on the
edge: pi stays pi, -pi becomes pi.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np


def wrap_angle(a: float) -> float:
    """``a`` wrapped to (-pi, pi], rad."""
    wrapped = math.remainder(a, math.tau)  # exact, in [-pi, pi]
    return math.pi if wrapped == -math.pi else wrapped


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Each angle of an array wrapped to (-pi, pi], rad (within a rounding of `wrap_angle`'s)."""
    return math.pi - (math.pi - a) % math.tau  # % takes the divisor's sign: the remainder is in [0, 2pi)

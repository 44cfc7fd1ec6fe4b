"""Landmark sightings and maps as SLAM and the map maker take and give them: which sightings a
camera could have made (`plausible`), and a filter's map as a ``LandmarkMap`` message
(`landmark_map`)."""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from ..logs import LimitedLog
from ..schemas import messages as m


class MapFilter(Protocol):
    """A filter that holds a map: `EkfSlam`, `LandmarkMapper`."""

    @property
    def landmarks(self) -> dict[int, tuple[float, float]]: ...

    def covariance(self, landmark_id: int) -> np.ndarray: ...


MAX_RANGE = 20.0
"""Farthest plausible sighting, m: the camera reads a 7 cm marker to 3 m or so."""


def plausible(frame: m.Landmarks, warn: LimitedLog) -> list[m.Landmark]:
    """The frame's sightings a camera could have made (0 < range < MAX_RANGE, |bearing| <= pi); one
    rate-limited line for the others. (The schema has already refused NaN and infinity.)"""
    good = [lm for lm in frame.landmarks if 0.0 < lm.range < MAX_RANGE and abs(lm.bearing) <= math.pi]
    if len(good) < len(frame.landmarks):
        bad = next(lm for lm in frame.landmarks if lm not in good)
        warn.warning("camera/landmarks implausible",
                     f"camera/landmarks: landmark {bad.id} at range {bad.range} m, bearing {bad.bearing} rad "
                     f"is not a sighting (range must be in (0, {MAX_RANGE}) m, bearing in [-pi, pi]): not used")
    return good


def landmark_map(filt: MapFilter, stamp: int) -> m.LandmarkMap:
    """The map of a filter with ``landmarks`` and ``covariance(id)`` (`EkfSlam`, `LandmarkMapper`)."""
    return m.LandmarkMap(stamp=stamp, landmarks=[
        m.MapLandmark(id=i, x=x, y=y, covariance=[float(v) for v in filt.covariance(i).ravel()])
        for i, (x, y) in sorted(filt.landmarks.items())])

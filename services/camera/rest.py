"""When the camera may rest: search fewer frames for markers while its picture does not change.

Detection is the camera's main cost (docs/camera.md, "What the camera costs"), and a robot
standing still sees the same markers frame after frame. So before a frame due for detection is
searched, it is shrunk to a small grey thumbnail (`thumbnail`: 32 x 24 cells, each the mean of
10 x 10 of the pixels of a 640 x 480 frame, every other one of every other row; 0.04 ms against
detection's 1.5 to 3.5 ms) and compared with the thumbnail of the frame
that began the current still spell (`change`). While the picture stays within
``camera.still_threshold`` of it for ``camera.rest_after_s``, the camera rests: it searches
``camera.rest_detection_rate_hz`` frames a second, enough for the localizer and SLAM to keep
seeing the markers. A change beyond the threshold ends the rest at once: that frame is searched,
and a new still spell starts from it.

Why these measures (bench/camera_rest.py measures them on the simulator's frames):

* **Light flicker** changes the whole picture's brightness, by up to ±15 % from frame to frame in the
  simulator's ideal profile: each thumbnail is divided by its own mean brightness first.
* **Sensor noise** is averaged away in a cell of 100 pixels.
* **A marker appearing** (carried in by hand, a door opening) changes a few cells a lot and the
  mean hardly at all: the change is the *largest* cell's, not the mean's.
* **Slow motion** (driving slowly straight at a far wall) changes each frame little from the one
  before: each frame is compared with the spell's first frame, not the previous one, so the
  change adds up until it ends the spell.

No bus and no clock here: `__main__.py` hands in each due frame's thumbnail and the time.
"""

from __future__ import annotations

import cv2
import numpy as np

THUMBNAIL = (32, 24)
"""Thumbnail width and height, cells: a marker 20 px wide in a 640 x 480 frame fills about one cell."""


def thumbnail(image: np.ndarray) -> np.ndarray:
    """``image`` (BGR or grey) as `THUMBNAIL` cells of mean grey, each divided by the whole
    thumbnail's mean (so 1.0 is the picture's mean brightness; a black picture stays 0)."""
    # Every other pixel of every other row, of the green channel only (the one closest to grey):
    # 0.04 ms where the whole frame in colour was 0.4 ms, and each cell still averages 100 pixels.
    sampled = image[::2, ::2, 1] if image.ndim == 3 else image[::2, ::2]
    small = cv2.resize(np.ascontiguousarray(sampled), THUMBNAIL, interpolation=cv2.INTER_AREA)
    cells = small.astype(np.float32)
    mean = float(cells.mean())
    return cells / mean if mean > 0 else cells


def change(a: np.ndarray, b: np.ndarray) -> float:
    """How different two thumbnails are: the largest cell's difference, in the pictures' mean brightness."""
    return float(np.abs(a - b).max())


class DetectionRest:
    """Whether a frame due for detection is searched (`search`), and whether the camera rests.

    ``threshold``: a change (`change`) above this is not still; ``rest_after_s``: still this long,
    s, before resting; ``rest_period_s``: a frame is searched at least this often while resting, s.
    Times are seconds of any monotonic clock (the service's ``time.monotonic()``; a test's own)."""

    def __init__(self, threshold: float, rest_after_s: float, rest_period_s: float) -> None:
        self.threshold, self.rest_after_s, self.rest_period_s = threshold, rest_after_s, rest_period_s
        self._spell: np.ndarray | None = None
        """The thumbnail that began the current still spell (None: no frame seen yet)."""
        self._still_since = 0.0
        self._last_search = 0.0
        self.resting = False
        """The picture has been still for ``rest_after_s``: only ``rest_period_s`` searches."""
        self.rests = 0
        """How many times the camera began to rest."""
        self.wakes = 0
        """How many rests a change ended."""
        self.last_change = 0.0
        """The latest frame's change from the spell's first frame."""

    def search(self, thumb: np.ndarray, now: float) -> bool:
        """True if the frame whose thumbnail is ``thumb``, due for detection at ``now``, is to be searched."""
        if self._spell is None or (moved := change(thumb, self._spell)) > self.threshold:
            if self.resting:
                self.wakes += 1
            self.last_change = 0.0 if self._spell is None else moved
            self._spell, self._still_since, self.resting = thumb, now, False
            return self._searched(now)
        self.last_change = moved
        if not self.resting and now - self._still_since >= self.rest_after_s:
            self.resting = True
            self.rests += 1
        if not self.resting or now - self._last_search >= self.rest_period_s - 1e-6:  # float sums of frame times
            return self._searched(now)
        return False

    def _searched(self, now: float) -> bool:
        self._last_search = now
        return True

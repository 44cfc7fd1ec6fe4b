"""ArUco dictionaries by name, as the configs give them (``camera.dictionary``, ``overhead.dictionary``)."""

from __future__ import annotations

import cv2

from ..errors import ConfigError


def aruco_dictionary(name: str) -> int:
    """OpenCV's id of a predefined ArUco dictionary (``camera.dictionary``, e.g. "DICT_4X4_50")."""
    value = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(value, int):
        raise ConfigError(f"camera.dictionary: {name!r} is not an OpenCV ArUco dictionary (e.g. DICT_4X4_50)")
    return value

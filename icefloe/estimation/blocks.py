"""Marker blocks: one ArUco id on several faces of a cube, used as ONE landmark at the cube's centre.

The camera reports each face it sees as a landmark with the block's id, at the face's centre
(so one frame may hold the id twice: two faces seen at once). The world map knows the block
only by its centre (`icefloe.worldmap.WorldMap.landmarks`), so each such sighting is moved
from the face to the centre before the filter sees it:

* with the marker's pose in the camera frame (``position`` and ``rotation``, as the camera
  service sends them): half the cube's edge straight back from the face, along the face's
  normal (the marker's z axis, which points out of the face towards the camera);
* without it (another detector): half the edge further along the line of sight, which is
  the same when the face is seen head-on and off by up to (edge/2)·sin(angle) sideways.

All sightings of one block in a frame are then averaged (in the robot's frame) into one, so
the filter takes one measurement per block and frame, not one per face.
"""

from __future__ import annotations

import math

import numpy as np

from ..schemas import messages as m
from ..vision.geometry import Mount, range_bearing


def face_normal(rotation: list[float]) -> np.ndarray:
    """The marker's z axis in the camera frame, from its Rodrigues vector (rad)."""
    r = np.asarray(rotation, dtype=float)
    angle = float(np.linalg.norm(r))
    z = np.array([0.0, 0.0, 1.0])
    if angle < 1e-12:
        return z
    k = r / angle
    return z * math.cos(angle) + np.cross(k, z) * math.sin(angle) + k * (k @ z) * (1.0 - math.cos(angle))


def centre_of(sighting: m.Landmark, half_side: float, mount: Mount) -> tuple[float, float]:
    """The block's centre in the robot frame (x, y, m) from one face's sighting."""
    if len(sighting.position) == 3 and len(sighting.rotation) == 3:
        centre = np.asarray(sighting.position, dtype=float) - half_side * face_normal(sighting.rotation)
        p = mount.to_robot(centre)
        return float(p[0]), float(p[1])
    rng = sighting.range + half_side
    return rng * math.cos(sighting.bearing), rng * math.sin(sighting.bearing)


def to_centres(landmarks: list[m.Landmark], half_sides: dict[int, float], mount: Mount) -> list[m.Landmark]:
    """``landmarks`` with each block's faces replaced by one sighting of the block's centre
    (range and bearing only), in the place of its first face; other landmarks as they are."""
    if not any(lm.id in half_sides for lm in landmarks):
        return landmarks
    centres: dict[int, list[tuple[float, float]]] = {}
    out: list[m.Landmark | int] = []
    for lm in landmarks:
        if lm.id not in half_sides:
            out.append(lm)
            continue
        if lm.id not in centres:
            centres[lm.id] = []
            out.append(lm.id)
        centres[lm.id].append(centre_of(lm, half_sides[lm.id], mount))
    result = []
    for item in out:
        if isinstance(item, int):
            points = centres[item]
            x = sum(p[0] for p in points) / len(points)
            y = sum(p[1] for p in points) / len(points)
            rng, bearing = range_bearing(np.array([x, y, 0.0]))
            result.append(m.Landmark(id=item, range=rng, bearing=bearing))
        else:
            result.append(item)
    return result

"""The maths of scoring: aligning two point sets, map error, trajectory error. numpy only, no bus.

Alignment (Umeyama 1991, "Least-squares estimation of transformation parameters between two
point patterns"): the rotation R, translation t and, for a similarity, scale c that minimise
sum |dst_i - (c R src_i + t)|^2 over matched points. With cov = (1/n) sum (dst_i - mu_dst)(src_i - mu_src)^T
and its SVD U D V^T, R = U S V^T, where S = diag(1, -1) if det(U) det(V) < 0 (a reflection would
fit better: we take the best rotation instead) and I otherwise; c = trace(D S) / var(src);
t = mu_dst - c R mu_src. Rigid alignment is the same with c = 1 (this is what the ECE4078
course's SLAM_eval.py does, under the name Umeyama).

Trajectory error (Sturm et al. 2012, the TUM RGB-D benchmark; Geiger et al. 2012, KITTI):

* absolute trajectory error (ATE): align the estimated positions to the true ones, then the
  distance between each aligned estimate and its true position (RMSE, mean, max);
* relative pose error per metre (RPE): for every pose i and the first pose j at least `segment`
  metres further along the true path, the error of the estimated motion from i to j against the
  true one, inv(true_ij) * est_ij: its translation as a percentage of the distance travelled, its
  rotation in degrees per metre. No alignment is needed (a motion from i to j is the same in any
  frame), and none is done: a scale error shows here as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..angles import wrap_angles

ALIGNMENTS = ("rigid", "similarity", "none")
MIN_POINTS = {"rigid": 2, "similarity": 3, "none": 1}
"""Matched points an alignment needs to leave something to score: one point fixes a rigid
alignment's translation but not its rotation; two points fit a similarity exactly."""


class NotEnough(ValueError):
    """Too few matched points or poses to align or to score."""


# --------------------------------------------------------------------------- alignment


@dataclass(frozen=True)
class Alignment:
    """p' = scale * R(rotation) p + translation."""

    rotation: float = 0.0
    """rad, counter-clockwise."""
    translation: tuple[float, float] = (0.0, 0.0)
    """m."""
    scale: float = 1.0
    kind: str = "none"

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Points (N x 2) moved by this alignment."""
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        r = np.array([[c, -s], [s, c]])
        return self.scale * np.asarray(points, float) @ r.T + np.array(self.translation)


def align(src: np.ndarray, dst: np.ndarray, kind: str = "rigid") -> Alignment:
    """The alignment (`ALIGNMENTS`) that best moves ``src`` onto ``dst`` (both N x 2, matched by row)."""
    if kind not in ALIGNMENTS:
        raise ValueError(f"alignment must be one of {', '.join(ALIGNMENTS)}, not {kind!r}")
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    n = len(src)
    if n < MIN_POINTS[kind]:
        raise NotEnough(f"{kind} alignment needs at least {MIN_POINTS[kind]} matched points, got {n}")
    if kind == "none":
        return Alignment()
    mu_src, mu_dst = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_src, dst - mu_dst
    var_src = (a**2).sum() / n
    if var_src < 1e-18:
        raise NotEnough(f"the {n} points to align are all at one place: no rotation can be found")
    cov = b.T @ a / n
    u, d, vt = np.linalg.svd(cov)
    s = np.eye(2)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[1, 1] = -1.0
    r = u @ s @ vt
    scale = float(np.trace(np.diag(d) @ s) / var_src) if kind == "similarity" else 1.0
    t = mu_dst - scale * r @ mu_src
    return Alignment(math.atan2(r[1, 0], r[0, 0]), (float(t[0]), float(t[1])), scale, kind)


def rmse(errors: np.ndarray) -> float:
    """Root mean square of distances (the ECE4078 RMSE: sqrt of the mean squared distance)."""
    return float(np.sqrt(np.mean(np.asarray(errors, float) ** 2))) if len(errors) else 0.0


# --------------------------------------------------------------------------- maps


@dataclass(frozen=True)
class MapScore:
    """A landmark map against the true one."""

    alignment: Alignment
    rmse: float
    """After alignment, m: sqrt(mean squared distance) over the markers in both."""
    rmse_raw: float
    """Before alignment, m."""
    errors: dict[int, float]
    """Distance from each matched marker (aligned) to its true place, m, by id."""
    aligned: dict[int, tuple[float, float]]
    """Each matched marker's position after alignment, m."""
    missed: list[int]
    """In the world, not in the map."""
    spurious: list[int]
    """In the map, not in the world."""


def score_map(estimate: dict[int, tuple[float, float]], truth: dict[int, tuple[float, float]],
              kind: str = "rigid") -> MapScore:
    """Align the estimated landmarks to the true ones (matched by id) and measure what is left."""
    ids = sorted(set(estimate) & set(truth))
    est = np.array([estimate[i] for i in ids], float).reshape(-1, 2)
    true = np.array([truth[i] for i in ids], float).reshape(-1, 2)
    alignment = align(est, true, kind)
    moved = alignment.apply(est)
    distances = np.linalg.norm(moved - true, axis=1)
    return MapScore(alignment, rmse(distances), rmse(np.linalg.norm(est - true, axis=1)),
                    {i: float(e) for i, e in zip(ids, distances, strict=True)},
                    {i: (float(p[0]), float(p[1])) for i, p in zip(ids, moved, strict=True)},
                    sorted(set(truth) - set(estimate)), sorted(set(estimate) - set(truth)))


# --------------------------------------------------------------------------- trajectories


@dataclass(frozen=True)
class Trajectory:
    """Poses in time order: t (s), x, y (m), theta (rad), one array each."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    theta: np.ndarray

    @classmethod
    def of(cls, rows: list[tuple[float, float, float, float]] | np.ndarray) -> Trajectory:
        """From (t, x, y, theta) rows in any order: sorted by time; of poses with the same time, the
        last one given (the localizer publishes again for a stamp when a camera frame corrects it)."""
        a = np.asarray(rows, float).reshape(-1, 4)
        order = np.argsort(a[:, 0], kind="stable")
        a = a[order]
        keep = np.append(a[1:, 0] != a[:-1, 0], True) if len(a) else np.zeros(0, bool)
        a = a[keep]
        return cls(a[:, 0], a[:, 1], a[:, 2], a[:, 3])

    def __len__(self) -> int:
        return len(self.t)

    def xy(self) -> np.ndarray:
        return np.column_stack([self.x, self.y])


def associate(est_t: np.ndarray, true_t: np.ndarray, max_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j) of an estimate and a true pose, each the other's nearest in time within
    ``max_dt`` s: every estimate takes its nearest true pose, and a true pose taken by several
    estimates keeps only the nearest one. Both time arrays sorted. Returns index arrays."""
    if not len(est_t) or not len(true_t):
        return np.zeros(0, int), np.zeros(0, int)
    right = np.clip(np.searchsorted(true_t, est_t), 1, len(true_t) - 1) if len(true_t) > 1 else np.zeros(
        len(est_t), int)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(true_t[left] - est_t) <= np.abs(true_t[right] - est_t), left, right)
    dt = np.abs(true_t[nearest] - est_t)
    i = np.flatnonzero(dt <= max_dt)
    j = nearest[i]
    # One estimate per true pose: the nearest (sort by true index, then by dt; keep the first of each).
    order = np.lexsort((dt[i], j))
    i, j = i[order], j[order]
    first = np.append(True, j[1:] != j[:-1]) if len(j) else np.zeros(0, bool)
    keep = np.sort(i[first])  # in time order
    return keep, nearest[keep]


@dataclass(frozen=True)
class PathScore:
    """A trajectory against the true one."""

    pairs: int
    """Poses associated by time."""
    unmatched: int
    """Estimated poses with no true pose within the tolerance."""
    alignment: Alignment
    ate_rmse: float
    """Absolute trajectory error after alignment, m."""
    ate_mean: float
    ate_max: float
    ate_rmse_raw: float
    """Before alignment, m."""
    heading_rmse: float
    """Heading error after alignment (the alignment's rotation added), rad."""
    distance: float
    """Length of the true path over the associated poses, m."""
    segment: float
    """RPE segment length, m."""
    segments: int
    """RPE: segments measured (0: the path is shorter than one segment; RPE fields are nan)."""
    rpe_translation: float
    """Mean translation error per distance travelled, % (100 * m/m)."""
    rpe_rotation: float
    """Mean rotation error per distance travelled, deg/m."""


def relative(x: np.ndarray, y: np.ndarray, th: np.ndarray, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, ...]:
    """The motion from pose i to pose j, in pose i's frame: (dx, dy, dtheta)."""
    c, s = np.cos(th[i]), np.sin(th[i])
    gx, gy = x[j] - x[i], y[j] - y[i]
    return c * gx + s * gy, -s * gx + c * gy, wrap_angles(th[j] - th[i])


def score_path(est: Trajectory, truth: Trajectory, *, max_dt: float = 0.02, kind: str = "rigid",
               segment: float = 1.0) -> PathScore:
    """ATE after alignment and RPE per metre of ``est`` against ``truth`` (see the module's docstring)."""
    i, j = associate(est.t, truth.t, max_dt)
    if len(i) < max(MIN_POINTS[kind], 2):
        raise NotEnough(f"{len(i)} poses are within {max_dt:g} s of a true pose: {kind} alignment needs at "
                        f"least {max(MIN_POINTS[kind], 2)} (do the two cover the same time? --max-dt widens it)")
    ex, ey, eth = est.x[i], est.y[i], est.theta[i]
    tx, ty, tth = truth.x[j], truth.y[j], truth.theta[j]
    e_xy, t_xy = np.column_stack([ex, ey]), np.column_stack([tx, ty])
    alignment = align(e_xy, t_xy, kind)
    errors = np.linalg.norm(alignment.apply(e_xy) - t_xy, axis=1)
    heading = wrap_angles(eth + alignment.rotation - tth)

    # RPE: from each pose to the first pose at least `segment` further along the true path.
    along = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(tx), np.diff(ty)))])
    end = np.searchsorted(along, along + segment - 1e-9)
    start = np.flatnonzero(end < len(along))
    end = end[start]
    trans_pct, rot_deg_m = math.nan, math.nan
    if len(start):
        length = along[end] - along[start]
        tdx, tdy, tdth = relative(tx, ty, tth, start, end)
        edx, edy, edth = relative(ex, ey, eth, start, end)
        # inv(true) * est: the estimated motion seen from where the true motion ends.
        c, s = np.cos(tdth), np.sin(tdth)
        gx, gy = edx - tdx, edy - tdy
        err_t = np.hypot(c * gx + s * gy, -s * gx + c * gy)
        err_r = np.abs(wrap_angles(edth - tdth))
        trans_pct = float(np.mean(err_t / length) * 100.0)
        rot_deg_m = float(np.mean(np.degrees(err_r) / length))
    return PathScore(len(i), len(est) - len(i), alignment, rmse(errors), float(errors.mean()), float(errors.max()),
                     rmse(np.hypot(ex - tx, ey - ty)), rmse(heading), float(along[-1]), segment, len(start),
                     trans_pct, rot_deg_m)

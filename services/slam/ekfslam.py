"""EKF-SLAM over landmarks with known ids (ArUco markers): pure logic, no bus.

State: the robot's pose and every landmark seen so far, in SLAM's own frame
(the robot's pose when SLAM started, unless told otherwise)::

    mu = (x, y, theta, m1x, m1y, m2x, m2y, ...)        P: (3 + 2n) x (3 + 2n)

This is the localizer's filter (icefloe/estimation/ekf.py) with the map moved
into the state. The same three steps, each touching a part of P:

Prediction — an odometry increment u = (dx, dy, dth) in the robot's frame
moves the robot only; the landmarks stay. With F and G the localizer's
Jacobians (3 x 3) and M its increment noise::

    P_rr' = F P_rr F^T + G M G^T        robot-robot block
    P_rm' = F P_rm                      robot-map blocks (and their transpose)

Update — landmark i, already in the state, seen at range r and bearing b::

    ddx = mx - x,  ddy = my - y,  q = ddx^2 + ddy^2
    z_hat = (sqrt(q), wrap(atan2(ddy, ddx) - th))
    H = [-ddx/sqrt(q), -ddy/sqrt(q),  0,   ...,  ddx/sqrt(q), ddy/sqrt(q), ...]
        [ ddy/q,       -ddx/q,       -1,   ..., -ddy/q,       ddx/q,       ...]
          (robot columns)                       (the columns of landmark i)
    then the localizer's gate and Joseph update over the whole state.

New landmark — seen for the first time: put it where the sighting says and
grow the state (Thrun, Burgard, Fox, *Probabilistic Robotics*, ch. 10)::

    a = th + b
    m = (x + r cos a, y + r sin a)
    Gx = dm/d(x, y, th) = [[1, 0, -r sin a], [0, 1, r cos a]]
    Gz = dm/d(r, b)     = [[cos a, -r sin a], [sin a, r cos a]]
    P_mm = Gx P_rr Gx^T + Gz R Gz^T     its own uncertainty
    P_mx = Gx P_r:                      correlated with the robot (and so with the map)

The ids tell which landmark is which (no data association to guess); a
sighting that fails the gate is an outlier. At most ``max_landmarks`` are
kept, so a flood of made-up ids cannot grow the state without end.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from icefloe.angles import wrap_angle
from icefloe.estimation.ekf import GatedFilter, Noise, Outcome, Result


class EkfSlam(GatedFilter):
    """`predict` with odometry increments, `observe` landmarks; `pose`, `landmarks`, `covariance`."""

    def __init__(self, noise: Noise | None = None, *, gate_chi2: float = 11.83, max_landmarks: int = 100,
                 mean: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 sigma: tuple[float, float, float] = (1e-3, 1e-3, 1e-3)) -> None:
        """``sigma``: initial std devs of x, y (m), theta (rad): small, SLAM's frame is where it starts."""
        self.noise = noise or Noise()
        self.gate_chi2 = gate_chi2
        self.max_landmarks = max_landmarks
        self.mu = np.zeros(3)
        self.P = np.zeros((3, 3))
        self.index: dict[int, int] = {}
        """Landmark id -> its x's row in mu (its y's is the next)."""
        self.set_pose(mean, sigma)
        self.accepted = self.added = self.outliers = self.unknown = 0

    def set_pose(self, mean: Iterable[float], sigma: Iterable[float]) -> None:
        """Start over at ``mean`` with independent std devs ``sigma``: the map is forgotten."""
        self.mu = np.array(list(mean), dtype=float)
        self.mu[2] = wrap_angle(self.mu[2])
        self.P = np.diag(np.square(np.array(list(sigma), dtype=float)))
        self.index = {}

    @property
    def pose(self) -> tuple[float, float, float]:
        return float(self.mu[0]), float(self.mu[1]), float(self.mu[2])

    @property
    def pose_covariance(self) -> np.ndarray:
        return self.P[:3, :3]

    @property
    def landmarks(self) -> dict[int, tuple[float, float]]:
        """Id -> (x, y) in SLAM's frame, m."""
        return {i: (float(self.mu[k]), float(self.mu[k + 1])) for i, k in self.index.items()}

    def covariance(self, landmark_id: int) -> np.ndarray:
        """The 2 x 2 covariance of a landmark's position, m^2."""
        k = self.index[landmark_id]
        return self.P[k:k + 2, k:k + 2]

    # ------------------------------------------------------------------ prediction

    def predict(self, dx: float, dy: float, dth: float) -> None:
        """Move the robot by an odometry increment (robot frame: m forward, m left, rad CCW)."""
        th = self.mu[2]
        c, s = math.cos(th), math.sin(th)
        F = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
        G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        d = math.hypot(dx, dy)
        n = self.noise
        M = np.diag([n.odom_sigma_d**2 * d, n.odom_sigma_d**2 * d,
                     n.odom_sigma_theta**2 * abs(dth) + n.odom_sigma_theta_d**2 * d])
        self.mu[:3] += [c * dx - s * dy, s * dx + c * dy, dth]
        self.mu[2] = wrap_angle(self.mu[2])
        P = self.P
        P[:3, :3] = F @ P[:3, :3] @ F.T + G @ M @ G.T
        P[:3, 3:] = F @ P[:3, 3:]
        P[3:, :3] = P[:3, 3:].T

    # ------------------------------------------------------------------ update

    def _noise(self, rng: float) -> np.ndarray:
        n = self.noise
        return np.diag([n.sigma_range**2 + (n.sigma_range_rel * rng) ** 2, n.sigma_bearing**2])

    def observe(self, landmark_id: int, rng: float, bearing: float) -> Result:
        """One landmark seen at ``rng`` m and ``bearing`` rad: update with it, or add it to the map."""
        if landmark_id not in self.index:
            return self._add(landmark_id, rng, bearing)
        k = self.index[landmark_id]
        x, y, th = self.mu[:3]
        ddx, ddy = self.mu[k] - x, self.mu[k + 1] - y
        q = ddx * ddx + ddy * ddy
        if q < 1e-6:  # the robot sits on the landmark: the bearing is undefined
            self.outliers += 1
            return Result(Outcome.OUTLIER, landmark_id, math.inf)
        r_hat = math.sqrt(q)
        H = np.zeros((2, len(self.mu)))
        H[:, :3] = [[-ddx / r_hat, -ddy / r_hat, 0.0], [ddy / q, -ddx / q, -1.0]]
        H[:, k:k + 2] = [[ddx / r_hat, ddy / r_hat], [-ddy / q, ddx / q]]
        nu = np.array([rng - r_hat, wrap_angle(bearing - (math.atan2(ddy, ddx) - th))])
        return self.correct(landmark_id, H, nu, self._noise(rng))

    def _add(self, landmark_id: int, rng: float, bearing: float) -> Result:
        if len(self.index) >= self.max_landmarks:
            self.unknown += 1  # the map is full: a flood of made-up ids must not grow the state
            return Result(Outcome.UNKNOWN, landmark_id)
        x, y, th = self.mu[:3]
        a = th + bearing
        c, s = math.cos(a), math.sin(a)
        Gx = np.array([[1.0, 0.0, -rng * s], [0.0, 1.0, rng * c]])
        Gz = np.array([[c, -rng * s], [s, rng * c]])
        n = len(self.mu)
        P = np.zeros((n + 2, n + 2))
        P[:n, :n] = self.P
        P[n:, :n] = Gx @ self.P[:3, :]
        P[:n, n:] = P[n:, :n].T
        P[n:, n:] = Gx @ self.P[:3, :3] @ Gx.T + Gz @ self._noise(rng) @ Gz.T
        self.mu = np.concatenate([self.mu, [x + rng * c, y + rng * s]])
        self.P = P
        self.index[landmark_id] = n
        self.added += 1
        return Result(Outcome.ACCEPTED, landmark_id, 0.0)

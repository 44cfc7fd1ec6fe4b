"""Map making with a known pose: each landmark its own little EKF, pure logic, no bus.

When the robot's pose is known (an external localizer, the simulator's truth),
the landmarks do not depend on one another: each one's position (mx, my) is
estimated on its own, with a 2 x 2 covariance S.

First sighting, at range r and bearing b from the pose (x, y, th)::

    a = th + b
    m = (x + r cos a, y + r sin a)
    Gz = dm/d(r, b)     = [[cos a, -r sin a], [sin a, r cos a]]
    Gx = dm/d(x, y, th) = [[1, 0, -r sin a], [0, 1, r cos a]]
    S  = Gz R Gz^T + Gx Q Gx^T          R: the sighting's noise, Q: the pose's

Every later sighting corrects it (the localizer's update, icefloe/estimation/ekf.py,
with the landmark in the state instead of the robot)::

    ddx = mx - x,  ddy = my - y,  q = ddx^2 + ddy^2
    z_hat = (sqrt(q), wrap(atan2(ddy, ddx) - th))
    H  = dz/dm = [[ ddx/sqrt(q), ddy/sqrt(q)],
                  [-ddy/q,       ddx/q      ]]
    Hx = dz/d(x, y, th)                 (the pose's own uncertainty counts as sighting noise)
    nu = wrap(z - z_hat)
    C  = H S H^T + R + Hx Q Hx^T
    d2 = nu^T C^-1 nu > gate: an outlier, not used
    K  = S H^T C^-1,  m = m + K nu,  S = (I - K H) S (I - K H)^T + K (R + Hx Q Hx^T) K^T

At most ``max_landmarks`` are kept (a flood of made-up ids cannot grow the map without end).
"""

from __future__ import annotations

import math

import numpy as np

from icefloe.angles import wrap_angle
from icefloe.estimation.ekf import Noise, Outcome, Result


class LandmarkMapper:
    """`observe` sightings from known poses; `landmarks` and `covariance` give the map."""

    def __init__(self, noise: Noise | None = None, *, pose_sigma: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 gate_chi2: float = 11.83, max_landmarks: int = 100) -> None:
        """``pose_sigma``: how far off the known pose may be, std dev of x, y (m) and theta (rad)."""
        self.noise = noise or Noise()
        self.Q = np.diag(np.square(pose_sigma))
        self.gate_chi2 = gate_chi2
        self.max_landmarks = max_landmarks
        self.mean: dict[int, np.ndarray] = {}
        self.cov: dict[int, np.ndarray] = {}
        self.accepted = self.added = self.outliers = self.unknown = 0

    @property
    def landmarks(self) -> dict[int, tuple[float, float]]:
        """Id -> (x, y), m, in the frame of the poses."""
        return {i: (float(m[0]), float(m[1])) for i, m in sorted(self.mean.items())}

    def covariance(self, landmark_id: int) -> np.ndarray:
        """2 x 2, m^2."""
        return self.cov[landmark_id]

    def _noise(self, rng: float) -> np.ndarray:
        n = self.noise
        return np.diag([n.sigma_range**2 + (n.sigma_range_rel * rng) ** 2, n.sigma_bearing**2])

    def observe(self, pose: tuple[float, float, float], landmark_id: int, rng: float, bearing: float) -> Result:
        """Landmark ``landmark_id`` seen at ``rng`` m, ``bearing`` rad from ``pose`` (x m, y m, theta rad)."""
        x, y, th = pose
        R = self._noise(rng)
        if landmark_id not in self.mean:
            if len(self.mean) >= self.max_landmarks:
                self.unknown += 1
                return Result(Outcome.UNKNOWN, landmark_id)
            a = th + bearing
            c, s = math.cos(a), math.sin(a)
            Gz = np.array([[c, -rng * s], [s, rng * c]])
            Gx = np.array([[1.0, 0.0, -rng * s], [0.0, 1.0, rng * c]])
            self.mean[landmark_id] = np.array([x + rng * c, y + rng * s])
            self.cov[landmark_id] = Gz @ R @ Gz.T + Gx @ self.Q @ Gx.T
            self.added += 1
            return Result(Outcome.ACCEPTED, landmark_id, 0.0)
        m, S = self.mean[landmark_id], self.cov[landmark_id]
        ddx, ddy = m[0] - x, m[1] - y
        q = ddx * ddx + ddy * ddy
        if q < 1e-6:  # the robot sits on the landmark: the bearing is undefined
            self.outliers += 1
            return Result(Outcome.OUTLIER, landmark_id, math.inf)
        r_hat = math.sqrt(q)
        H = np.array([[ddx / r_hat, ddy / r_hat], [-ddy / q, ddx / q]])
        Hx = np.array([[-ddx / r_hat, -ddy / r_hat, 0.0], [ddy / q, -ddx / q, -1.0]])
        Rt = R + Hx @ self.Q @ Hx.T
        nu = np.array([rng - r_hat, wrap_angle(bearing - (math.atan2(ddy, ddx) - th))])
        C_inv = np.linalg.inv(H @ S @ H.T + Rt)
        d2 = float(nu @ C_inv @ nu)
        if d2 > self.gate_chi2:
            self.outliers += 1
            return Result(Outcome.OUTLIER, landmark_id, d2)
        K = S @ H.T @ C_inv
        IKH = np.eye(2) - K @ H
        self.mean[landmark_id] = m + K @ nu
        self.cov[landmark_id] = IKH @ S @ IKH.T + K @ Rt @ K.T
        self.accepted += 1
        return Result(Outcome.ACCEPTED, landmark_id, d2)

"""Extended Kalman filter localization against a map of known landmarks: pure logic, no bus.

State: the robot's pose in the map frame, mu = (x, y, theta) in (m, m, rad),
theta counter-clockwise positive in (-pi, pi], with covariance P (3 x 3).

Prediction (motion) — the input is an odometry increment u = (dx, dy, dth):
how far the robot moved *in its own frame* between two odometry poses (see
`increment`). Applying it at the current estimate::

    x'  = x + cos(th) dx - sin(th) dy
    y'  = y + sin(th) dx + cos(th) dy
    th' = th + dth

    F = d(x', y', th')/d(x, y, th) = [[1, 0, -sin(th) dx - cos(th) dy],
                                      [0, 1,  cos(th) dx - sin(th) dy],
                                      [0, 0,  1]]
    G = d(x', y', th')/d(dx, dy, dth) = [[cos(th), -sin(th), 0],
                                         [sin(th),  cos(th), 0],
                                         [0,        0,       1]]
    P' = F P F^T + G M G^T

M, the noise of the increment, grows with the distance d and the turn |dth|
(random walk: variances add along the path)::

    M = diag(sd^2 d,  sd^2 d,  st^2 |dth| + std^2 d)

Update (measurement) — one landmark i at known (mx, my), seen at range r and
bearing b (Thrun, Burgard, Fox, *Probabilistic Robotics*, 2005, Table 7.2)::

    ddx = mx - x,  ddy = my - y,  q = ddx^2 + ddy^2
    z_hat = (sqrt(q), wrap(atan2(ddy, ddx) - th))
    H = [[-ddx/sqrt(q), -ddy/sqrt(q),  0],
         [ ddy/q,       -ddx/q,       -1]]
    nu = wrap(z - z_hat)             innovation (the bearing part wrapped)
    S  = H P H^T + R                 R = diag(sr^2 + (srel r)^2, sb^2)
    d2 = nu^T S^-1 nu                Mahalanobis distance, chi-square with 2 dof
    if d2 > gate: reject (outlier)
    K  = P H^T S^-1
    mu = mu + K nu
    P  = (I - K H) P (I - K H)^T + K R K^T     (Joseph form: stays symmetric and positive)

Several landmarks in one frame are applied one after the other; each is gated
against the estimate the previous ones left.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ..angles import wrap_angle


@dataclass(frozen=True)
class Noise:
    """Noise model (``config.localizer``): standard deviations."""

    sigma_range: float = 0.03
    """m."""
    sigma_range_rel: float = 0.02
    """Fraction of the range."""
    sigma_bearing: float = 0.02
    """rad."""
    odom_sigma_d: float = 0.02
    """m per sqrt(m) travelled."""
    odom_sigma_theta: float = 0.03
    """rad per sqrt(rad) turned."""
    odom_sigma_theta_d: float = 0.03
    """rad per sqrt(m) travelled."""


class Outcome(Enum):
    ACCEPTED = "accepted"
    OUTLIER = "rejected by the Mahalanobis gate"
    UNKNOWN = "unknown marker id (not in the map)"


@dataclass(frozen=True)
class Result:
    """What one observation did: outcome, its squared Mahalanobis distance (nan if unknown)."""

    outcome: Outcome
    id: int
    d2: float = math.nan


def increment(prev: tuple[float, float, float], new: tuple[float, float, float]) -> tuple[float, float, float]:
    """The motion from odometry pose ``prev`` to ``new``, in the robot's frame at ``prev``.

    (dx m forward, dy m left, dth rad). It does not depend on where the
    odometry frame is, so it can be applied to the map-frame estimate.
    """
    x0, y0, th0 = prev
    x1, y1, th1 = new
    c, s = math.cos(th0), math.sin(th0)
    ex, ey = x1 - x0, y1 - y0
    return c * ex + s * ey, -s * ex + c * ey, wrap_angle(th1 - th0)


def shift_sighting(rng: float, bearing: float, u: tuple[float, float, float]) -> tuple[float, float]:
    """A landmark sighting re-expressed from where the robot is now.

    The camera saw the landmark at (``rng`` m, ``bearing`` rad) some time ago;
    since then the robot moved by ``u`` = (dx, dy, dth), in the robot's frame
    at the time of the sighting (odometry's increment, which is precise over a
    fraction of a second). The landmark's position in the old robot frame is
    p = rng (cos bearing, sin bearing); in the present frame it is
    R(-dth) (p - (dx, dy)). Returns its (range m, bearing rad) from there.
    Without this, a frame 50 ms old taken while turning at 1.5 rad/s would
    drag the heading by 4 degrees.
    """
    dx, dy, dth = u
    px, py = rng * math.cos(bearing) - dx, rng * math.sin(bearing) - dy
    c, s = math.cos(dth), math.sin(dth)
    qx, qy = c * px + s * py, -s * px + c * py
    return math.hypot(qx, qy), math.atan2(qy, qx)


class GatedFilter:
    """What the localizer's filter (`Ekf`) and SLAM's share: the state ``mu`` with covariance ``P``,
    corrected by one sighting at a time through the Mahalanobis gate, and counts of what each did."""

    mu: np.ndarray
    P: np.ndarray
    gate_chi2: float
    accepted: int
    outliers: int

    def correct(self, landmark_id: int, H: np.ndarray, nu: np.ndarray, R: np.ndarray) -> Result:
        """Correct the state with one sighting (`gated_update`), unless it fails the gate; count which."""
        mu, P, d2 = gated_update(self.mu, self.P, H, nu, R, self.gate_chi2)
        if mu is None:
            self.outliers += 1
            return Result(Outcome.OUTLIER, landmark_id, d2)
        self.mu, self.P = mu, P
        self.accepted += 1
        return Result(Outcome.ACCEPTED, landmark_id, d2)


class Ekf(GatedFilter):
    """EKF localizer over (x, y, theta). `predict` with odometry, `observe` landmarks."""

    def __init__(
        self,
        landmarks: Mapping[int, tuple[float, float]],
        noise: Noise | None = None,
        *,
        gate_chi2: float = 11.83,
        mean: tuple[float, float, float] = (0.0, 0.0, 0.0),
        sigma: tuple[float, float, float] = (0.1, 0.1, 0.1),
    ) -> None:
        """``landmarks``: id -> (x, y) in the map, m. ``sigma``: initial std dev of x, y (m), theta (rad)."""
        self.landmarks = dict(landmarks)
        self.noise = noise or Noise()
        self.gate_chi2 = gate_chi2
        self.mu = np.zeros(3)
        self.P = np.zeros((3, 3))
        self.set_pose(mean, sigma)
        self.accepted = 0
        self.outliers = 0
        self.unknown = 0

    def set_pose(self, mean: Iterable[float], sigma: Iterable[float]) -> None:
        """Start over at ``mean`` (m, m, rad) with independent std devs ``sigma``."""
        self.mu = np.array(list(mean), dtype=float)
        self.mu[2] = wrap_angle(self.mu[2])
        self.P = np.diag(np.square(np.array(list(sigma), dtype=float)))

    @property
    def pose(self) -> tuple[float, float, float]:
        return float(self.mu[0]), float(self.mu[1]), float(self.mu[2])

    # ------------------------------------------------------------------ prediction

    def predict(self, dx: float, dy: float, dth: float) -> None:
        """Move by an odometry increment (robot frame: m forward, m left, rad CCW)."""
        th = self.mu[2]
        c, s = math.cos(th), math.sin(th)
        F = np.array([[1.0, 0.0, -s * dx - c * dy],
                      [0.0, 1.0, c * dx - s * dy],
                      [0.0, 0.0, 1.0]])
        G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        d = math.hypot(dx, dy)
        n = self.noise
        M = np.diag([n.odom_sigma_d**2 * d, n.odom_sigma_d**2 * d,
                     n.odom_sigma_theta**2 * abs(dth) + n.odom_sigma_theta_d**2 * d])
        self.mu = self.mu + np.array([c * dx - s * dy, s * dx + c * dy, dth])
        self.mu[2] = wrap_angle(self.mu[2])
        self.P = F @ self.P @ F.T + G @ M @ G.T

    # ------------------------------------------------------------------ update

    def expected(self, landmark_id: int) -> tuple[float, float]:
        """(range m, bearing rad) at which the current estimate expects to see a known landmark."""
        mx, my = self.landmarks[landmark_id]
        ddx, ddy = mx - self.mu[0], my - self.mu[1]
        return math.hypot(ddx, ddy), wrap_angle(math.atan2(ddy, ddx) - self.mu[2])

    def observe(self, landmark_id: int, rng: float, bearing: float) -> Result:
        """Correct the estimate with one landmark seen at ``rng`` m and ``bearing`` rad."""
        if landmark_id not in self.landmarks:
            self.unknown += 1
            return Result(Outcome.UNKNOWN, landmark_id)
        mx, my = self.landmarks[landmark_id]
        ddx, ddy = mx - self.mu[0], my - self.mu[1]
        q = ddx * ddx + ddy * ddy
        if q < 1e-6:  # the robot sits on the landmark: the bearing is undefined, nothing to learn
            self.outliers += 1
            return Result(Outcome.OUTLIER, landmark_id, math.inf)
        r_hat = math.sqrt(q)
        H = np.array([[-ddx / r_hat, -ddy / r_hat, 0.0],
                      [ddy / q, -ddx / q, -1.0]])
        nu = np.array([rng - r_hat, wrap_angle(bearing - (math.atan2(ddy, ddx) - self.mu[2]))])
        n = self.noise
        R = np.diag([n.sigma_range**2 + (n.sigma_range_rel * rng) ** 2, n.sigma_bearing**2])
        return self.correct(landmark_id, H, nu, R)


def gated_update(mu: np.ndarray, P: np.ndarray, H: np.ndarray, nu: np.ndarray, R: np.ndarray,
                 gate_chi2: float) -> tuple[np.ndarray | None, np.ndarray | None, float]:
    """One EKF correction with innovation ``nu`` (measurement Jacobian ``H``, noise ``R``), gated:
    (mu, P, d2), or (None, None, d2) when the squared Mahalanobis distance d2 exceeds ``gate_chi2``.
    ``mu[2]`` is the heading (wrapped). Joseph form for P, so it stays symmetric positive definite."""
    S = H @ P @ H.T + R
    S_inv = np.linalg.inv(S)
    d2 = float(nu @ S_inv @ nu)
    if d2 > gate_chi2:
        return None, None, d2
    K = P @ H.T @ S_inv
    mu = mu + K @ nu
    mu[2] = wrap_angle(mu[2])
    IKH = np.eye(len(mu)) - K @ H
    return mu, IKH @ P @ IKH.T + K @ R @ K.T, d2


def pose_from_landmarks(seen: Iterable[tuple[tuple[float, float], float, float]]) -> tuple[float, float, float] | None:
    """The pose that best explains landmarks seen at once, or None if they cannot fix it.

    ``seen``: ((mx, my) map position m, range m, bearing rad) per landmark.
    Each sighting puts the landmark at p = r (cos b, sin b) in the robot frame;
    we want the rotation th and translation t with m ~ R(th) p + t. With the
    centroids removed (p', m'), the least-squares rotation is (2-D Kabsch /
    Umeyama, 1991)::

        th = atan2(sum(p'_x m'_y - p'_y m'_x), sum(p'_x m'_x + p'_y m'_y))
        t  = mean(m) - R(th) mean(p)

    Needs two or more landmarks at least 0.1 m apart.
    """
    pairs = [(np.array(m, dtype=float), np.array([r * math.cos(b), r * math.sin(b)])) for m, r, b in seen]
    if len(pairs) < 2:
        return None
    ms = np.array([m for m, _ in pairs])
    ps = np.array([p for _, p in pairs])
    m_c, p_c = ms - ms.mean(axis=0), ps - ps.mean(axis=0)
    if np.max(np.linalg.norm(m_c, axis=1)) < 0.05:
        return None
    cross = float(np.sum(p_c[:, 0] * m_c[:, 1] - p_c[:, 1] * m_c[:, 0]))
    dot = float(np.sum(p_c[:, 0] * m_c[:, 0] + p_c[:, 1] * m_c[:, 1]))
    th = math.atan2(cross, dot)
    c, s = math.cos(th), math.sin(th)
    t = ms.mean(axis=0) - np.array([[c, -s], [s, c]]) @ ps.mean(axis=0)
    return float(t[0]), float(t[1]), wrap_angle(th)

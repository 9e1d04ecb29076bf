"""The paper's Kalman filter (Lee & Park, eq. 3–4), reproduced as the baseline to beat.

State x = [position, velocity, acceleration]; triple integrator with white jerk of
spectral density W; the measurement is the reference-point-compensated acceleration,
H = [0, 0, 1]. Pure functions (filterpy's functional form) plus a thin class.

Known limit (shared/spec/paper-and-sensor.md): a bias in the measured acceleration is
not observable with H = [0, 0, 1] — the filter smooths noise and integrates whatever
bias the reference point left, exactly like raw integration. That is the drift of the
paper's fig. 7, and the reason for gateway/core/estimator.py.
"""
from __future__ import annotations

import numpy as np

H_ACCELERATION = np.array([[0.0, 0.0, 1.0]])

# The paper does not print W. A white-jerk density of 1000 (m/s³)²/Hz lets the filter
# follow the experiment's 10 m/s² steps within a few samples (a step of Δa every ~0.1 s:
# W ≈ Δa²/0.1 s); the drift it shows does not depend on this choice.
DEFAULT_JERK_DENSITY = 1000.0


def transition(dt_s: float) -> np.ndarray:
    """Φ of eq. 3."""
    return np.array([[1.0, dt_s, 0.5 * dt_s * dt_s], [0.0, 1.0, dt_s], [0.0, 0.0, 1.0]])


def process_noise(dt_s: float, jerk_density: float) -> np.ndarray:
    """Q of eq. 4: continuous white jerk of density W (= filterpy's Q_continuous_white_noise(3, dt, W))."""
    d = dt_s
    return jerk_density * np.array(
        [
            [d**5 / 20.0, d**4 / 8.0, d**3 / 6.0],
            [d**4 / 8.0, d**3 / 3.0, d**2 / 2.0],
            [d**3 / 6.0, d**2 / 2.0, d],
        ]
    )


def predict(x, P, F, Q):
    return F @ x, F @ P @ F.T + Q


def update(x, P, z, H, R):
    """Kalman update with the Joseph form (as filterpy); returns x, P, innovation, its covariance S."""
    z = np.atleast_1d(np.asarray(z, dtype=float))
    R = np.atleast_2d(R)
    y = z - H @ x
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    x = x + K @ y
    i_kh = np.eye(P.shape[0]) - K @ H
    P = i_kh @ P @ i_kh.T + K @ R @ K.T
    return x, P, y, S


class PaperKalmanFilter:
    """One sample in, one estimate out: predict over the period, then update with the measurement."""

    def __init__(self, jerk_density: float, measurement_var_mps2_sq: float):
        if not (jerk_density > 0 and measurement_var_mps2_sq > 0):
            raise ValueError("jerk density and measurement variance must be positive")
        self.jerk_density = jerk_density
        self.R = np.array([[measurement_var_mps2_sq]])
        self.reset()

    def reset(self) -> None:
        # at rest at the origin; the acceleration is known to the measurement noise
        self.x = np.zeros(3)
        self.P = np.diag([0.0, 0.0, self.R[0, 0]])
        self.innovation = 0.0
        self.innovation_var = float(self.R[0, 0])

    def predict(self, dt_s: float) -> None:
        self.x, self.P = predict(self.x, self.P, transition(dt_s), process_noise(dt_s, self.jerk_density))

    def update(self, acc_mps2: float) -> None:
        self.x, self.P, y, S = update(self.x, self.P, acc_mps2, H_ACCELERATION, self.R)
        self.innovation, self.innovation_var = float(y[0]), float(S[0, 0])

    def step(self, dt_s: float, acc_mps2: float | None) -> np.ndarray:
        """dt_s since the previous sample; acc None (invalid) → predict only."""
        if dt_s > 0:
            self.predict(dt_s)
        if acc_mps2 is not None and np.isfinite(acc_mps2):
            self.update(acc_mps2)
        return self.x.copy()


def run_paper_filter(t_s, acc_mps2, valid, jerk_density: float, measurement_var: float):
    """The class over a series: states (N×3) and position variance (N)."""
    kf = PaperKalmanFilter(jerk_density, measurement_var)
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(acc_mps2, dtype=float)
    ok = np.asarray(valid, dtype=bool) & np.isfinite(a)
    states = np.empty((t.size, 3))
    pos_var = np.empty(t.size)
    for k in range(t.size):
        kf.step(t[k] - t[k - 1] if k else 0.0, a[k] if ok[k] else None)
        states[k] = kf.x
        pos_var[k] = kf.P[0, 0]
    return states, pos_var

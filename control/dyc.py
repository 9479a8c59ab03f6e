"""Direct yaw-moment control laws on the linear 2-DOF (beta, r) model.

x = [beta, r - r_ref], input the corrective yaw moment Mz [N m]:
    beta_dot = -(C_f + C_r)/(m u) beta + ((b C_r - a C_f)/(m u^2) - 1) r + C_f/(m u) delta
    r_dot    = (b C_r - a C_f)/I_z beta - (a^2 C_f + b^2 C_r)/(I_z u) r + a C_f/I_z delta + Mz/I_z
with delta the front angle; a rear angle delta_r adds C_r/(m u) delta_r and -b C_r/I_z delta_r
(Rajamani, Vehicle Dynamics and Control, 2012, sec. 2.3 and 8.3; per-axle stiffnesses).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_continuous_are

from control.reference import GRAVITY, bicycle_state_matrix


def bicycle_matrices(u: float, params) -> tuple[np.ndarray, np.ndarray]:
    """(A, B_mz) of the 2-DOF model at speed ``u`` [m/s] for states [beta, r] and input Mz."""
    a11, a12, a21, a22 = bicycle_state_matrix(u, params)
    return np.array([[a11, a12], [a21, a22]]), np.array([[0.0], [1.0 / params.yaw_inertia]])


def actuator_lag_terms(params) -> tuple[float, float]:
    """(motor torque lag [s], longitudinal relaxation length sigma_kappa at the static wheel load
    [m]) of :func:`actuator_lag`; (0, 0) for a parameter object without a motor lag and tyre."""
    if not (hasattr(params, "motor_time_constant") and hasattr(params, "static_relaxation_lengths")):
        return 0.0, 0.0
    return params.motor_time_constant, params.static_relaxation_lengths[0]


def actuator_lag(u, params, terms: tuple[float, float] | None = None):
    """Time constant [s] of the delivered yaw moment behind the commanded one at speed ``u``
    [m/s]: the motors' torque lag plus the longitudinal tyre force's build-up over its
    relaxation length at the static wheel load, sigma_kappa / u (Pacejka, Tire and Vehicle
    Dynamics, 3rd ed., sec. 7.2): 28 ms at 80 km/h, 80 ms at 20 km/h on this car. ``u`` scalar
    or (B,); ``terms``: :func:`actuator_lag_terms` of ``params`` if already at hand. Zero for a
    parameter object without a motor lag and tyre (a bare 2-DOF description)."""
    motor, sigma_kappa = actuator_lag_terms(params) if terms is None else terms
    return motor + sigma_kappa / np.maximum(np.abs(np.asarray(u, dtype=float)), 1.0)


@dataclass(frozen=True)
class LQRWeights:
    """Bryson's rule: acceptable sideslip [rad], yaw-rate error [rad/s] and yaw moment [N m]."""

    beta: float = 0.05
    yaw_rate_error: float = 0.03
    yaw_moment: float = 2500.0


@dataclass
class LQRYawController:
    """Gain-scheduled LQR aware of the actuator's lag: Mz = -K(u) [beta, r - r_ref, M], with M the yaw
    moment the wheels deliver now (a first-order lag :func:`actuator_lag` behind what they were
    given, which the caller reports through :meth:`note_delivered`). K from the continuous Riccati
    equation of the 2-DOF model augmented with that lag, M_dot = (Mz - M) / tau(u), on a speed grid
    (3-45 m/s), interpolated linearly in u. Designed without the lag, the gains that suit 80 km/h
    leave the loop with damping ratio ~0.4 there and, at 20 km/h where the tyres' force build-up
    (sigma / u) is slower than the car's yaw response, commanded moments the tyres could not follow:
    the wheels spun up and the car oscillated in a gentle turn (README, "Control"). With it: damping
    ~0.8 at every speed, and 2.5x lower yaw-rate gain at 20 km/h."""

    params: object
    weights: LQRWeights = field(default_factory=LQRWeights)
    speeds: np.ndarray = field(default_factory=lambda: np.linspace(3.0, 45.0, 43))

    def __post_init__(self) -> None:
        w = self.weights
        if min(w.beta, w.yaw_rate_error, w.yaw_moment) <= 0:
            raise ValueError(f"LQR weights must be > 0, got {w}")
        R = np.array([[1 / w.yaw_moment**2]])
        self._lag_terms = actuator_lag_terms(self.params)
        self._delivered: np.ndarray | None = None
        gains = []
        for u in self.speeds:
            A, B = bicycle_matrices(float(u), self.params)
            tau = float(actuator_lag(float(u), self.params, self._lag_terms))
            if tau > 0.0:  # states [beta, r, M], input the commanded moment
                A = np.block([[A, B], [np.zeros((1, 2)), np.full((1, 1), -1.0 / tau)]])
                B = np.array([[0.0], [0.0], [1.0 / tau]])
            Q = np.diag([1 / w.beta**2, 1 / w.yaw_rate_error**2, 0.0][:A.shape[0]])
            P = solve_continuous_are(A, B, Q, R)
            k = np.linalg.solve(R, B.T @ P)[0]
            gains.append(np.append(k, 0.0) if tau == 0.0 else k)
        self.gains = np.array(gains)  # (S, 3): on beta, r - r_ref and the delivered moment

    def gain(self, u: np.ndarray) -> np.ndarray:
        """K(u) (B, 3)."""
        u = np.clip(np.abs(u), self.speeds[0], self.speeds[-1])
        return np.stack([np.interp(u, self.speeds, self.gains[:, j]) for j in range(3)], axis=-1)

    def reset(self) -> None:
        self._delivered = None

    def note_delivered(self, moment: np.ndarray, u: np.ndarray, dt: float) -> None:
        """The wheels were given ``moment`` (B,) [N m] for ``dt`` [s] at speed ``u``: the moment
        they deliver follows it through the actuator lag."""
        if self._delivered is None:
            self._delivered = np.zeros_like(moment)
        lag = actuator_lag(u, self.params, self._lag_terms)
        self._delivered = self._delivered + (moment - self._delivered) * np.minimum(dt / np.maximum(lag, 1e-12), 1.0)

    def __call__(self, u, beta, r, r_ref, delta_f, delta_r, dt: float, mu: np.ndarray | None = None) -> np.ndarray:
        """Mz (B,) [N m]; the steer angles enter through the reference only (pure state feedback),
        the moment the wheels deliver now through :meth:`note_delivered` (zero before). ``mu``
        is unused (the laws' common signature): the gains are scheduled on speed only."""
        k = self.gain(u)
        moment = -(k[:, 0] * beta + k[:, 1] * (r - r_ref))
        return moment if self._delivered is None else moment - k[:, 2] * self._delivered


@dataclass
class SlidingModeYawController:
    """Sliding mode on s = (r - r_ref) - lam * beta (beta_ref = 0):
    Mz = I_z (r_ref_dot + lam beta_dot - f_r - eta sat(s / phi)) with f_r the 2-DOF yaw
    acceleration without Mz and beta_dot = (F_yf + F_yr) / (m u) - r; the boundary layer
    ``phi`` [rad/s] removes chattering (Slotine & Li 1991, ch. 7). ``lam`` weights sideslip
    into the surface with the sign of this car's LQR gain on beta (tested; a strongly
    understeering car's optimal gain can have the other sign): a car sliding out of a left turn
    (beta < 0) needs a clockwise moment, as a yaw rate above the reference does.

    The linear model's tyre forces grow without bound with slip; beyond the friction limit
    that would command large moments of the wrong sign. f_r therefore uses axle forces
    saturated at the estimated mu times the axle load (mu given per call). Even so it
    over-predicts a braked axle past its peak by more than ``eta``, so outside the boundary
    layer the equivalent control is dropped where it points away from the surface: the
    moment then always has the sign of -s there (reaching holds; Slotine & Li's condition
    needs eta above the model error, which this keeps from mattering)."""

    params: object
    lam: float = 0.5
    eta: float = 1.0
    phi: float = 0.05
    max_moment: float = 4000.0
    _previous_ref: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("eta", "phi", "max_moment"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SlidingModeYawController.{name} must be > 0, got {getattr(self, name)!r}")
        if self.lam < 0:
            raise ValueError(f"lam must be >= 0, got {self.lam!r}")

    def reset(self) -> None:
        self._previous_ref = None

    def __call__(self, u, beta, r, r_ref, delta_f, delta_r, dt: float, mu: np.ndarray | None = None) -> np.ndarray:
        """Mz (B,) [N m] at speed u, sideslip beta, yaw rate r and reference r_ref (B,), front and
        rear road-wheel angles delta_f, delta_r [rad] (B,), per-wheel mu (B, 4). ``beta`` as the
        StabilityController shrinks it: where it is exactly 0 (inside the sideslip deadband) it is
        held, so its rate in the equivalent control is 0 too (the linear model's beta_dot at
        beta = 0 is not 0 in a turn: it had commanded ~-67 N m at 0.43 g, 80 km/h, with the car
        on its reference)."""
        p = self.params
        c_f, c_r = p.axle_cornering_stiffness
        a, b, iz, m, L = p.cg_to_front, p.cg_to_rear, p.yaw_inertia, p.mass, p.wheelbase
        u = np.maximum(np.abs(u), 1.0)
        mu_mean = np.ones_like(u) if mu is None else np.mean(mu, axis=-1)
        front_limit = mu_mean * m * GRAVITY * b / L
        rear_limit = mu_mean * m * GRAVITY * a / L
        fy_front = np.clip(c_f * (delta_f - beta - a * r / u), -front_limit, front_limit)
        fy_rear = np.clip(c_r * (delta_r - beta + b * r / u), -rear_limit, rear_limit)
        f_r = (a * fy_front - b * fy_rear) / iz
        beta_dot = np.where(beta == 0.0, 0.0, (fy_front + fy_rear) / (m * u) - r)
        ref_dot = np.zeros_like(r_ref) if self._previous_ref is None else (r_ref - self._previous_ref) / dt
        self._previous_ref = r_ref.copy()
        s = (r - r_ref) - self.lam * beta
        equivalent = ref_dot + self.lam * beta_dot - f_r
        # outside the boundary layer the model's equivalent control may only help reach the surface:
        # the linear axle model (clipped at mu Fz) over-predicts a saturated axle's force (beyond the
        # tyre's peak, under combined slip), by far more than the reaching rate eta, and cancelling
        # that phantom yaw acceleration turned the moment against s (ISO 3888-2 at 70 km/h, oracle:
        # r stuck near 0 at full right lock with +3 kN m, 5.6 m off the line)
        equivalent = np.where((np.abs(s) > self.phi) & (equivalent * s > 0.0), 0.0, equivalent)
        mz = iz * (equivalent - self.eta * np.clip(s / self.phi, -1.0, 1.0))
        return np.clip(mz, -self.max_moment, self.max_moment)

"""Direct yaw-moment control laws on the linear 2-DOF (beta, r) model.

x = [beta, r - r_ref], input the corrective yaw moment Mz [N m]:
    beta_dot = -(C_f + C_r)/(m u) beta + ((b C_r - a C_f)/(m u^2) - 1) r + C_f/(m u) delta
    r_dot    = (b C_r - a C_f)/I_z beta - (a^2 C_f + b^2 C_r)/(I_z u) r + a C_f/I_z delta + Mz/I_z
with delta the front angle; a rear angle delta_r adds C_r/(m u) delta_r and -b C_r/I_z delta_r
(Rajamani, Vehicle Dynamics and Control, 2012, sec. 2.3 and 8.3; per-axle stiffnesses).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
from numba.extending import register_jitable
from scipy.linalg import solve_continuous_are

from fourwis.control.allocation import allocation_kernel
from fourwis.control.reference import (
    GRAVITY,
    axle_friction,
    bicycle_state_matrix,
    eq20_gain,
    sideslip_bound_of,
    slower_time_constant,
    steady_yaw_rate,
)
from fourwis.core.kernels import JIT, scratch


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
    return lag_time(np.asarray(u, dtype=float), motor, sigma_kappa)


@register_jitable
def lag_time(u, motor: float, sigma_kappa: float):
    """:func:`actuator_lag` from its terms (written once, for numpy arrays and compiled code)."""
    return motor + sigma_kappa / np.maximum(np.abs(u), 1.0)


@register_jitable
def delivered_next(delivered, moment, lag, dt: float):
    """The yaw moment [N m] the wheels deliver after ``dt`` [s] of ``moment``, a first-order lag
    ``lag`` [s] behind it (:meth:`LQRYawController.note_delivered`)."""
    return delivered + (moment - delivered) * np.minimum(dt / np.maximum(lag, 1e-12), 1.0)


@register_jitable
def lqr_moment(k_beta, k_error, k_moment, beta, r, r_ref, delivered):
    """The LQR's yaw moment -K [beta, r - r_ref, M] [N m] (gains k_*, delivered moment M)."""
    return -(k_beta * beta + k_error * (r - r_ref)) - k_moment * delivered


@numba.njit(inline="always", **JIT)
def interpolated_gain(u: float, speeds, gains, j: int) -> float:
    """Column ``j`` of the gain table ``gains`` (S, 3) at speed |u| [m/s], linear in speed over
    ``speeds`` (S,) and held beyond its ends (the rule of numpy.interp)."""
    x = min(max(abs(u), speeds[0]), speeds[-1])
    i = np.searchsorted(speeds, x, side="right") - 1
    if i >= speeds.size - 1 or speeds[i] == x:
        return gains[i, j]
    slope = (gains[i + 1, j] - gains[i, j]) / (speeds[i + 1] - speeds[i])
    return slope * (x - speeds[i]) + gains[i, j]


@numba.njit(**JIT)
def _interpolated_gains(u, speeds, gains, out) -> None:
    for b in range(u.size):
        for j in range(3):
            out[b, j] = interpolated_gain(u[b], speeds, gains, j)


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
            Q = np.diag([1 / w.beta**2, 1 / w.yaw_rate_error**2, 0.0][: A.shape[0]])
            P = solve_continuous_are(A, B, Q, R)
            k = np.linalg.solve(R, B.T @ P)[0]
            gains.append(np.append(k, 0.0) if tau == 0.0 else k)
        self.gains = np.array(gains)  # (S, 3): on beta, r - r_ref and the delivered moment

    def gain(self, u: np.ndarray) -> np.ndarray:
        """K(u): shape u.shape + (3,) (u scalar or any array of speeds [m/s])."""
        u = np.asarray(u, dtype=float)
        out = np.empty((u.size, 3))
        _interpolated_gains(np.ascontiguousarray(u).ravel(), self.speeds, self.gains, out)
        return out.reshape(u.shape + (3,))

    def reset(self) -> None:
        self._delivered = None

    def note_delivered(self, moment: np.ndarray, u: np.ndarray, dt: float) -> None:
        """The wheels were given ``moment`` (B,) [N m] for ``dt`` [s] at speed ``u``: the moment
        they deliver follows it through the actuator lag."""
        delivered = np.zeros_like(moment) if self._delivered is None else self._delivered
        self._delivered = delivered_next(delivered, moment, actuator_lag(u, self.params, self._lag_terms), dt)

    def __call__(self, u, beta, r, r_ref, delta_f, delta_r, dt: float, mu: np.ndarray | None = None) -> np.ndarray:
        """Mz (B,) [N m]; the steer angles enter through the reference only (pure state feedback),
        the moment the wheels deliver now through :meth:`note_delivered` (zero before). ``mu``
        is unused (the laws' common signature): the gains are scheduled on speed only."""
        k = self.gain(u)
        delivered = 0.0 if self._delivered is None else self._delivered
        return lqr_moment(k[..., 0], k[..., 1], k[..., 2], beta, r, r_ref, delivered)


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
        u, beta, r, r_ref, delta_f, delta_r = np.broadcast_arrays(
            *(np.asarray(x, dtype=float) for x in (u, beta, r, r_ref, delta_f, delta_r))
        )
        mu_mean = np.ones_like(u) if mu is None else np.broadcast_to(np.mean(mu, axis=-1), u.shape)
        previous = np.full(u.shape, np.nan) if self._previous_ref is None else self._previous_ref
        flat = (
            np.ascontiguousarray(x, dtype=float).ravel()
            for x in (u, beta, r, r_ref, delta_f, delta_r, mu_mean, np.broadcast_to(previous, u.shape))
        )
        moment = np.empty(u.size)
        _smc_moments(*flat, float(dt), self.terms(), moment)
        moment = moment.reshape(u.shape)
        self._previous_ref = r_ref.copy()
        return moment

    def terms(self) -> tuple[float, ...]:
        """(C_f, C_r, a, b, I_z, m, L, lam, eta, phi, max_moment) as :func:`smc_moment` takes them."""
        p = self.params
        c_f, c_r = p.axle_cornering_stiffness
        return (
            float(c_f),
            float(c_r),
            float(p.cg_to_front),
            float(p.cg_to_rear),
            float(p.yaw_inertia),
            float(p.mass),
            float(p.wheelbase),
            float(self.lam),
            float(self.eta),
            float(self.phi),
            float(self.max_moment),
        )


@numba.njit(inline="always", **JIT)
def smc_moment(u, beta, r, r_ref, delta_f, delta_r, mu_mean, previous_ref, dt, terms) -> float:
    """:class:`SlidingModeYawController`'s moment [N m] for one vehicle; ``previous_ref``: the
    reference at the previous call (NaN: none, its rate is then 0); ``terms``:
    :meth:`SlidingModeYawController.terms`."""
    c_f, c_r, a, b, iz, m, wheelbase, lam, eta, phi, max_moment = terms
    u = max(abs(u), 1.0)
    front_limit = mu_mean * m * GRAVITY * b / wheelbase
    rear_limit = mu_mean * m * GRAVITY * a / wheelbase
    fy_front = min(max(c_f * (delta_f - beta - a * r / u), -front_limit), front_limit)
    fy_rear = min(max(c_r * (delta_r - beta + b * r / u), -rear_limit), rear_limit)
    f_r = (a * fy_front - b * fy_rear) / iz
    beta_dot = 0.0 if beta == 0.0 else (fy_front + fy_rear) / (m * u) - r
    ref_dot = 0.0 if math.isnan(previous_ref) else (r_ref - previous_ref) / dt
    s = (r - r_ref) - lam * beta
    equivalent = ref_dot + lam * beta_dot - f_r
    # outside the boundary layer the model's equivalent control may only help reach the surface:
    # the linear axle model (clipped at mu Fz) over-predicts a saturated axle's force (beyond the
    # tyre's peak, under combined slip), by far more than the reaching rate eta, and cancelling
    # that phantom yaw acceleration turned the moment against s (ISO 3888-2 at 70 km/h, oracle:
    # r stuck near 0 at full right lock with +3 kN m, 5.6 m off the line)
    if abs(s) > phi and equivalent * s > 0.0:
        equivalent = 0.0
    mz = iz * (equivalent - eta * min(max(s / phi, -1.0), 1.0))
    return min(max(mz, -max_moment), max_moment)


@numba.njit(**JIT)
def _smc_moments(u, beta, r, r_ref, delta_f, delta_r, mu_mean, previous_ref, dt, terms, out) -> None:
    for b in range(u.size):
        out[b] = smc_moment(
            u[b], beta[b], r[b], r_ref[b], delta_f[b], delta_r[b], mu_mean[b], previous_ref[b], dt, terms
        )


ACTIVE_SPEED = 2.0  #: below this speed [m/s] the law's moment is zero (the allocator still shares the drive)
YAW_DEADBAND = 0.02  #: |r - r_ref| [rad/s] tolerated without intervention (ESC practice)
MIN_PLANNING_MU = 0.1  #: the margin's floor: it lowers no planning friction below this (nor lifts one)

#: the settings of :func:`stability_command`, in the order of its settings array
#: (:meth:`control.StabilityController.kernel_arrays`): the law (1: sliding mode, 0: LQR), rear
#: steer (1 / 0), the step [s], the friction ellipse (1 / 0), mu_margin, the reference's
#: understeer gradient [rad s^2/m], wheelbase [m], the rear servo's range [rad] and rate
#: [rad/s], the actuator lag's terms (:func:`actuator_lag_terms`) and
#: :func:`control.reference.bicycle_terms`
SETTINGS = (
    "sliding_mode",
    "rear_steer",
    "dt",
    "friction_ellipse",
    "mu_margin",
    "understeer",
    "wheelbase",
    "max_rear_steer",
    "rear_steer_rate",
    "motor_lag",
    "sigma_kappa",
    "c_f",
    "c_r",
    "mass",
    "yaw_inertia",
    "cg_to_front",
    "cg_to_rear",
)
(
    S_SMC,
    S_REAR_STEER,
    S_DT,
    S_ELLIPSE,
    S_MARGIN,
    S_UNDERSTEER,
    S_WHEELBASE,
    S_MAX_REAR,
    S_REAR_RATE,
    S_MOTOR_LAG,
    S_SIGMA_KAPPA,
    S_C_F,
    S_C_R,
    S_MASS,
    S_IZ,
    S_A,
    S_B,
) = range(len(SETTINGS))

#: columns of a StabilityController's memory (B, M_WIDTH), one row per vehicle: the lagged yaw
#: reference [rad/s], the rear angle [rad], the moment the wheels deliver [N m] (LQR), the
#: previous reference [rad/s] (sliding mode) (NaN: no call yet); then the latest allocation
#: (torques (4) [N m], delivered yaw moment [N m] and drive force [N], feasible 1 / 0) and the
#: allocator's inputs of that call (for its error message): base torques (4), yaw moment, wheel
#: loads (4), friction (4), lateral forces (4), speed, front and rear steer
M_REFERENCE, M_REAR, M_DELIVERED, M_PREVIOUS_REF, M_TORQUES, M_MOMENT, M_FORCE, M_FEASIBLE = 0, 1, 2, 3, 4, 8, 9, 10
M_INPUTS = 11
M_WIDTH = M_INPUTS + 20


@register_jitable
def planning_friction(mu, mu_std, margin: float):
    """The friction a cautious controller plans with: the lower confidence bound mu - margin mu_std,
    stopping at MIN_PLANNING_MU (a friction already below it, ice, is kept); margin 0: mu as it
    is, whatever its sigma."""
    if margin == 0.0:
        return mu
    return np.maximum(mu - margin * mu_std, np.minimum(mu, MIN_PLANNING_MU))


@register_jitable
def deadband(x, width):
    """``x`` shrunk towards zero by ``width`` (zero inside the band, continuous outside)."""
    return np.sign(x) * np.maximum(np.abs(x) - width, 0.0)


@numba.njit(**JIT)
def stability_command(
    u,
    beta,
    r,
    ay,
    mu_hat,
    mu_std,
    fz,
    front,
    base,
    positions,
    peak_torque,
    peak_power,
    radius,
    settings,
    speeds,
    gains,
    law,
    memory,
) -> int:
    """One vehicle's step of :class:`control.StabilityController` (its docstring has the design):
    from the estimate (speed u [m/s], sideslip beta [rad], yaw rate r [rad/s], ay [m/s^2], per-wheel
    mu_hat, mu_std and loads fz [N] (4,)), the front road-wheel angle [rad] and the driver's base
    torques (4,) [N m]; the allocator's wheel positions and motor limits; ``settings``:
    :data:`SETTINGS`; ``speeds``, ``gains``: the LQR's table; ``law``:
    :meth:`SlidingModeYawController.terms`; ``memory`` (M_WIDTH,): the vehicle's row, updated
    (its rear angle and the allocation's torques are the command). Returns the allocator's
    status (0: fine)."""
    dt, margin = settings[S_DT], settings[S_MARGIN]
    mu = scratch((4,))
    for w in range(4):
        mu[w] = planning_friction(mu_hat[w], mu_std[w], margin)
    c_f, c_r, mass, iz, a, b = (
        settings[S_C_F],
        settings[S_C_R],
        settings[S_MASS],
        settings[S_IZ],
        settings[S_A],
        settings[S_B],
    )
    rear = 0.0
    if settings[S_REAR_STEER] != 0.0:  # eq. 20 at the servo's rate
        limit = settings[S_MAX_REAR]
        target = min(max(eq20_gain(u, a, b, mass, c_f, c_r) * front, -limit), limit)
        previous = 0.0 if math.isnan(memory[M_REAR]) else memory[M_REAR]
        step = settings[S_REAR_RATE] * dt
        rear = previous + min(max(target - previous, -step), step)
    memory[M_REAR] = rear
    # the 2-DOF steady state of the car as steered, bounded by the weaker axle's friction, lagged
    steady = steady_yaw_rate(
        u, front - rear, axle_friction(mu[0], mu[1], mu[2], mu[3]), settings[S_WHEELBASE], settings[S_UNDERSTEER]
    )
    reference = steady if math.isnan(memory[M_REFERENCE]) else memory[M_REFERENCE]
    reference = reference + (steady - reference) * min(dt / slower_time_constant(u, c_f, c_r, mass, iz, a, b), 1.0)
    memory[M_REFERENCE] = r_ref = reference
    mu_mean = (mu[0] + mu[1] + mu[2] + mu[3]) / 4.0
    bound = sideslip_bound_of(mu_mean)
    shrunk_error, shrunk_beta = deadband(r - r_ref, YAW_DEADBAND), deadband(beta, 0.5 * bound)
    if settings[S_SMC] != 0.0:
        moment = smc_moment(
            u, shrunk_beta, r_ref + shrunk_error, r_ref, front, rear, mu_mean, memory[M_PREVIOUS_REF], dt, law
        )
        memory[M_PREVIOUS_REF] = r_ref
    else:
        moment = lqr_moment(
            interpolated_gain(u, speeds, gains, 0),
            interpolated_gain(u, speeds, gains, 1),
            interpolated_gain(u, speeds, gains, 2),
            shrunk_beta,
            r_ref + shrunk_error,
            r_ref,
            memory[M_DELIVERED],
        )
    # a moment that turns the car further (understeer correction) fades out as |beta| approaches its bound
    if np.sign(moment) == np.sign(r_ref):
        moment = moment * min(max(1.0 - abs(beta) / bound, 0.0), 1.0)
    if not abs(u) > ACTIVE_SPEED:
        moment = 0.0
    base_in, fz_in, mu_in, lateral = scratch((1, 4)), scratch((1, 4)), scratch((1, 4)), scratch((1, 4))
    yaw, speed, front_in, rear_in = scratch((1,)), scratch((1,)), scratch((1,)), scratch((1,))
    for w in range(4):
        base_in[0, w], fz_in[0, w], mu_in[0, w] = base[w], fz[w], mu[w]
        lateral[0, w] = fz[w] * (ay / GRAVITY) if settings[S_ELLIPSE] != 0.0 else 0.0
    yaw[0], speed[0], front_in[0], rear_in[0] = moment, u, front, rear
    inputs = memory[M_INPUTS:]
    inputs[0:4], inputs[4], inputs[5:9], inputs[9:13] = base_in[0], moment, fz_in[0], mu_in[0]
    inputs[13:17], inputs[17], inputs[18], inputs[19] = lateral[0], u, front, rear
    torques, delivered, force, feasible = scratch((1, 4)), scratch((1,)), scratch((1,)), scratch((1,), np.bool_)
    bad = allocation_kernel(
        base_in,
        yaw,
        fz_in,
        mu_in,
        lateral,
        speed,
        front_in,
        rear_in,
        positions,
        peak_torque,
        peak_power,
        radius,
        torques,
        delivered,
        force,
        feasible,
    )
    if bad:
        return bad
    memory[M_TORQUES : M_TORQUES + 4] = torques[0]
    memory[M_MOMENT], memory[M_FORCE], memory[M_FEASIBLE] = delivered[0], force[0], 1.0 if feasible[0] else 0.0
    if settings[S_SMC] == 0.0:  # the LQR is told what the wheels now deliver
        lag = lag_time(u, settings[S_MOTOR_LAG], settings[S_SIGMA_KAPPA])
        memory[M_DELIVERED] = delivered_next(memory[M_DELIVERED], delivered[0], lag, dt)
    return 0


def allocation_inputs(row: np.ndarray) -> tuple[np.ndarray, ...]:
    """The allocator's eight inputs of a vehicle's last :func:`stability_command` (its memory row),
    as :func:`control.allocation.allocation_error` takes them."""
    inputs = row[M_INPUTS:]
    return (
        inputs[None, 0:4],
        inputs[4:5],
        inputs[None, 5:9],
        inputs[None, 9:13],
        inputs[None, 13:17],
        inputs[17:18],
        inputs[18:19],
        inputs[19:20],
    )


@numba.njit(**JIT)
def stability_commands(
    u,
    beta,
    r,
    ay,
    mu,
    mu_std,
    fz,
    front,
    base,
    moving,
    positions,
    peak_torque,
    peak_power,
    radius,
    settings,
    speeds,
    gains,
    law,
    memory,
) -> tuple[int, int]:
    """:func:`stability_command` for each vehicle selected by ``moving`` (B,) bool (rows (B,) or
    (B, 4)); returns (status, vehicle) of the first failure, (0, -1) if none."""
    for b in range(u.size):
        if not moving[b]:
            continue
        bad = stability_command(
            u[b],
            beta[b],
            r[b],
            ay[b],
            mu[b],
            mu_std[b],
            fz[b],
            front[b],
            base[b],
            positions,
            peak_torque,
            peak_power,
            radius,
            settings,
            speeds,
            gains,
            law,
            memory[b],
        )
        if bad:
            return bad, b
    return 0, -1

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
from typing import NamedTuple

import numba
import numpy as np
from numba.extending import register_jitable
from scipy.linalg import solve_continuous_are

from fourwis.control.allocation import Allocation, AllocationInputs, AllocatorLimits, allocation_kernel
from fourwis.control.reference import (
    GRAVITY,
    axle_friction,
    bicycle_state_matrix,
    eq20_gain,
    friction_limited,
    outside_stable_region,
    sideslip_bound_of,
    sideslip_moment,
    slower_time_constant,
)
from fourwis.core.kernels import JIT, bundle_dispatch, scratch
from fourwis.core.types import Estimate


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
    ``lag`` [s] behind it (the LQR's M, :class:`LQRYawController`)."""
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


class LqrLaw(NamedTuple):
    """The LQR as the compiled DYC step takes it: its gain table, gains (S, 3) on sideslip,
    yaw-rate error and delivered moment at the speeds (S,) [m/s]."""

    speeds: np.ndarray
    gains: np.ndarray


@dataclass
class LQRYawController:
    """Gain-scheduled LQR aware of the actuator's lag: Mz = -K(u) [beta, r - r_ref, M], with M the yaw
    moment the wheels deliver now (a first-order lag :func:`actuator_lag` behind what they were
    given: :func:`delivered_next`). K from the continuous Riccati equation of the 2-DOF model
    augmented with that lag, M_dot = (Mz - M) / tau(u), on a speed grid (3-45 m/s), interpolated
    linearly in u. The lag is in the design because without it the gains that suit 80 km/h leave
    the loop poorly damped and command, at low speed, moments the tyres cannot build up in time.
    The law is stateless: M is its caller's (:class:`fourwis.control.StabilityController`'s memory)
    (docs/decisions/0024-lag-aware-lqr.md)."""

    params: object
    weights: LQRWeights = field(default_factory=LQRWeights)
    speeds: np.ndarray = field(default_factory=lambda: np.linspace(3.0, 45.0, 43))

    def __post_init__(self) -> None:
        w = self.weights
        if min(w.beta, w.yaw_rate_error, w.yaw_moment) <= 0:
            raise ValueError(f"LQR weights must be > 0, got {w}")
        R = np.array([[1 / w.yaw_moment**2]])
        lag_terms = actuator_lag_terms(self.params)
        gains = []
        for u in self.speeds:
            A, B = bicycle_matrices(float(u), self.params)
            tau = float(actuator_lag(float(u), self.params, lag_terms))
            if tau > 0.0:  # states [beta, r, M], input the commanded moment
                A = np.block([[A, B], [np.zeros((1, 2)), np.full((1, 1), -1.0 / tau)]])
                B = np.array([[0.0], [0.0], [1.0 / tau]])
            Q = np.diag([1 / w.beta**2, 1 / w.yaw_rate_error**2, 0.0][: A.shape[0]])
            P = solve_continuous_are(A, B, Q, R)
            k = np.linalg.solve(R, B.T @ P)[0]
            gains.append(np.append(k, 0.0) if tau == 0.0 else k)
        self.gains = np.array(gains)  # (S, 3): on beta, r - r_ref and the delivered moment
        self.law = LqrLaw(np.ascontiguousarray(self.speeds, dtype=float), self.gains)

    def gain(self, u: np.ndarray) -> np.ndarray:
        """K(u): shape u.shape + (3,) (u scalar or any array of speeds [m/s])."""
        u = np.asarray(u, dtype=float)
        out = np.empty((u.size, 3))
        _interpolated_gains(np.ascontiguousarray(u).ravel(), self.speeds, self.gains, out)
        return out.reshape(u.shape + (3,))

    def moment(self, u, beta, r, r_ref, delivered=0.0) -> np.ndarray:
        """Mz [N m] at speed u [m/s], sideslip beta [rad], yaw rate r and its reference r_ref
        [rad/s] (arrays of one shape), with the wheels delivering ``delivered`` [N m] now; the
        steer angles enter through the reference only (pure state feedback)."""
        k = self.gain(u)
        return lqr_moment(k[..., 0], k[..., 1], k[..., 2], beta, r, r_ref, delivered)


class SmcLaw(NamedTuple):
    """The sliding mode as :func:`smc_moment` takes it: the 2-DOF model's axle cornering
    stiffnesses c_f, c_r [N/rad], CG to axle distances a, b [m], yaw inertia iz [kg m^2], mass m
    [kg], wheelbase [m], and the law's lam [-], eta [rad/s^2], phi [rad/s], max_moment [N m]."""

    c_f: float
    c_r: float
    a: float
    b: float
    iz: float
    m: float
    wheelbase: float
    lam: float
    eta: float
    phi: float
    max_moment: float


@dataclass
class SlidingModeYawController:
    """Sliding mode on s = (r - r_ref) - lam * beta (beta_ref = 0):
    Mz = I_z (r_ref_dot + lam beta_dot - f_r - eta sat(s / phi)) with f_r the 2-DOF yaw
    acceleration without Mz and beta_dot = (F_yf + F_yr) / (m u) - r; the boundary layer
    ``phi`` [rad/s] removes chattering (Slotine & Li 1991, ch. 7). ``lam`` weights sideslip
    into the surface with the sign of this car's LQR gain on beta (tested; a strongly
    understeering car's optimal gain can have the other sign): a car sliding out of a left turn
    (beta < 0) needs a clockwise moment, as a yaw rate above the reference does. ``lam`` >= 0
    [1/s], ``eta`` > 0 (the reaching rate) [rad/s^2], ``phi`` > 0, ``max_moment`` > 0 (the bound
    of |Mz|) [N m]; other values raise ValueError.

    The linear model's tyre forces grow without bound with slip; beyond the friction limit
    that would command large moments of the wrong sign. f_r therefore uses axle forces
    saturated at the estimated mu times the axle load (mu given per call). Even so it
    over-predicts a braked axle past its peak by more than ``eta``, so outside the boundary
    layer the equivalent control is dropped where it points away from the surface: the
    moment then always has the sign of -s there (reaching holds; Slotine & Li's condition
    needs eta above the model error, which this keeps from mattering). The law is stateless:
    the reference's previous value (for its rate) is its caller's
    (docs/decisions/0025-sliding-mode-guards.md)."""

    params: object
    lam: float = 0.5
    eta: float = 1.0
    phi: float = 0.05
    max_moment: float = 4000.0

    def __post_init__(self) -> None:
        for name in ("eta", "phi", "max_moment"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SlidingModeYawController.{name} must be > 0, got {getattr(self, name)!r}")
        if self.lam < 0:
            raise ValueError(f"lam must be >= 0, got {self.lam!r}")
        p = self.params
        c_f, c_r = p.axle_cornering_stiffness
        self.law = SmcLaw(
            float(c_f), float(c_r), float(p.cg_to_front), float(p.cg_to_rear), float(p.yaw_inertia), float(p.mass),
            float(p.wheelbase), float(self.lam), float(self.eta), float(self.phi), float(self.max_moment),
        )  # fmt: skip

    def moment(self, u, beta, r, r_ref, delta_f, delta_r, dt: float, mu=None, previous_ref=None) -> np.ndarray:
        """Mz [N m] at speed u [m/s], sideslip beta [rad], yaw rate r and reference r_ref [rad/s],
        front and rear road-wheel angles delta_f, delta_r [rad] (broadcast together), per-wheel
        mu (..., 4) (None: 1) and the reference ``previous_ref`` [rad/s] a step ``dt`` [s] before
        (None: no previous step, its rate is 0). ``beta`` as the StabilityController shrinks it:
        where it is exactly 0 (inside the sideslip deadband) it is held, so its rate in the
        equivalent control is 0 too (the linear model's beta_dot at beta = 0 is not 0 in a turn)."""
        u, beta, r, r_ref, delta_f, delta_r = np.broadcast_arrays(
            *(np.asarray(x, dtype=float) for x in (u, beta, r, r_ref, delta_f, delta_r))
        )
        mu_mean = np.ones_like(u) if mu is None else np.broadcast_to(np.sum(mu, axis=-1) / 4.0, u.shape)
        previous = np.full(u.shape, np.nan) if previous_ref is None else np.broadcast_to(previous_ref, u.shape)
        flat = (
            np.ascontiguousarray(x, dtype=float).ravel()
            for x in (u, beta, r, r_ref, delta_f, delta_r, mu_mean, previous)
        )
        moment = np.empty(u.size)
        _smc_moments(*flat, float(dt), self.law, moment)
        return moment.reshape(u.shape)


@numba.njit(inline="always", **JIT)
def smc_moment(u, beta, r, r_ref, delta_f, delta_r, mu_mean, previous_ref, dt, law: SmcLaw) -> float:
    """:class:`SlidingModeYawController`'s moment [N m] for one vehicle; ``previous_ref``: the
    reference at the previous call (NaN: none, its rate is then 0)."""
    c_f, c_r, a, b, iz, m, wheelbase, lam, eta, phi, max_moment = law
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
    # tyre's peak, under combined slip) by far more than the reaching rate eta, and cancelling
    # that phantom yaw acceleration would turn the moment against s (docs/decisions/0025-sliding-mode-guards.md)
    if abs(s) > phi and equivalent * s > 0.0:
        equivalent = 0.0
    mz = iz * (equivalent - eta * min(max(s / phi, -1.0), 1.0))
    return min(max(mz, -max_moment), max_moment)


@numba.njit(**JIT)
def _smc_moments(u, beta, r, r_ref, delta_f, delta_r, mu_mean, previous_ref, dt, law, out) -> None:
    for b in range(u.size):
        out[b] = smc_moment(u[b], beta[b], r[b], r_ref[b], delta_f[b], delta_r[b], mu_mean[b], previous_ref[b], dt, law)


ACTIVE_SPEED = 2.0  #: below this speed [m/s] the law's moment is zero (the allocator still shares the drive)
YAW_DEADBAND = 0.02  #: |r - r_ref| [rad/s] tolerated without intervention (ESC practice)
MIN_PLANNING_MU = 0.1  #: the margin's floor: it lowers no planning friction below this (nor lifts one)


class DycSettings(NamedTuple):
    """A :class:`fourwis.control.StabilityController`'s settings as its compiled step takes them:
    rear steer (eq. 20) on, friction ellipse on, the step dt [s], mu_margin [sigma], the
    reference's understeer gradient [rad s^2/m], wheelbase [m], the rear servo's range [rad] and
    rate [rad/s], the actuator lag's terms (:func:`actuator_lag_terms`: motor lag [s],
    sigma_kappa [m]) and the 2-DOF model's c_f, c_r [N/rad], mass [kg], yaw inertia [kg m^2],
    cg_to_front, cg_to_rear [m]."""

    rear_steer: bool
    friction_ellipse: bool
    dt: float
    mu_margin: float
    understeer: float
    wheelbase: float
    max_rear_steer: float
    rear_steer_rate: float
    motor_lag: float
    sigma_kappa: float
    c_f: float
    c_r: float
    mass: float
    yaw_inertia: float
    cg_to_front: float
    cg_to_rear: float


class DycMemory(NamedTuple):
    """A StabilityController's memory of B vehicles, one row each (NaN: no step yet): the yaw
    reference (B,) [rad/s] and its lagged steady state before the friction bound (B,) [rad/s], the
    rear road-wheel angle it commands (B,) [rad], the yaw moment
    the wheels deliver (B,) [N m] (the LQR's M), the reference at the previous step (B,) [rad/s]
    (the sliding mode's rate), the latest allocation (the command: its torques) and the
    allocator's inputs of that step (for its error message)."""

    reference: np.ndarray
    lagged: np.ndarray
    rear: np.ndarray
    delivered: np.ndarray
    previous_reference: np.ndarray
    allocation: Allocation
    inputs: AllocationInputs


def fresh_memory(batch: int) -> DycMemory:
    """A :class:`DycMemory` of ``batch`` vehicles before their first step (the wheels deliver no moment)."""

    def nan(*shape) -> np.ndarray:
        return np.full(shape, np.nan)

    return DycMemory(
        nan(batch), nan(batch), nan(batch), np.zeros(batch), nan(batch),
        Allocation(nan(batch, 4), nan(batch), nan(batch), np.zeros(batch, dtype=np.bool_)),
        AllocationInputs(nan(batch, 4), nan(batch), nan(batch, 4), nan(batch, 4), nan(batch, 4), nan(batch),
                         nan(batch), nan(batch), np.zeros(batch, dtype=np.bool_)),
    )  # fmt: skip


def clear_memory(memory: DycMemory, rows: np.ndarray) -> None:
    """Forget the vehicles ``rows`` (B,) bool of ``memory``, in place."""
    fresh = fresh_memory(1)
    for group, new in ((memory, fresh), (memory.allocation, fresh.allocation), (memory.inputs, fresh.inputs)):
        for field_now, field_new in zip(group, new):
            if isinstance(field_now, np.ndarray):
                field_now[rows] = field_new[0]


class DycKernel(NamedTuple):
    """A StabilityController as its compiled step (and the compiled closed loop) takes it."""

    settings: DycSettings
    limits: AllocatorLimits
    law: LqrLaw | SmcLaw
    memory: DycMemory


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


#: ``law_moment(law, b, u, beta, r_ref, error, front, rear, mu_mean, memory, dt) -> Mz``: the yaw
#: moment [N m] of ``law`` (:class:`LqrLaw` or :class:`SmcLaw`) for vehicle b at speed u, the
#: shrunk sideslip beta and yaw-rate error, the reference r_ref, the road-wheel angles and mean
#: planning friction, from its ``memory`` row (the LQR's delivered moment; the sliding mode's
#: previous reference, which it updates)
law_moment = bundle_dispatch("law_moment", "law, b, u, beta, r_ref, error, front, rear, mu_mean, memory, dt")
#: ``law_delivered(law, b, delivered, u, memory, settings)``: after the allocation, the LQR's
#: memory of the moment the wheels deliver follows the allocated ``delivered`` [N m] through the
#: actuator lag; the sliding mode keeps none
law_delivered = bundle_dispatch("law_delivered", "law, b, delivered, u, memory, settings")


@law_moment.register(LqrLaw)
def _lqr_law_moment(law, b, u, beta, r_ref, error, front, rear, mu_mean, memory, dt):
    speeds, gains = law
    return lqr_moment(
        interpolated_gain(u, speeds, gains, 0), interpolated_gain(u, speeds, gains, 1),
        interpolated_gain(u, speeds, gains, 2), beta, r_ref + error, r_ref, memory.delivered[b],
    )  # fmt: skip


@law_moment.register(SmcLaw)
def _smc_law_moment(law, b, u, beta, r_ref, error, front, rear, mu_mean, memory, dt):
    moment = smc_moment(u, beta, r_ref + error, r_ref, front, rear, mu_mean, memory.previous_reference[b], dt, law)
    memory.previous_reference[b] = r_ref
    return moment


@law_delivered.register(LqrLaw)
def _lqr_delivered(law, b, delivered, u, memory, settings):
    lag = lag_time(u, settings.motor_lag, settings.sigma_kappa)
    memory.delivered[b] = delivered_next(memory.delivered[b], delivered, lag, settings.dt)


@law_delivered.register(SmcLaw)
def _smc_delivered(law, b, delivered, u, memory, settings):
    pass


@numba.njit(**JIT)
def stability_command(dyc: DycKernel, b: int, estimate: Estimate, front: float, base: np.ndarray) -> int:
    """Vehicle b's step of :class:`fourwis.control.StabilityController` (its docstring has the
    design): from row b of the ``estimate`` (u, beta, r, ay, per-wheel mu, mu_std and fz), the
    front road-wheel angle [rad] and the driver's base torques (4,) [N m], into row b of the
    controller's memory, whose allocation's torques and rear angle are the command. Returns the
    allocator's status (0: fine)."""
    settings, memory = dyc.settings, dyc.memory
    dt, margin = settings.dt, settings.mu_margin
    u, beta, r, ay = estimate.u[b], estimate.beta[b], estimate.r[b], estimate.ay[b]
    mu = scratch((4,))
    for w in range(4):
        mu[w] = planning_friction(estimate.mu[b, w], estimate.mu_std[b, w], margin)
    c_f, c_r, mass, iz = settings.c_f, settings.c_r, settings.mass, settings.yaw_inertia
    a, b_rear = settings.cg_to_front, settings.cg_to_rear
    rear = 0.0
    if settings.rear_steer:  # eq. 20 at the servo's rate
        limit = settings.max_rear_steer
        target = min(max(eq20_gain(u, a, b_rear, mass, c_f, c_r) * front, -limit), limit)
        previous = 0.0 if math.isnan(memory.rear[b]) else memory.rear[b]
        step = settings.rear_steer_rate * dt
        rear = previous + min(max(target - previous, -step), step)
    memory.rear[b] = rear
    # the 2-DOF steady state of the car as steered, lagged like the car's yaw response, then bounded
    # by the weaker axle's friction (a grip the road no longer has is gone at once, not after the lag)
    steady = u * (front - rear) / (settings.wheelbase + settings.understeer * (u * u))
    lagged = steady if math.isnan(memory.lagged[b]) else memory.lagged[b]
    lagged = lagged + (steady - lagged) * min(dt / slower_time_constant(u, c_f, c_r, mass, iz, a, b_rear), 1.0)
    memory.lagged[b] = lagged
    memory.reference[b] = r_ref = friction_limited(lagged, u, axle_friction(mu[0], mu[1], mu[2], mu[3]))
    mu_mean = (mu[0] + mu[1] + mu[2] + mu[3]) / 4.0
    bound = sideslip_bound_of(mu_mean)
    shrunk_error, shrunk_beta = deadband(r - r_ref, YAW_DEADBAND), deadband(beta, 0.5 * bound)
    moment = law_moment(dyc.law, b, u, shrunk_beta, r_ref, shrunk_error, front, rear, mu_mean, memory, dt)
    # a moment that turns the car further (understeer correction) fades out as |beta| approaches its bound
    if np.sign(moment) == np.sign(r_ref):
        moment = moment * min(max(1.0 - abs(beta) / bound, 0.0), 1.0)
    unstable = abs(u) > ACTIVE_SPEED and outside_stable_region(r - r_ref, beta, bound)
    # inside the stable region a moment that drives the yaw rate away from its reference fades out as
    # the error grows to the deadband (a law's model-based terms must not undo the car's own response)
    if not unstable and moment * (r - r_ref) > 0.0:
        moment = moment * max(1.0 - abs(r - r_ref) / YAW_DEADBAND, 0.0)
    # beyond the stable region's sideslip the ESC's sideslip moment holds it (the 2-DOF law, linear
    # in a beta it sees well damped, hardly answers a car sliding on ice)
    moment += sideslip_moment(beta, bound)
    if not abs(u) > ACTIVE_SPEED:
        moment = 0.0
    inputs = memory.inputs
    for w in range(4):
        inputs.base_torques[b, w], inputs.fz[b, w], inputs.mu[b, w] = base[w], estimate.fz[b, w], mu[w]
        inputs.lateral[b, w] = estimate.fz[b, w] * (ay / GRAVITY) if settings.friction_ellipse else 0.0
    inputs.yaw_moment[b], inputs.speed[b], inputs.front_steer[b], inputs.rear_steer[b] = moment, u, front, rear
    inputs.stability_first[b] = unstable
    row = slice(b, b + 1)
    allocation = memory.allocation
    bad = allocation_kernel(
        AllocationInputs(
            inputs.base_torques[row], inputs.yaw_moment[row], inputs.fz[row], inputs.mu[row], inputs.lateral[row],
            inputs.speed[row], inputs.front_steer[row], inputs.rear_steer[row], inputs.stability_first[row],
        ),
        dyc.limits,
        Allocation(allocation.torques[row], allocation.yaw_moment[row], allocation.drive_force[row],
                   allocation.feasible[row]),
    )  # fmt: skip
    if bad:
        return bad
    law_delivered(dyc.law, b, allocation.yaw_moment[b], u, memory, settings)
    return 0


def inputs_row(inputs: AllocationInputs, b: int) -> AllocationInputs:
    """Row b of ``inputs`` as a batch of one (for :func:`fourwis.control.allocation.allocation_error`)."""
    return AllocationInputs(*(field[b : b + 1] for field in inputs))


@numba.njit(**JIT)
def stability_commands(dyc: DycKernel, estimate: Estimate, front: np.ndarray, base: np.ndarray) -> tuple[int, int]:
    """:func:`stability_command` for each vehicle (rows of ``estimate``, ``front`` (B,), ``base``
    (B, 4)); returns (status, vehicle) of the first failure, (0, -1) if none."""
    for b in range(front.size):
        bad = stability_command(dyc, b, estimate, front[b], base[b])
        if bad:
            return bad, b
    return 0, -1

"""Baselines every estimator is judged beside: what a filter must beat to be worth its model.

* ``baseline-kf``: a Kalman observer on the linear single-track (bicycle) model, states
  [v, r], inputs the axles' mean steer angles, measured [ay, r], the forward speed taken as
  measured (Rajamani, *Vehicle Dynamics and Control*, 2nd ed., sec. 2.3: the linear lateral
  model; the observer of Leanza, Reina and Blanco-Claraco, Sensors 21 (2021) 5409, built
  afresh);
* ``baseline-steady``: the steady-state single-track sideslip from the measured yaw rate,
  beta = r (b / u - m a u / (L C_r)) (the rear axle's slip in a steady turn, whose lateral force
  is m u r a / L);
* ``baseline-zero``: beta = 0.

Each reads the forward speed from the ``speed`` channel where it is valid, else from the mean
wheel-centre speed R omega of the four wheels; the steer angles from the per-wheel channels
(each axle's mean); the cornering stiffness of each axle from the estimation model's tyres at
the static loads (:attr:`ModelParams.axle_cornering_stiffness`), so a vehicle file's tyres
reach them as they reach the filters. They hold a nominal mu (mu_std 0) and report the normal
loads of the measured accelerations. All have the step interface of
:class:`fourwis.core.types.Estimator` and a :meth:`replay` of a whole log.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from fourwis.core.checks import check_step, is_number, member_rows
from fourwis.core.kernels import JIT
from fourwis.core.types import CH_AX, CH_AY, CH_DELTA, CH_OMEGA, CH_SPEED, CH_YAW_RATE, N_CHANNELS, Estimate
from fourwis.estimation.joint import CLOCK_TOLERANCE, I_R, I_V, MU_BOUNDS, NOISE_STEP, NoiseParams, empty_estimate
from fourwis.estimation.model import MIN_SPEED, ModelParams, normal_loads, substeps

BASELINES = ("baseline-kf", "baseline-steady", "baseline-zero")  #: the baselines' names (make_estimator)


def measured_speed(values: np.ndarray, valid: np.ndarray, wheel_radius: float) -> np.ndarray:
    """The forward speed (N,) [m/s] of readings (N, N_CHANNELS): the ``speed`` channel where valid,
    else the mean wheel-centre speed R omega of the four wheels."""
    wheels = values[:, CH_OMEGA : CH_OMEGA + 4].mean(axis=1) * wheel_radius
    return np.where(valid[:, CH_SPEED], values[:, CH_SPEED], wheels)


def axle_steer(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The front and rear axles' mean road-wheel steer angles (N,) [rad] of readings (N, N_CHANNELS)."""
    return values[:, CH_DELTA : CH_DELTA + 2].mean(axis=1), values[:, CH_DELTA + 2 : CH_DELTA + 4].mean(axis=1)


def steady_state_sideslip(yaw_rate, speed, params: ModelParams) -> np.ndarray:
    """The linear single-track model's steady-state sideslip [rad] at yaw rate [rad/s] and forward
    speed [m/s] (arrays; the speed floored at MIN_SPEED): beta = r (b / u - m a u / (L C_r))."""
    a, b, L = params.cg_to_front, params.cg_to_rear, params.wheelbase
    c_r = params.axle_cornering_stiffness[1]
    u = np.maximum(np.abs(speed), MIN_SPEED)
    return np.asarray(yaw_rate) * (b / u - params.mass * a * u / (L * c_r))


def _measurements(values, valid, held: np.ndarray) -> np.ndarray:
    """ax, ay, yaw rate (N, 3) of readings, each held at its last valid value (``held`` (N, 3),
    updated in place) where invalid."""
    channels = [CH_AX, CH_AY, CH_YAW_RATE]
    ok = valid[:, channels] & np.isfinite(values[:, channels])
    held[:] = np.where(ok, values[:, channels], held)
    return held.copy()


class _Memoryless:
    """A baseline that is a function of each reading (steady-state sideslip, beta = 0)."""

    needs_truth = False

    def __init__(self, params: ModelParams, dt: float = 0.002, nominal_mu: float = 0.8):
        self.params, self.dt = params, check_step(dt)
        if not (is_number(nominal_mu) and MU_BOUNDS[0] <= nominal_mu <= MU_BOUNDS[1]):
            raise ValueError(f"nominal_mu must lie in {MU_BOUNDS}, got {nominal_mu!r}")
        self.nominal_mu = float(nominal_mu)
        self._held: np.ndarray | None = None

    def sideslip(self, yaw_rate: np.ndarray, speed: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def reset(self, reading, initial_speed=None, mask: np.ndarray | None = None) -> None:
        """Start (or restart the rows of ``mask``) from a first reading (values (B, N_CHANNELS))."""
        values = np.asarray(reading.values, dtype=float)
        _check_shape(values)
        first = np.where(np.asarray(reading.valid)[:, [CH_AX, CH_AY, CH_YAW_RATE]], values[:, [0, 1, 2]], 0.0)
        first = np.where(np.isfinite(first), first, 0.0)
        if self._held is None or mask is None or len(self._held) != len(values):
            self._held = first
        else:
            self._held[mask] = first[mask]

    def _estimate(self, values: np.ndarray, valid: np.ndarray, held: np.ndarray) -> Estimate:
        measured = _measurements(values, valid, held)
        u = measured_speed(values, valid, self.params.wheel_radius)
        beta = self.sideslip(measured[:, 2], u)
        return _estimate(u, beta, measured, self.nominal_mu, self.params, np.zeros(len(u)))

    def step(self, reading, truth: Estimate | None = None, members=None) -> Estimate:
        """The baseline of the rows ``members`` (all if None) of ``reading``."""
        if self._held is None:
            raise RuntimeError("call reset(first_reading, initial_speed) before the first step")
        values, valid = np.asarray(reading.values, dtype=float), np.asarray(reading.valid, dtype=bool)
        _check_shape(values)
        rows = member_rows(members, len(values))
        held = self._held[rows]
        out = self._estimate(values[rows], valid[rows], held)
        self._held[rows] = held
        return out

    def replay(self, values, valid, t, initial_speed) -> Estimate:
        """A whole log (values, valid (T, N_CHANNELS)) at once: the estimate fields (T, 1) (per
        wheel (T, 1, 4)), as :meth:`StateEstimator.replay` records them."""
        values, valid = np.asarray(values, dtype=float), np.asarray(valid, dtype=bool)
        _check_shape(values)
        channels = [CH_AX, CH_AY, CH_YAW_RATE]
        ok = valid[:, channels] & np.isfinite(values[:, channels])
        measured = _hold_forward(np.where(ok, values[:, channels], np.nan))
        u = measured_speed(values, valid, self.params.wheel_radius)
        out = _estimate(u, self.sideslip(measured[:, 2], u), measured, self.nominal_mu, self.params, np.zeros(len(u)))
        return Estimate(*(field[:, None] for field in out))


def _hold_forward(x: np.ndarray) -> np.ndarray:
    """Each column of x (T, n) with its NaN held at the last finite value (0 before the first)."""
    x = x.copy()
    for c in range(x.shape[1]):
        column = x[:, c]
        good = np.isfinite(column)
        index = np.where(good, np.arange(len(column)), 0)
        np.maximum.accumulate(index, out=index)
        column[:] = np.where(good[index], column[index], 0.0)
    return x


class SteadyStateSideslip(_Memoryless):
    """``baseline-steady``: the single-track steady-state sideslip of the measured yaw rate
    (:func:`steady_state_sideslip`)."""

    def sideslip(self, yaw_rate, speed):
        return steady_state_sideslip(yaw_rate, speed, self.params)


class ZeroSideslip(_Memoryless):
    """``baseline-zero``: no sideslip at all (v = 0)."""

    def sideslip(self, yaw_rate, speed):
        return np.zeros_like(np.asarray(yaw_rate, dtype=float))


def _estimate(u, beta, measured, nominal_mu, params, beta_std) -> Estimate:
    """An Estimate of rows of forward speed u, sideslip beta (with v = u tan beta), the measured
    (N, 3) ax, ay, yaw rate, a nominal mu and the normal loads of ax, ay."""
    n = len(u)
    v = np.abs(u) * np.tan(beta)
    return Estimate(
        u=np.asarray(u, float),
        v=v,
        beta=np.arctan2(v, np.maximum(np.abs(u), MIN_SPEED)),
        r=measured[:, 2].copy(),
        ax=measured[:, 0].copy(),
        ay=measured[:, 1].copy(),
        mu=np.full((n, 4), nominal_mu),
        fz=normal_loads(measured[:, 0], measured[:, 1], params),
        beta_std=np.asarray(beta_std, float),
        mu_std=np.zeros((n, 4)),
    )


def _check_shape(values: np.ndarray) -> None:
    if values.ndim != 2 or values.shape[1] != N_CHANNELS:
        raise ValueError(f"sensor reading must have shape (B, {N_CHANNELS}), got {values.shape}")


# ---- the linear single-track Kalman observer -----------------------------------------------
class LinearModel(NamedTuple):
    """The linear single-track model's constants: mass [kg], yaw inertia [kg m^2], CG to the axles
    a, b [m], the axles' cornering stiffness C_f, C_r [N/rad]."""

    mass: float
    yaw_inertia: float
    a: float
    b: float
    c_f: float
    c_r: float


@numba.njit(inline="always", **JIT)
def _derivative(m: LinearModel, u: float, v: float, r: float, delta_f: float, delta_r: float) -> tuple:
    """(v_dot, r_dot, ay) of the linear single-track model at forward speed u [m/s] (floored at
    MIN_SPEED): axle forces C (delta - slip of the axle's centre)."""
    u = max(abs(u), MIN_SPEED)
    f_front = m.c_f * (delta_f - (v + m.a * r) / u)
    f_rear = m.c_r * (delta_r - (v - m.b * r) / u)
    ay = (f_front + f_rear) / m.mass
    return ay - u * r, (m.a * f_front - m.b * f_rear) / m.yaw_inertia, ay


@numba.njit(**JIT)
def _kf_step(m, x, P, q, R, u, delta_f, delta_r, z, valid, dt) -> float:
    """One step of the observer on x = [v, r] (2,) and P (2, 2), in place: Euler substeps of at most
    MODEL_STEP over ``dt`` [s] (covariance through I + h A, process noise q (2,) per NOISE_STEP
    scaled by h), then the update by the measured [ay, r] ``z`` (2,) with variances R (2,) on the
    ``valid`` (2,) channels (sequential scalar updates: the noise is diagonal). Returns the
    innovation NLL."""
    n = substeps(dt)
    h = dt / n
    uu = max(abs(u), MIN_SPEED)
    # A = d(v_dot, r_dot)/d(v, r), constant over the step
    a11 = -(m.c_f + m.c_r) / (m.mass * uu)
    a12 = -(m.a * m.c_f - m.b * m.c_r) / (m.mass * uu) - uu
    a21 = -(m.a * m.c_f - m.b * m.c_r) / (m.yaw_inertia * uu)
    a22 = -(m.a * m.a * m.c_f + m.b * m.b * m.c_r) / (m.yaw_inertia * uu)
    for _ in range(n):
        v_dot, r_dot, _ay = _derivative(m, u, x[0], x[1], delta_f, delta_r)
        x[0] += h * v_dot
        x[1] += h * r_dot
        f11, f12, f21, f22 = 1.0 + h * a11, h * a12, h * a21, 1.0 + h * a22
        p11, p12, p22 = P[0, 0], P[0, 1], P[1, 1]
        n11 = f11 * (f11 * p11 + f12 * p12) + f12 * (f11 * p12 + f12 * p22) + q[0] * h / NOISE_STEP
        n12 = f21 * (f11 * p11 + f12 * p12) + f22 * (f11 * p12 + f12 * p22)
        n22 = f21 * (f21 * p11 + f22 * p12) + f22 * (f21 * p12 + f22 * p22) + q[1] * h / NOISE_STEP
        P[0, 0], P[0, 1], P[1, 0], P[1, 1] = n11, n12, n12, n22
    nll = 0.0
    for k in range(2):
        if not valid[k]:
            continue
        # the measurement row H: ay = c1 v + c2 r + (steer terms), r = r
        if k == 0:
            h1, h2 = -(m.c_f + m.c_r) / (m.mass * uu), -(m.a * m.c_f - m.b * m.c_r) / (m.mass * uu)
            predicted = _derivative(m, u, x[0], x[1], delta_f, delta_r)[2]
        else:
            h1, h2 = 0.0, 1.0
            predicted = x[1]
        ph1 = P[0, 0] * h1 + P[0, 1] * h2
        ph2 = P[0, 1] * h1 + P[1, 1] * h2
        s = h1 * ph1 + h2 * ph2 + R[k]
        if not s > 0.0:
            return math.nan
        nu = z[k] - predicted
        g1, g2 = ph1 / s, ph2 / s
        x[0] += g1 * nu
        x[1] += g2 * nu
        P[0, 0] -= g1 * ph1
        P[0, 1] -= g1 * ph2
        P[1, 1] -= g2 * ph2
        P[1, 0] = P[0, 1]
        nll += 0.5 * (nu * nu / s + math.log(s) + math.log(2.0 * math.pi))
    return nll


@numba.njit(**JIT)
def _kf_run(m, x, P, held, t_prev, q, R, nominal_dt, u, delta_f, delta_r, values, valid, t, x_out, std_out):
    """The observer of one car through readings (N, N_CHANNELS) at times t (N,) (NaN: a nominal
    step) with speeds u and axle steer (N,): the held-sample rule of the filters (a measurement
    identical to the previous one counts once), x_out (N, 2) and the sideslip sigma [rad]
    std_out (N,). ``held`` (2,): the last valid ay, r; ``t_prev`` (1,) the last time. Returns the
    first failing row, or -1."""
    z, ok = np.empty(2), np.empty(2, dtype=np.bool_)
    for k in range(values.shape[0]):
        dt = nominal_dt
        if math.isfinite(t[k]) and math.isfinite(t_prev[0]):
            elapsed = t[k] - t_prev[0]
            if elapsed < 0.0:
                return k
            if elapsed > 0.0 and abs(elapsed - dt) > CLOCK_TOLERANCE * dt:
                dt = elapsed
        for i in range(2):
            c = CH_AY if i == 0 else CH_YAW_RATE
            z[i] = values[k, c]
            ok[i] = valid[k, c] and math.isfinite(z[i]) and z[i] != held[i]
            if valid[k, c] and math.isfinite(z[i]):
                held[i] = z[i]
        nll = _kf_step(m, x, P, q, R, u[k], delta_f[k], delta_r[k], z, ok, dt)
        if not math.isfinite(nll):
            return k
        if math.isfinite(t[k]):
            t_prev[0] = t[k]
        x_out[k, 0], x_out[k, 1] = x[0], x[1]
        std_out[k] = math.sqrt(max(P[0, 0], 0.0)) / max(abs(u[k]), MIN_SPEED)
    return -1


class LinearSingleTrackKF:
    """``baseline-kf``: the Kalman observer on the linear single-track model (module docstring),
    in the filters' hand-set noise: the process noise of v and r and the ay and gyro noise of
    ``noise`` (:class:`NoiseParams`, per NOISE_STEP and per sample as there), started from v = 0
    and the measured yaw rate with the state filters' initial sigmas of v and r."""

    needs_truth = False

    def __init__(self, params: ModelParams, dt: float = 0.002, noise: NoiseParams | None = None, nominal_mu=0.8):
        self.params, self.dt = params, check_step(dt)
        if not (is_number(nominal_mu) and MU_BOUNDS[0] <= nominal_mu <= MU_BOUNDS[1]):
            raise ValueError(f"nominal_mu must lie in {MU_BOUNDS}, got {nominal_mu!r}")
        self.nominal_mu = float(nominal_mu)
        self.noise = noise or NoiseParams()
        if np.ndim(self.noise.process_std) != 1 or np.ndim(self.noise.ay_std) or np.ndim(self.noise.gyro_std):
            raise ValueError("baseline-kf takes one noise for the batch (no per-member noise)")
        process = np.square(np.asarray(self.noise.process_std, dtype=float))
        self._q = np.array([process[I_V], process[I_R]])
        self._R = np.square(np.array([self.noise.ay_std, self.noise.gyro_std], dtype=float))
        c_f, c_r = params.axle_cornering_stiffness
        self._model = LinearModel(
            float(params.mass), float(params.yaw_inertia), float(params.cg_to_front), float(params.cg_to_rear), c_f, c_r
        )
        self._state = None

    def reset(self, reading, initial_speed=None, mask: np.ndarray | None = None) -> None:
        """Start (or restart the rows of ``mask``) from a first reading: v = 0, r measured."""
        values = np.asarray(reading.values, dtype=float)
        _check_shape(values)
        B = len(values)
        valid = np.asarray(reading.valid, dtype=bool)
        r0 = np.where(valid[:, CH_YAW_RATE] & np.isfinite(values[:, CH_YAW_RATE]), values[:, CH_YAW_RATE], 0.0)
        x = np.stack([np.zeros(B), r0], axis=1)
        P = np.broadcast_to(np.diag([0.3, 0.02]) ** 2, (B, 2, 2)).copy()
        held = np.full((B, 2), np.nan)
        fresh = [x, P, held, np.full((B, 1), np.nan), _held_accelerations(values, valid)]
        if self._state is None or mask is None or len(self._state[0]) != B:
            self._state = fresh
        else:
            for old, new in zip(self._state, fresh):
                old[mask] = new[mask]

    def _run(self, b: int, values, valid, t) -> tuple[np.ndarray, np.ndarray]:
        x, P, held, t_prev, _ = self._state
        u = measured_speed(values, valid, self.params.wheel_radius)
        delta_f, delta_r = axle_steer(values)
        x_out, std_out = np.empty((len(values), 2)), np.empty(len(values))
        row = (x[b], P[b], held[b], t_prev[b])
        failed = _kf_run(
            self._model, *row, self._q, self._R, self.dt, u, delta_f, delta_r,
            np.ascontiguousarray(values), np.ascontiguousarray(valid), np.ascontiguousarray(t, dtype=float),
            x_out, std_out,
        )  # fmt: skip
        if failed >= 0:
            raise ValueError(
                f"baseline-kf at sample {failed}: the time {float(t[failed])!r} s is before the previous one, "
                "or its innovation variance is not positive"
            )
        return x_out, std_out

    def step(self, reading, truth: Estimate | None = None, members=None) -> Estimate:
        """One step of the rows ``members`` (all if None) of ``reading`` (times ``t`` (B,) or empty)."""
        if self._state is None:
            raise RuntimeError("call reset(first_reading, initial_speed) before the first step")
        values, valid = np.asarray(reading.values, dtype=float), np.asarray(reading.valid, dtype=bool)
        _check_shape(values)
        rows = member_rows(members, len(values))
        t = np.asarray(getattr(reading, "t", None) if getattr(reading, "t", None) is not None else [], float)
        out = empty_estimate(len(rows))
        for j, b in enumerate(rows):
            time = t[b : b + 1] if t.size else np.full(1, np.nan)
            x_out, std = self._run(int(b), values[b : b + 1], valid[b : b + 1], time)
            measured = _measurements(values[b : b + 1], valid[b : b + 1], self._state[4][b : b + 1])
            u = measured_speed(values[b : b + 1], valid[b : b + 1], self.params.wheel_radius)
            one = _estimate(u, np.arctan2(x_out[:, 0], np.maximum(np.abs(u), MIN_SPEED)), measured, self.nominal_mu,
                            self.params, std)  # fmt: skip
            one = one._replace(r=x_out[:, 1])
            for target, value in zip(out, one):
                target[j] = value[0]
        return out

    def replay(self, values, valid, t, initial_speed) -> Estimate:
        """A whole log from a reset on its first reading: the estimate fields (T, 1) (per wheel (T, 1, 4))."""
        values, valid = np.asarray(values, dtype=float), np.asarray(valid, dtype=bool)
        self.reset(_Reading(values[:1], valid[:1]), initial_speed)
        x_out, std = self._run(0, values, valid, np.asarray(t, dtype=float))
        channels = [CH_AX, CH_AY, CH_YAW_RATE]
        ok = valid[:, channels] & np.isfinite(values[:, channels])
        measured = _hold_forward(np.where(ok, values[:, channels], np.nan))
        u = measured_speed(values, valid, self.params.wheel_radius)
        out = _estimate(u, np.arctan2(x_out[:, 0], np.maximum(np.abs(u), MIN_SPEED)), measured, self.nominal_mu,
                        self.params, std)  # fmt: skip
        return Estimate(*(field[:, None] for field in out._replace(r=x_out[:, 1])))


class _Reading(NamedTuple):
    values: np.ndarray
    valid: np.ndarray


def _held_accelerations(values, valid) -> np.ndarray:
    """The first reading's ax, ay, yaw rate (B, 3), 0 where invalid."""
    first = values[:, [CH_AX, CH_AY, CH_YAW_RATE]]
    return np.where(valid[:, [CH_AX, CH_AY, CH_YAW_RATE]] & np.isfinite(first), first, 0.0)


def make_baseline(name: str, params: ModelParams, dt: float = 0.002, noise=None, nominal_mu: float = 0.8):
    """The baseline ``name`` of :data:`BASELINES` for the estimation model ``params`` at step ``dt`` [s]."""
    if name == "baseline-kf":
        return LinearSingleTrackKF(params, dt, noise, nominal_mu)
    if noise is not None:
        raise ValueError(f"{name} takes no noise: it is a function of each reading")
    if name == "baseline-steady":
        return SteadyStateSideslip(params, dt, nominal_mu)
    if name == "baseline-zero":
        return ZeroSideslip(params, dt, nominal_mu)
    raise ValueError(f"unknown baseline {name!r}; known: {list(BASELINES)}")


__all__ = [
    "BASELINES",
    "LinearSingleTrackKF",
    "SteadyStateSideslip",
    "ZeroSideslip",
    "make_baseline",
    "measured_speed",
    "steady_state_sideslip",
]

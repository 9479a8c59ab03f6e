"""Upper-layer references: desired yaw rate, sideslip bound, the sideslip phase-plane stability
region, and the paper's 4WS law.

Vehicle parameters are duck-typed (a VehicleParams-like object: mass, yaw_inertia,
cg_to_front, cg_to_rear, wheelbase, axle_cornering_stiffness, max_rear_steer).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from importlib import resources

import numba
import numpy as np
from numba.extending import register_jitable

from fourwis.core.constants import GRAVITY
from fourwis.core.kernels import JIT

FRICTION_USE = 0.85  #: share of mu*g the reference may ask for (Rajamani 2012, sec. 8.5)
MIN_SPEED = 1.0  #: speed floor in divisions [m/s]
MAX_YAW_TIME_CONSTANT = 0.5  #: cap of yaw_time_constant [s] (this car: 0.25 s at 40 m/s)


def understeer_gradient(params) -> float:
    """K_us = (m / L) (b / C_f - a / C_r) [rad s^2/m] of the linear 2-DOF model (per-axle
    stiffnesses); zero for this car (a = b, equal tyres): neutral steer."""
    c_f, c_r = params.axle_cornering_stiffness
    return params.mass / params.wheelbase * (params.cg_to_rear / c_f - params.cg_to_front / c_r)


def reference_yaw_rate(
    u: np.ndarray, delta_f: np.ndarray, mu: np.ndarray, params, understeer: float | None = None
) -> np.ndarray:
    """Desired yaw rate (B,) [rad/s]: the 2-DOF steady state u delta / (L + K_us u^2), bounded by
    the friction limit 0.85 mu g / u with mu the mean of the estimated per-wheel mu (B, 4)
    (:func:`steady_yaw_rate`).

    ``understeer`` [rad s^2/m]: K_us; None takes the car's own, floored at 0 (neutral): an
    oversteering car's steady state has no bound at its critical speed sqrt(L / -K_us) and
    turns against the steering above it, which no reference should ask for."""
    k = max(understeer_gradient(params), 0.0) if understeer is None else understeer
    return steady_yaw_rate(np.asarray(u, dtype=float), delta_f, np.mean(mu, axis=-1), params.wheelbase, k)


@register_jitable
def steady_yaw_rate(u, delta_f, mu_mean, wheelbase: float, understeer: float):
    """:func:`reference_yaw_rate` from the mean friction ``mu_mean``, the wheelbase [m] and the
    gradient K_us [rad s^2/m] (written once, for numpy arrays and for the compiled controller)."""
    return friction_limited(u * delta_f / (wheelbase + understeer * (u * u)), u, mu_mean)


@register_jitable
def friction_limited(yaw_rate, u, mu_mean):
    """``yaw_rate`` [rad/s] within the friction limit 0.85 mu_mean g / u at speed ``u`` [m/s]."""
    limit = FRICTION_USE * mu_mean * GRAVITY / np.maximum(np.abs(u), MIN_SPEED)
    return np.minimum(np.maximum(yaw_rate, -limit), limit)


def bicycle_state_matrix(u, params) -> tuple:
    """Entries (a11, a12, a21, a22) of the linear 2-DOF model's state matrix for [beta, r] at
    speed ``u`` [m/s] (scalar or (B,)), per-axle stiffnesses (Rajamani 2012, sec. 2.3):
    beta_dot = a11 beta + a12 r, r_dot = a21 beta + a22 r (plus the steer and moment inputs)."""
    return bicycle_entries(u, *bicycle_terms(params))


def bicycle_terms(params) -> tuple[float, ...]:
    """(C_f, C_r [N/rad], m [kg], I_z [kg m^2], a, b [m]) of duck-typed vehicle ``params``, as
    :func:`bicycle_entries` and :func:`slower_time_constant` take them."""
    c_f, c_r = params.axle_cornering_stiffness
    return (
        float(c_f),
        float(c_r),
        float(params.mass),
        float(params.yaw_inertia),
        float(params.cg_to_front),
        float(params.cg_to_rear),
    )


@register_jitable
def bicycle_entries(u, c_f: float, c_r: float, m: float, iz: float, a: float, b: float) -> tuple:
    """:func:`bicycle_state_matrix` from the axle stiffnesses, mass, yaw inertia and CG position."""
    return (
        -(c_f + c_r) / (m * u),
        (b * c_r - a * c_f) / (m * (u * u)) - 1.0,
        (b * c_r - a * c_f) / iz,
        -(a * a * c_f + b * b * c_r) / (iz * u),
    )


def yaw_time_constant(u: np.ndarray, params) -> np.ndarray:
    """Time constant (B,) [s] of the linear 2-DOF model's slower mode at speed u [m/s]:
    -1 / max Re(eig A(u)) (:func:`bicycle_state_matrix`), from the 2 x 2 matrix's trace
    and determinant. The car answers a steering input this fast: ~0.036 s at 20 km/h and 0.16 s
    at 90 km/h on this car (the time constant grows with speed, as the model's damping falls).
    At most MAX_YAW_TIME_CONSTANT: an oversteering car near or above its critical speed has a
    slow or unstable mode, which no reference should follow."""
    return slower_time_constant(np.asarray(u, dtype=float), *bicycle_terms(params))


@register_jitable
def slower_time_constant(u, c_f: float, c_r: float, m: float, iz: float, a: float, b: float):
    """:func:`yaw_time_constant` from :func:`bicycle_terms`."""
    a11, a12, a21, a22 = bicycle_entries(np.maximum(np.abs(u), MIN_SPEED), c_f, c_r, m, iz, a, b)
    half_trace, det = 0.5 * (a11 + a22), a11 * a22 - a12 * a21
    slower = half_trace + np.sqrt(np.maximum(half_trace * half_trace - det, 0.0))  # the slower eigenvalue's real part
    return 1.0 / np.maximum(-slower, 1.0 / MAX_YAW_TIME_CONSTANT)


def weaker_axle_friction(mu: np.ndarray) -> np.ndarray:
    """Friction (B,) that bounds the car's steady lateral acceleration, from per-wheel mu (B, 4)
    (FL, FR, RL, RR): the lower of the two axles' means. In a steady turn each axle carries its
    share of m a_y (front b / L, rear a / L, in proportion to its static load), so the axle that
    saturates first sets the limit (Milliken & Milliken, Race Car Vehicle Dynamics, 1995, ch. 5);
    the mean of the four wheels overstates it where the axles stand on different surfaces (a
    car's front axle on a patch its rear axle has not reached), and equals it on a uniform road
    or one split left / right (docs/decisions/0023-yaw-reference.md)."""
    mu = np.asarray(mu, dtype=float)
    return axle_friction(mu[..., 0], mu[..., 1], mu[..., 2], mu[..., 3])


@register_jitable
def axle_friction(front_left, front_right, rear_left, rear_right):
    """:func:`weaker_axle_friction` of the four wheels' friction."""
    return np.minimum(0.5 * (front_left + front_right), 0.5 * (rear_left + rear_right))


def sideslip_bound(mu: np.ndarray) -> np.ndarray:
    """Largest acceptable |beta| (B,) [rad]: atan(0.02 mu g), 11 deg at mu 1, 3.4 deg at 0.3 (snow),
    1.1 deg at 0.1 (ice) (the mu-dependent bound of ESC practice; van Zanten, SAE 2000-01-1633),
    mu the mean of the per-wheel friction (B, 4)."""
    return sideslip_bound_of(np.mean(mu, axis=-1))


@register_jitable
def sideslip_bound_of(mu_mean):
    """:func:`sideslip_bound` of the mean friction."""
    return np.arctan(0.02 * mu_mean * GRAVITY)


#: the car is outside its stable region when its yaw rate misses the reference by more than
#: STABLE_YAW_ERROR [rad/s] (4 deg/s) or its sideslip exceeds STABLE_SIDESLIP times the sideslip
#: bound (a production ESC's entry thresholds: van Zanten, SAE 2000-01-1633, enters at a few deg/s
#: of yaw-rate error, and on sideslip before the bound)
STABLE_YAW_ERROR = 0.07
STABLE_SIDESLIP = 0.6


@register_jitable
def outside_stable_region(yaw_rate_error, beta, bound):
    """Whether a car with yaw-rate error ``yaw_rate_error`` = r - r_ref [rad/s] and sideslip ``beta``
    [rad] is outside its stable region, given the sideslip bound ``bound`` [rad]
    (:func:`sideslip_bound`): the test that switches an ESC on and puts a yaw moment before the
    driver's drive force in the allocation (scalars or arrays of one shape)."""
    return (np.abs(yaw_rate_error) > STABLE_YAW_ERROR) | (np.abs(beta) > STABLE_SIDESLIP * bound)


#: moment per rad of sideslip beyond STABLE_SIDESLIP x the bound [N m/rad] (:func:`sideslip_moment`)
SIDESLIP_GAIN = 4.0e4


@register_jitable
def sideslip_moment(beta, bound):
    """The yaw moment [N m] (counter-clockwise positive) that holds the sideslip ``beta`` [rad] within
    STABLE_SIDESLIP times its ``bound`` [rad]: SIDESLIP_GAIN times the sideslip beyond that, zero
    within it (a car sliding out of a left turn, beta < 0, is turned clockwise)."""
    limit = STABLE_SIDESLIP * bound
    return SIDESLIP_GAIN * (beta - np.minimum(np.maximum(beta, -limit), limit))


def sideslip_rate(u: np.ndarray, v: np.ndarray, r: np.ndarray, ax: np.ndarray, ay: np.ndarray) -> np.ndarray:
    """beta_dot [rad/s] of beta = atan(v / u) from the body's specific forces ax = u_dot - v r and
    ay = v_dot + u r [m/s^2]: (u v_dot - v u_dot) / (u^2 + v^2) = (u (ay - u r) - v (ax + v r)) /
    (u^2 + v^2), exact (u floored at MIN_SPEED). No derivative of a noisy signal: it needs only
    what an estimator reports."""
    u = np.maximum(np.abs(u), MIN_SPEED)
    return (u * (ay - u * r) - v * (ax + v * r)) / (u**2 + v**2)


@dataclass(frozen=True)
class PhasePlaneRegion:
    """Sideslip phase-plane stability region |beta_dot + c1 beta| <= c2 (Inagaki, Kushiro and Yamamoto,
    AVEC '94; the band form of He et al., Proc. IMechE D 220, 2006) within the yaw-rate window |r|
    <= k mu g / u it was derived over (k = ``yaw_rate_window``; the band alone, an unbounded strip,
    reaches spinning states beyond it): inside, the car returns to straight running by itself with
    the steering straight (on the 2-DOF model it was derived on; the full plant is checked in the
    tests). Slope c1 [1/s] and half-width c2 [rad/s] tabulated over speed [m/s] x road friction,
    interpolated bilinearly and clamped to the table's range. The shipped table is this car's
    (derived by ``python -m fourwis.training.phase_plane_fit``; Inagaki et al.'s dry-road numbers, c1 = 2.49
    1/s and c2 = 9.55 deg/s, are their car's); :meth:`default` loads it. For another car:
    ``PhasePlaneRegion.from_table(fourwis.training.phase_plane_fit.fit_table(params))`` (~3.5 min)."""

    speeds: tuple[float, ...]
    frictions: tuple[float, ...]
    slope: tuple[tuple[float, ...], ...]  #: c1 (speeds x frictions) [1/s]
    bound: tuple[tuple[float, ...], ...]  #: c2 (speeds x frictions) [rad/s]
    yaw_rate_window: float = 3.0  #: k of the window |r| <= k mu g / u

    def __post_init__(self) -> None:
        for name in ("speeds", "frictions"):
            axis = np.asarray(getattr(self, name), dtype=float)
            if axis.ndim != 1 or axis.size < 2 or not np.all(np.isfinite(axis)) or np.any(np.diff(axis) <= 0):
                raise ValueError(
                    f"PhasePlaneRegion.{name} must be at least two increasing finite values, "
                    f"got {getattr(self, name)!r}"
                )
        shape = (len(self.speeds), len(self.frictions))
        for name in ("slope", "bound"):
            grid = np.asarray(getattr(self, name), dtype=float)
            if grid.shape != shape or not np.all(np.isfinite(grid)) or (name == "bound" and np.any(grid <= 0)):
                raise ValueError(
                    f"PhasePlaneRegion.{name} must be a finite {shape} table"
                    + (" of values > 0" if name == "bound" else "")
                    + f", got shape {grid.shape}"
                )

    @staticmethod
    def from_table(table: dict) -> PhasePlaneRegion:
        """From the layout of control/data/phase_plane.json, which
        ``fourwis.training.phase_plane_fit.fit_table(params)`` returns for any car."""
        return PhasePlaneRegion(
            tuple(table["speeds_m_s"]),
            tuple(table["frictions"]),
            tuple(map(tuple, table["slope_1_s"])),
            tuple(map(tuple, table["bound_rad_s"])),
            float(table["yaw_rate_window"]),
        )

    @staticmethod
    @functools.cache
    def default() -> PhasePlaneRegion:
        """The region of the default car (control/data/phase_plane.json)."""
        return PhasePlaneRegion.from_table(
            json.loads(resources.files("fourwis.control").joinpath("data/phase_plane.json").read_text())
        )

    @functools.cached_property
    def _grids(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(speeds, frictions, stacked (slope, bound) (2, S, F)) as arrays."""
        return (
            np.asarray(self.speeds, dtype=float),
            np.asarray(self.frictions, dtype=float),
            np.stack([self.slope, self.bound]).astype(float),
        )

    def coefficients(self, u: np.ndarray, mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(c1 [1/s], c2 [rad/s]) at speeds ``u`` (B,) [m/s] and per-wheel friction ``mu`` (B, 4) (its mean)."""
        return self._at(u, mu)[:2]

    def _at(self, u: np.ndarray, mu: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(c1, c2, u, mean mu) (B,) each, the inputs checked and as float arrays."""
        u = np.ascontiguousarray(np.atleast_1d(np.asarray(u, dtype=float)))
        mu_mean = np.ascontiguousarray(np.atleast_1d(np.mean(mu, axis=-1)), dtype=float)
        if u.ndim != 1 or mu_mean.shape != u.shape:
            raise ValueError(f"u must have shape (B,) and mu (B, 4); got u {u.shape}, mu {np.shape(mu)}")
        out = np.empty((2, u.size))
        _bilinear(*self._grids, u, mu_mean, out)
        return out[0], out[1], u, mu_mean

    def index(
        self, u: np.ndarray, beta: np.ndarray, beta_rate: np.ndarray, r: np.ndarray, mu: np.ndarray
    ) -> np.ndarray:
        """max(|beta_dot + c1 beta| / c2, |r| / (k mu g / u)) (B,): below 1 inside the region,
        above 1 outside. ``u`` [m/s], ``beta`` [rad], ``beta_rate`` [rad/s], ``r`` [rad/s] (B,),
        ``mu`` (B, 4) (its mean is the road friction)."""
        c1, c2, u, mu_mean = self._at(u, mu)
        beta, beta_rate, r = (np.asarray(x, dtype=float) for x in (beta, beta_rate, r))
        if not beta.shape == beta_rate.shape == r.shape == c1.shape:
            raise ValueError(
                f"beta, beta_rate and r must have the shape of u {c1.shape}; got {beta.shape}, "
                f"{beta_rate.shape}, {r.shape}"
            )
        window = self.yaw_rate_window * mu_mean * GRAVITY / np.maximum(np.abs(u), MIN_SPEED)
        return np.maximum(np.abs(beta_rate + c1 * beta) / c2, np.abs(r) / window)

    def state_index(self, state) -> np.ndarray:
        """:meth:`index` (B,) of an Estimate-like state (u, v, beta, r, ax, ay, mu), with beta_dot
        from :func:`sideslip_rate`."""
        s = state
        return self.index(s.u, s.beta, sideslip_rate(s.u, s.v, s.r, s.ax, s.ay), s.r, s.mu)


@numba.njit(**JIT)
def _bilinear(speeds, frictions, grid, u, mu, out) -> None:
    """out[:, b] = grid (2, S, F) interpolated bilinearly at (|u_b|, mu_b), clamped to the table.
    Compiled: the Gymnasium env evaluates the region at every step (numpy's ~25 small-array
    calls took 36 us per step, 4% of a single env's)."""
    for b in range(u.size):
        x = min(max(abs(u[b]), speeds[0]), speeds[-1])
        y = min(max(mu[b], frictions[0]), frictions[-1])
        i = min(np.searchsorted(speeds, x, side="right"), speeds.size - 1) - 1
        j = min(np.searchsorted(frictions, y, side="right"), frictions.size - 1) - 1
        wx = (x - speeds[i]) / (speeds[i + 1] - speeds[i])
        wy = (y - frictions[j]) / (frictions[j + 1] - frictions[j])
        for k in range(2):
            out[k, b] = (1.0 - wx) * ((1.0 - wy) * grid[k, i, j] + wy * grid[k, i, j + 1]) + wx * (
                (1.0 - wy) * grid[k, i + 1, j] + wy * grid[k, i + 1, j + 1]
            )


@numba.njit(inline="always", **JIT)
def eq20_gain(u: float, a: float, b: float, mass: float, c_f: float, c_r: float) -> float:
    """Paper eq. 20, proportional 4WS gain k = delta_r / delta_f for zero steady-state sideslip.

    ``k = (-b + m a u^2 / (C_r L)) / (a + m b u^2 / (C_f L))`` with positive axle cornering
    stiffnesses C_f, C_r [N/rad] (Abe, *Vehicle Handling Dynamics*, sec. 9.2): the paper's k1,
    k2, which it leaves undefined, read as the front and rear axle stiffnesses. Scalars [m/s, m,
    m, kg, N/rad, N/rad]; :func:`rear_steer_gain` applies it over arrays, and the plant's kernel
    inlines it (envs.vehicle, the scenarios' rear_steer_feedforward).
    """
    wheelbase = a + b
    u2 = u * u
    return (-b + mass * a * u2 / (c_r * wheelbase)) / (a + mass * b * u2 / (c_f * wheelbase))


def rear_steer_gain(u: np.ndarray, params) -> np.ndarray:
    """Paper eq. 20 (zero-sideslip proportional 4WS) at speeds ``u`` [m/s] (scalar or (B,)):
    :func:`eq20_gain` (written once; its Python function, which numpy broadcasts over arrays).
    Opposite phase (k < 0) below u0 = sqrt(b C_r L / (m a)), in phase above."""
    c_f, c_r = params.axle_cornering_stiffness
    law = getattr(eq20_gain, "py_func", eq20_gain)  # (the function itself under NUMBA_DISABLE_JIT)
    return law(np.asarray(u, dtype=float), params.cg_to_front, params.cg_to_rear, params.mass, c_f, c_r)


def rear_steer_feedforward(u: np.ndarray, delta_f: np.ndarray, params) -> np.ndarray:
    """Rear road-wheel angle (B,) [rad] of the eq. 20 law, limited to the actuator range."""
    return np.clip(rear_steer_gain(u, params) * delta_f, -params.max_rear_steer, params.max_rear_steer)

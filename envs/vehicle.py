"""Truth plant of the 4WID-4WS car: parameters, state layout and the compiled dynamics.

One implementation of the physics, a numba kernel looping over a leading batch axis;
the single vehicle is a batch of one. Higher fidelity than, and different from, the
estimator's 3-DOF Dugoff model (no "inverse crime"):

* body: longitudinal u, lateral v, yaw r (ISO 8855) plus global pose X, Y, psi;
* four wheel-spin DOFs, ``J omega_dot = T - R Fx - M_roll``;
* tyres: PAC2002 Magic Formula, combined slip, load dependent, peaks scaled by the
  friction of the road under each wheel (:mod:`envs.tyre`);
* tyre transient slip (relaxation lengths, Pacejka, *Tire and Vehicle Dynamics*, 3rd ed.,
  sec. 7.2): the slips are states, ``sigma dkappa'/dt = (R omega - v_cx) - |v_cx| kappa'``
  and likewise laterally. This is the physics of a tyre carcass, and it is also how the
  stiffness of wheel spin at low speed is handled: the textbook quasi-static slip
  ``(R omega - u)/u`` puts an eigenvalue ``-Kx R^2 / (J u)`` (about -3,000 1/s at 1 m/s) in
  the wheel dynamics, beyond any explicit step of 2 ms; with relaxation the wheel mode is
  a ~14 Hz oscillation whose damping grows with speed, plus MF-Tyre's low-speed damping
  (``VXLOW``), so fixed-step RK4 at 2 ms is stable from standstill to 45 m/s
  (tests/test_vehicle.py checks the eigenvalues against RK4's stability region);
* normal loads with longitudinal and lateral load transfer (h = 0.54 m) driven by the
  body accelerations through a first-order lag that stands for pitch/roll dynamics
  (and removes the algebraic loop between loads and forces); the lateral transfer is
  split between the axles in proportion to their static loads;
* four in-wheel motors: first-order torque lag, peak torque and peak power limits;
* front and rear steering servos with angle and rate limits; the paper's proportional
  4WS law (eq. 20) as a switchable rear-steer feed-forward.

The paper's car has a = b and equal tyres, so it is neutral-steer: its linear understeer
gradient ``K = m/L (b/C_f - a/C_r)`` is zero, the steady-state yaw-rate gain ``u/L`` grows
without bound with speed instead of saturating at the characteristic speed, and near the
limit the rear axle (which carries the same load as the front) saturates as early as the
front, so the uncontrolled car tends to oversteer and spin in aggressive manoeuvres.

Integration: classical RK4 at a fixed step (2 ms by default, the paper's sample time);
the road friction under each wheel is sampled at the start of each step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np

from envs.tyre import TyreParams, combined_forces, relaxation_lengths
from estimation.jit import JIT

GRAVITY = 9.80665  #: standard gravity [m/s^2]


@dataclass(frozen=True)
class VehicleParams:
    """Vehicle parameters [SI]. Paper Table 1 where it gives them; sources for the rest."""

    mass: float = 830.0  #: total mass [kg] (paper Table 1)
    yaw_inertia: float = 1110.0  #: yaw moment of inertia Iz [kg m^2] (Table 1)
    cg_to_front: float = 1.17  #: a, CG to front axle [m] (Table 1)
    cg_to_rear: float = 1.17  #: b, CG to rear axle [m] (Table 1; L = 2.34 m)
    track_front: float = 1.416  #: front track [m] (Table 1)
    track_rear: float = 1.416  #: rear track [m] (Table 1)
    wheel_radius: float = 0.278  #: effective rolling radius R [m] (Table 1)
    cg_height: float = 0.54  #: CG height h [m] (Table 1)
    #: wheel + tyre + in-wheel motor rotor spin inertia [kg m^2]: ~0.7 for a 14" wheel
    #: and tyre (Genta & Morello, The Automotive Chassis, vol. 1) plus ~0.3 for an
    #: outer-rotor in-wheel motor.
    wheel_inertia: float = 1.0
    steering_ratio: float = 16.0  #: steering-wheel to road-wheel angle ratio [-] (typical 14-18)
    #: motor peak torque [N m]: the grip-limited torque on dry road is mu*Fz*R ~ 566 N m
    #: per wheel for this car; the motors are sized just above it.
    motor_peak_torque: float = 600.0
    motor_peak_power: float = 25.0e3  #: per-motor peak power [W] (caps torque above ~42 rad/s)
    motor_time_constant: float = 0.010  #: torque response lag [s] (in-wheel motors: 5-20 ms)
    max_front_steer: float = 0.60  #: front road-wheel angle limit [rad] (~34 deg)
    #: front steer rate limit [rad/s]: 1.6 rad/s at the road wheel is ~1,470 deg/s at the
    #: steering wheel, above the ~1,320 deg/s peak of a 300 deg, 0.7 Hz sine-with-dwell robot.
    front_steer_rate: float = 1.6
    max_rear_steer: float = math.radians(5.0)  #: rear road-wheel angle limit [rad] (active rear steer: 3-10 deg)
    rear_steer_rate: float = 0.5  #: rear steer rate limit [rad/s]
    steer_time_constant: float = 0.010  #: steering servo position lag [s]
    #: rolling resistance coefficient [-] (QSY1 of the tyre's .tir file)
    rolling_resistance: float = 0.01
    drag_area: float = 0.60  #: Cd * A [m^2] (Cd 0.32, A 1.9 m^2: small hatchback)
    air_density: float = 1.206  #: [kg/m^3] (ISO 2533 at 20 deg C)
    load_transfer_time_constant: float = 0.05  #: lag of load transfer behind accelerations [s] (pitch/roll)
    #: low-speed damping of tyre slip [N s/m] at static load, faded out (cosine) by ``low_speed_fade`` (MF-Tyre VXLOW idea)
    low_speed_damping: float = 1000.0
    low_speed_fade: float = 1.0  #: speed at which the low-speed damping vanishes [m/s] (VXLOW of the .tir)
    min_relaxation_length: float = 0.1  #: floor for the load-dependent relaxation lengths [m]
    width: float = 1.60  #: overall body width [m] (track + tyre width), for cone courses
    front_overhang: float = 0.60  #: front axle to front bumper [m]
    rear_overhang: float = 0.50  #: rear axle to rear bumper [m]
    rear_steer_feedforward: bool = False  #: apply the paper's 4WS law (eq. 20) on top of the rear command
    tyre: TyreParams = field(default_factory=TyreParams)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("tyre", "rear_steer_feedforward"):
                continue
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"VehicleParams.{f.name} must be a finite number > 0, got {value!r}")

    def replace(self, **overrides) -> "VehicleParams":
        """Copy with ``overrides``; unknown names raise ValueError."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown VehicleParams field(s) {unknown}; known: {sorted(known)}")
        return replace(self, **overrides)

    @property
    def wheelbase(self) -> float:
        """L = a + b [m]."""
        return self.cg_to_front + self.cg_to_rear

    @property
    def static_wheel_loads(self) -> np.ndarray:
        """Static normal loads (4,) [N], order FL, FR, RL, RR."""
        front = self.mass * GRAVITY * self.cg_to_rear / (2.0 * self.wheelbase)
        rear = self.mass * GRAVITY * self.cg_to_front / (2.0 * self.wheelbase)
        return np.array([front, front, rear, rear])

    @property
    def reference_wheel_load(self) -> float:
        """Mean static wheel load [N]: the load at which road mu equals the tyre's peak."""
        return self.mass * GRAVITY / 4.0

    @property
    def axle_cornering_stiffness(self) -> tuple[float, float]:
        """(C_f, C_r): linear cornering stiffness of each axle at static load [N/rad]."""
        fz = self.static_wheel_loads
        c = self.tyre.cornering_stiffness(fz)
        return float(c[0] + c[1]), float(c[2] + c[3])

    @property
    def wheel_positions(self) -> np.ndarray:
        """Contact-point positions (4, 2) [m] in the body frame, (x forward, y left)."""
        a, b = self.cg_to_front, self.cg_to_rear
        tf, tr = self.track_front / 2.0, self.track_rear / 2.0
        return np.array([[a, tf], [a, -tf], [-b, tr], [-b, -tr]])

    @cached_property
    def kernel_tyre_array(self) -> np.ndarray:
        """Tyre coefficients packed for the compiled kernel, shape (N_TYRE_COEFFS,)."""
        return self.tyre.as_array()

    @cached_property
    def kernel_array(self) -> np.ndarray:
        """Parameters packed for the compiled kernel, shape (N_PARAMS,)."""
        mux, muy = self.tyre.peak_friction(self.reference_wheel_load)
        c_f, c_r = self.axle_cornering_stiffness
        values = {
            "mass": self.mass, "yaw_inertia": self.yaw_inertia, "cg_to_front": self.cg_to_front,
            "cg_to_rear": self.cg_to_rear, "track_front": self.track_front, "track_rear": self.track_rear,
            "wheel_radius": self.wheel_radius, "cg_height": self.cg_height, "wheel_inertia": self.wheel_inertia,
            "motor_peak_torque": self.motor_peak_torque, "motor_peak_power": self.motor_peak_power,
            "motor_time_constant": self.motor_time_constant, "max_front_steer": self.max_front_steer,
            "front_steer_rate": self.front_steer_rate, "max_rear_steer": self.max_rear_steer,
            "rear_steer_rate": self.rear_steer_rate, "steer_time_constant": self.steer_time_constant,
            "rolling_resistance": self.rolling_resistance, "drag_area": self.drag_area,
            "air_density": self.air_density, "load_transfer_time_constant": self.load_transfer_time_constant,
            "low_speed_damping": self.low_speed_damping, "low_speed_fade": self.low_speed_fade,
            "min_relaxation_length": self.min_relaxation_length,
            "rear_steer_feedforward": float(self.rear_steer_feedforward),
            "inv_mux_ref": 1.0 / float(mux), "inv_muy_ref": 1.0 / float(muy),
            "axle_stiffness_front": c_f, "axle_stiffness_rear": c_r,
            "reference_wheel_load": self.reference_wheel_load,
        }
        return np.array([values[name] for name in PARAM_NAMES], dtype=np.float64)


PARAM_NAMES = (
    "mass", "yaw_inertia", "cg_to_front", "cg_to_rear", "track_front", "track_rear", "wheel_radius",
    "cg_height", "wheel_inertia", "motor_peak_torque", "motor_peak_power", "motor_time_constant",
    "max_front_steer", "front_steer_rate", "max_rear_steer", "rear_steer_rate", "steer_time_constant",
    "rolling_resistance", "drag_area", "air_density", "load_transfer_time_constant", "low_speed_damping",
    "low_speed_fade", "min_relaxation_length", "rear_steer_feedforward", "inv_mux_ref", "inv_muy_ref",
    "axle_stiffness_front", "axle_stiffness_rear", "reference_wheel_load",
)
(P_M, P_IZ, P_A, P_B, P_TF, P_TR, P_RW, P_H, P_JW, P_TMAX, P_PMAX, P_TAU_M, P_DF_MAX, P_DF_RATE,
 P_DR_MAX, P_DR_RATE, P_TAU_S, P_FRR, P_CDA, P_RHO, P_TAU_LT, P_CLOW, P_VLOW, P_SIGMA_MIN, P_FF4WS,
 P_INV_MUX, P_INV_MUY, P_CF, P_CR, P_FZREF) = range(len(PARAM_NAMES))

#: State layout, shape (..., NX): pose, body velocities, wheel speeds, motor torques,
#: steer angles, tyre deflections (relaxed slip * relaxation length) and lagged accelerations.
STATE_NAMES = (
    "x", "y", "psi", "u", "v", "r",
    "omega_fl", "omega_fr", "omega_rl", "omega_rr",
    "torque_fl", "torque_fr", "torque_rl", "torque_rr",
    "delta_f", "delta_r",
    "defl_x_fl", "defl_x_fr", "defl_x_rl", "defl_x_rr",
    "defl_y_fl", "defl_y_fr", "defl_y_rl", "defl_y_rr",
    "ax_lag", "ay_lag",
)
NX = len(STATE_NAMES)
S_X, S_Y, S_PSI, S_U, S_V, S_R = range(6)
S_OMEGA, S_TORQUE, S_DELTA_F, S_DELTA_R, S_DEFL_X, S_DEFL_Y, S_AX, S_AY = 6, 10, 14, 15, 16, 20, 24, 25

#: Control layout, shape (..., NU): motor torque commands [N m] and road-wheel steer commands [rad].
CONTROL_NAMES = ("torque_fl", "torque_fr", "torque_rl", "torque_rr", "delta_f", "delta_r")
NU = len(CONTROL_NAMES)
C_TORQUE, C_DELTA_F, C_DELTA_R = 0, 4, 5

#: Diagnostic outputs, shape (..., NAUX), evaluated at the returned state.
AUX_NAMES = (
    "ax", "ay",
    "fz_fl", "fz_fr", "fz_rl", "fz_rr",
    "fx_fl", "fx_fr", "fx_rl", "fx_rr",
    "fy_fl", "fy_fr", "fy_rl", "fy_rr",
    "kappa_fl", "kappa_fr", "kappa_rl", "kappa_rr",
    "alpha_fl", "alpha_fr", "alpha_rl", "alpha_rr",
    "mu_fl", "mu_fr", "mu_rl", "mu_rr",
    "usage_fl", "usage_fr", "usage_rl", "usage_rr",
)
NAUX = len(AUX_NAMES)
A_AX, A_AY, A_FZ, A_FX, A_FY, A_KAPPA, A_ALPHA, A_MU, A_USAGE = 0, 1, 2, 6, 10, 14, 18, 22, 26

MU_MAX = 2.0  #: largest accepted road friction coefficient


@numba.njit(inline="always", **JIT)
def rear_steer_gain(u: float, a: float, b: float, mass: float, c_f: float, c_r: float) -> float:
    """Paper eq. 20, proportional 4WS gain k = delta_r / delta_f for zero steady-state sideslip.

    ``k = (-b + m a u^2 / (C_r L)) / (a + m b u^2 / (C_f L))`` with positive axle cornering
    stiffnesses C_f, C_r [N/rad] (Abe, *Vehicle Handling Dynamics*, sec. 9.2). The paper
    writes k1, k2 in the convention where cornering stiffnesses are negative.
    """
    wheelbase = a + b
    u2 = u * u
    return (-b + mass * a * u2 / (c_r * wheelbase)) / (a + mass * b * u2 / (c_f * wheelbase))


@numba.njit(**JIT)
def _derivative(x, ctrl, mu, p, tp, dx, aux):
    """State derivative of one vehicle; fills ``dx`` (NX,) and diagnostics ``aux`` (NAUX,)."""
    m, iz, a, b = p[P_M], p[P_IZ], p[P_A], p[P_B]
    rw, h, jw = p[P_RW], p[P_H], p[P_JW]
    wheelbase = a + b
    u, v, r, psi = x[S_U], x[S_V], x[S_R], x[S_PSI]
    ax_lag, ay_lag = x[S_AX], x[S_AY]
    delta_f, delta_r = x[S_DELTA_F], x[S_DELTA_R]

    # normal loads: static + lagged longitudinal and lateral transfer
    fz_front = m * GRAVITY * b / (2.0 * wheelbase)
    fz_rear = m * GRAVITY * a / (2.0 * wheelbase)
    d_long = m * ax_lag * h / (2.0 * wheelbase)
    d_lat_f = m * ay_lag * h * b / (wheelbase * p[P_TF])
    d_lat_r = m * ay_lag * h * a / (wheelbase * p[P_TR])

    fx_sum = 0.0
    fy_sum = 0.0
    mz_sum = 0.0
    fade = 0.0
    speed = math.sqrt(u * u + v * v)
    if speed < p[P_VLOW]:
        fade = 0.5 * (1.0 + math.cos(math.pi * speed / p[P_VLOW]))
    for i in range(4):
        front = i < 2
        left = i % 2 == 0
        xi = a if front else -b
        yi = (p[P_TF] if front else p[P_TR]) * (0.5 if left else -0.5)
        delta = delta_f if front else delta_r
        if front:
            fz = fz_front - d_long + (-d_lat_f if left else d_lat_f)
        else:
            fz = fz_rear + d_long + (-d_lat_r if left else d_lat_r)
        fz = max(fz, 1.0)
        cd, sd = math.cos(delta), math.sin(delta)
        vxb = u - r * yi
        vyb = v + r * xi
        vcx = cd * vxb + sd * vyb
        vcy = -sd * vxb + cd * vyb
        sig_k, sig_a = relaxation_lengths(tp, fz)
        sig_k = max(sig_k, p[P_SIGMA_MIN])
        sig_a = max(sig_a, p[P_SIGMA_MIN])
        kappa = x[S_DEFL_X + i] / sig_k
        tan_alpha = x[S_DEFL_Y + i] / sig_a
        omega = x[S_OMEGA + i]
        slip_velocity = rw * omega - vcx
        fxw, fyw = combined_forces(tp, fz, kappa, tan_alpha, mu[i] * p[P_INV_MUX], mu[i] * p[P_INV_MUY])
        damping = p[P_CLOW] * fade * fz / p[P_FZREF]
        fxw += damping * slip_velocity
        fyw -= damping * vcy
        dx[S_DEFL_X + i] = slip_velocity - abs(vcx) * kappa
        dx[S_DEFL_Y + i] = vcy - abs(vcx) * tan_alpha
        # wheel spin: motor torque, tyre force, rolling resistance (smoothed sign)
        wheel_speed = rw * omega
        m_roll = rw * p[P_FRR] * fz * wheel_speed / math.sqrt(wheel_speed * wheel_speed + 0.0025)
        dx[S_OMEGA + i] = (x[S_TORQUE + i] - rw * fxw - m_roll) / jw
        # motor: first-order lag towards the torque/power-limited command
        t_lim = min(p[P_TMAX], p[P_PMAX] / max(abs(omega), 1e-6))
        t_cmd = min(max(ctrl[C_TORQUE + i], -t_lim), t_lim)
        dx[S_TORQUE + i] = (t_cmd - x[S_TORQUE + i]) / p[P_TAU_M]
        fxb = cd * fxw - sd * fyw
        fyb = sd * fxw + cd * fyw
        fx_sum += fxb
        fy_sum += fyb
        mz_sum += xi * fyb - yi * fxb
        aux[A_FZ + i] = fz
        aux[A_FX + i] = fxw
        aux[A_FY + i] = fyw
        aux[A_KAPPA + i] = kappa
        aux[A_ALPHA + i] = math.atan(tan_alpha)
        aux[A_MU + i] = mu[i]
        aux[A_USAGE + i] = math.sqrt(fxw * fxw + fyw * fyw) / (mu[i] * fz)

    drag = 0.5 * p[P_RHO] * p[P_CDA] * u * abs(u)
    ax = (fx_sum - drag) / m
    ay = fy_sum / m
    dx[S_X] = u * math.cos(psi) - v * math.sin(psi)
    dx[S_Y] = u * math.sin(psi) + v * math.cos(psi)
    dx[S_PSI] = r
    dx[S_U] = ax + v * r
    dx[S_V] = ay - u * r
    dx[S_R] = mz_sum / iz
    dx[S_AX] = (ax - ax_lag) / p[P_TAU_LT]
    dx[S_AY] = (ay - ay_lag) / p[P_TAU_LT]
    aux[A_AX] = ax
    aux[A_AY] = ay

    # steering servos with angle and rate limits; optional 4WS feed-forward (paper eq. 20)
    target_f = min(max(ctrl[C_DELTA_F], -p[P_DF_MAX]), p[P_DF_MAX])
    rate_f = (target_f - delta_f) / p[P_TAU_S]
    dx[S_DELTA_F] = min(max(rate_f, -p[P_DF_RATE]), p[P_DF_RATE])
    target_r = ctrl[C_DELTA_R]
    if p[P_FF4WS] > 0.0:
        target_r += rear_steer_gain(u, a, b, m, p[P_CF], p[P_CR]) * delta_f
    target_r = min(max(target_r, -p[P_DR_MAX]), p[P_DR_MAX])
    rate_r = (target_r - delta_r) / p[P_TAU_S]
    dx[S_DELTA_R] = min(max(rate_r, -p[P_DR_RATE]), p[P_DR_RATE])


@numba.njit(**JIT)
def _wheel_mu(x, p, base_mu, rects, mu):
    """Road friction under each wheel from a rectangle table (later rows win)."""
    c, s = math.cos(x[S_PSI]), math.sin(x[S_PSI])
    for i in range(4):
        xi = p[P_A] if i < 2 else -p[P_B]
        yi = (p[P_TF] if i < 2 else p[P_TR]) * (0.5 if i % 2 == 0 else -0.5)
        gx = x[S_X] + c * xi - s * yi
        gy = x[S_Y] + s * xi + c * yi
        value = base_mu
        for k in range(rects.shape[0]):
            if rects[k, 4] > 0.0 and rects[k, 0] <= gx < rects[k, 1] and rects[k, 2] <= gy < rects[k, 3]:
                value = rects[k, 4]
        mu[i] = value


@numba.njit(**JIT)
def _advance_one(x, ctrl, p, tp, base_mu, rects, mu_given, use_map, dt, n_steps, aux):
    """RK4 over ``n_steps`` steps of ``dt`` for one vehicle, in place. Returns a status code."""
    for j in range(NU):
        if not math.isfinite(ctrl[j]):
            return 1
    k1 = np.empty(NX)
    k2 = np.empty(NX)
    k3 = np.empty(NX)
    k4 = np.empty(NX)
    tmp = np.empty(NX)
    mu = np.empty(4)
    for _ in range(n_steps):
        if use_map:
            _wheel_mu(x, p, base_mu, rects, mu)
        else:
            mu[:] = mu_given
        for i in range(4):
            if not (0.0 < mu[i] <= MU_MAX):
                return 2
        _derivative(x, ctrl, mu, p, tp, k1, aux)
        for j in range(NX):
            tmp[j] = x[j] + 0.5 * dt * k1[j]
        _derivative(tmp, ctrl, mu, p, tp, k2, aux)
        for j in range(NX):
            tmp[j] = x[j] + 0.5 * dt * k2[j]
        _derivative(tmp, ctrl, mu, p, tp, k3, aux)
        for j in range(NX):
            tmp[j] = x[j] + dt * k3[j]
        _derivative(tmp, ctrl, mu, p, tp, k4, aux)
        for j in range(NX):
            x[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
            if not math.isfinite(x[j]):
                return 3
    if use_map:
        _wheel_mu(x, p, base_mu, rects, mu)
    _derivative(x, ctrl, mu, p, tp, k1, aux)
    return 0


@numba.njit(**JIT)
def _advance_serial(x, ctrl, p, tp, base_mu, rects, mu_given, use_map, dt, n_steps, aux, status):
    for b in range(x.shape[0]):
        status[b] = _advance_one(x[b], ctrl[b], p, tp, base_mu[b], rects[b], mu_given[b], use_map,
                                 dt, n_steps, aux[b])


@numba.njit(parallel=True, **JIT)
def _advance_parallel(x, ctrl, p, tp, base_mu, rects, mu_given, use_map, dt, n_steps, aux, status):
    for b in numba.prange(x.shape[0]):
        status[b] = _advance_one(x[b], ctrl[b], p, tp, base_mu[b], rects[b], mu_given[b], use_map,
                                 dt, n_steps, aux[b])


@numba.njit(**JIT)
def _derivatives_batch(x, ctrl, mu, p, tp, dx, aux):
    for b in range(x.shape[0]):
        _derivative(x[b], ctrl[b], mu[b], p, tp, dx[b], aux[b])


PARALLEL_MIN_BATCH = 64  #: batches at least this large run on all cores


def _check_array(name: str, value: np.ndarray, width: int) -> np.ndarray:
    value = np.ascontiguousarray(value, dtype=np.float64)
    if value.ndim != 2 or value.shape[1] != width:
        raise ValueError(f"{name} must have shape (batch, {width}), got {value.shape}")
    if not np.all(np.isfinite(value)):
        bad = np.argwhere(~np.isfinite(value))[0]
        raise ValueError(f"{name} has a non-finite value {value[tuple(bad)]!r} at index {tuple(int(i) for i in bad)}")
    return value


def derivatives(state: np.ndarray, controls: np.ndarray, mu: np.ndarray,
                params: VehicleParams) -> tuple[np.ndarray, np.ndarray]:
    """Pure batched dynamics: ``state (B, NX), controls (B, NU), mu (B, 4)`` -> ``(state_dot, aux)``.

    ``aux (B, NAUX)`` holds the diagnostics named in :data:`AUX_NAMES`.
    """
    state = _check_array("state", state, NX)
    controls = _check_array("controls", controls, NU)
    mu = _check_array("mu", mu, 4)
    if state.shape[0] != controls.shape[0] or state.shape[0] != mu.shape[0]:
        raise ValueError(f"batch sizes differ: state {state.shape}, controls {controls.shape}, mu {mu.shape}")
    _check_mu(mu)
    dx = np.empty_like(state)
    aux = np.empty((state.shape[0], NAUX))
    _derivatives_batch(state, controls, mu, params.kernel_array, params.kernel_tyre_array, dx, aux)
    return dx, aux


def _check_mu(mu: np.ndarray) -> None:
    bad = ~((mu > 0.0) & (mu <= MU_MAX))
    if np.any(bad):
        raise ValueError(f"road friction mu must lie in (0, {MU_MAX}], got {mu[bad][0]!r}")


class PlantStep(NamedTuple):
    """Result of :func:`step`: the new state (B, NX) and diagnostics at it (B, NAUX)."""

    state: np.ndarray
    aux: np.ndarray


def step(state: np.ndarray, controls: np.ndarray, params: VehicleParams, road, dt: float = 0.002,
         n_steps: int = 1) -> PlantStep:
    """Advance a batch ``n_steps`` RK4 steps of ``dt`` [s] with controls held; returns a new state.

    ``road``: a friction map (:mod:`envs.road`: one for the whole batch, or a sequence of B maps)
    or precomputed :class:`envs.road.RoadTables` (the fast path for repeated calls). Table maps
    are evaluated inside the kernel at every step; user callables are evaluated in Python once
    per call, so call with ``n_steps=1`` for them when a wheel may cross a friction boundary.
    Non-finite controls or road friction outside (0, 2] raise ValueError; a state that turns
    non-finite raises FloatingPointError (a run never silently produces NaN).
    """
    from envs.road import RoadTables, road_tables

    state = np.asarray(state, dtype=np.float64)
    controls = np.ascontiguousarray(controls, dtype=np.float64)
    if state.ndim != 2 or state.shape[1] != NX:
        raise ValueError(f"state must have shape (batch, {NX}), got {state.shape}")
    batch = state.shape[0]
    if controls.shape != (batch, NU):
        raise ValueError(f"controls must have shape ({batch}, {NU}), got {controls.shape}")
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f"dt must be a finite number > 0, got {dt!r}")
    if int(n_steps) != n_steps or n_steps < 1:
        raise ValueError(f"n_steps must be a positive integer, got {n_steps!r}")
    tables = road if isinstance(road, RoadTables) else road_tables(road, state, params)
    if tables.base_mu.shape[0] != batch:
        raise ValueError(f"road tables are for a batch of {tables.base_mu.shape[0]}, state batch is {batch}")
    out = state.copy()
    aux = np.empty((batch, NAUX))
    status = np.zeros(batch, dtype=np.int64)
    kernel = _advance_parallel if batch >= PARALLEL_MIN_BATCH else _advance_serial
    kernel(out, controls, params.kernel_array, params.kernel_tyre_array, tables.base_mu, tables.rects,
           tables.mu_given, tables.use_map, float(dt), int(n_steps), aux, status)
    if status.any():
        b = int(np.flatnonzero(status)[0])
        code = int(status[b])
        if code == 1:
            raise ValueError(f"controls[{b}] has a non-finite value: {controls[b]!r}")
        if code == 2:
            raise ValueError(f"road friction under vehicle {b} is outside (0, {MU_MAX}] at x={out[b, S_X]:.3f} m, "
                             f"y={out[b, S_Y]:.3f} m")
        if not np.all(np.isfinite(state[b])):
            raise ValueError(f"state[{b}] has a non-finite value: {state[b]!r}")
        raise FloatingPointError(f"plant state of vehicle {b} became non-finite (last finite state {state[b]!r})")
    return PlantStep(out, aux)


def initial_state(params: VehicleParams, speed: float | np.ndarray, batch_size: int = 1,
                  x: float = 0.0, y: float = 0.0, heading: float = 0.0) -> np.ndarray:
    """Straight free-rolling state (batch_size, NX) at ``speed`` [m/s] (scalar or (batch_size,))."""
    speed = np.broadcast_to(np.asarray(speed, dtype=np.float64), (batch_size,))
    if not np.all(np.isfinite(speed)) or np.any(speed < 0.0):
        raise ValueError(f"initial speed must be finite and >= 0, got {speed!r}")
    state = np.zeros((batch_size, NX))
    state[:, S_X] = x
    state[:, S_Y] = y
    state[:, S_PSI] = heading
    state[:, S_U] = speed
    state[:, S_OMEGA:S_OMEGA + 4] = speed[:, None] / params.wheel_radius
    return state

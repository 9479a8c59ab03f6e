"""Wheel actuation: each wheel's net torque demand to its motor and friction brake, with wheel-slip
control (ABS on braking, traction control on drive) on estimated quantities.

Every controller (and the driver) asks for a net torque per wheel [N m], drive minus brake, as the
estimators' torque channel counts it. :func:`actuate` meets it the way a brake-blending unit does:
the motor takes what its torque and power limits allow at the wheel's measured speed (regenerative
braking first), the friction brake the rest of a braking demand, as a pressure command of that
torque over the brake gain (forward driving: the brake opposes a wheel spinning forwards).

Wheel-slip control, per wheel and switchable, runs before the split on the measured wheel speed
omega, the estimated forward speed u and the estimated friction mu_hat of the wheel's road (what a
production ABS/TCS unit has: its wheel-speed sensors and a vehicle-speed and friction estimate),
with slip ``s = (R omega - u_w) / max(u_w, min_speed)`` against the wheel's own forward speed
``u_w = u_ref - r_hat y_w`` (y_w its lateral position, left positive, r_hat the estimated yaw rate:
in a turn the outer wheels roll faster than the CG; the steer angle's cosine is left out). The
reference speed u_ref bounds the car's speed from the side the slip is on, as production units
do: ABS takes the larger of the estimate u and the fastest wheel's rim speed, TCS the smaller of u
and the slowest wheel's (each moved to the CG with r_hat y_w), each wheel reference held within
``REFERENCE_MARGIN`` of the measured longitudinal acceleration (falling and rising no faster than
that: a braked wheel lags the car, a spinning one runs ahead of it). A speed estimator built on
the wheels alone loses the car's speed when all four slip, as the joint estimator does under full
braking; and with the fastest wheel as TCS's reference, four wheels spinning alike on ice read no
slip at all (docs/decisions/0039-wheel-slip-control.md, 0042).

The slip window is scheduled on the friction, ``peak = peak_slip mu_hat`` and
``band = max(slip_band mu_hat, MIN_SLIP_BAND)`` (mu_hat floored at MIN_SLIP_MU): the tyre's
stiffness does not fall with the road's grip, so its peak slip does (0.147 mu on the shipped tyre).
A braking demand is
scaled by ``clip((peak + band / 2 + s) / band, 0, 1)`` (ABS: full demand while the slip is above
-(peak - band / 2), none below -(peak + band / 2)), a drive demand by
``clip((peak + band / 2 - s) / band, 0, 1)`` (TCS). A full pedal asks for several times the
torque the road can take, so the wheel settles where the scaled demand balances its tyre force,
just past the peak slip: a proportional slip controller in place of a production unit's pressure
build/hold/dump rule tables. Below ``min_speed`` the estimated speed cannot give a slip and ABS is
off (production units hand over to the driver at a few km/h; UN R13-H's wheel-lock criterion
applies above 15 km/h).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from fourwis.core.checks import is_number
from fourwis.core.kernels import JIT

#: default target |slip| at friction 1 [-]: the shipped Magic Formula tyre's Fx(kappa) peaks at
#: 0.142-0.147 on mu 1 (2.0-2.8 kN) and at that times mu on a road of friction mu
PEAK_SLIP = 0.15
SLIP_BAND = 0.06  #: slip over which the demand fades from full to none at friction 1 [-]
MIN_SLIP_SPEED = 1.0  #: estimated speed [m/s] below which slip control is off (ABS cut-out)
MIN_SLIP_MU = 0.05  #: floor of the friction estimate the slip window is scheduled on [-]
#: narrowest slip window [-]: ~25 times the slip noise of a wheel-speed sensor at 60 km/h (0.05 rad/s
#: x 0.278 m / 16.7 m/s = 8e-4); narrower, on ice, the noise chops the demand
MIN_SLIP_BAND = 0.02
#: extra decay of the wheel-speed reference beyond the measured deceleration [m/s^2] (above the
#: accelerometer's 0.03 m/s^2 bias std, so the reference does not drift above the car)
REFERENCE_MARGIN = 0.1


class WheelActuators(NamedTuple):
    """The car's wheel actuators and their slip control, as :func:`actuate` takes them: ``abs`` and
    ``tcs`` switch ABS and traction control, ``peak_slip`` and ``slip_band`` [-] place the slip
    window, ``min_speed`` [m/s]; wheel radius [m], motor peak torque [N m] and power [W], brake gain
    [N m/Pa] and largest pressure [Pa], the front and rear tracks [m]; ``reference`` (B, 2) [m/s]
    each vehicle's wheel-speed references, the fastest wheel's (ABS) and the slowest wheel's (TCS),
    updated in place (0: none yet), and the step ``dt`` [s] they ramp over."""

    abs: bool
    tcs: bool
    peak_slip: float
    slip_band: float
    min_speed: float
    wheel_radius: float
    motor_peak_torque: float
    motor_peak_power: float
    brake_gain: float
    brake_max_pressure: float
    track_front: float
    track_rear: float
    reference: np.ndarray
    dt: float


def wheel_actuators(
    params, batch_size: int, dt: float, abs: bool = True, tcs: bool = True, peak_slip: float = PEAK_SLIP,
    slip_band: float = SLIP_BAND, min_speed: float = MIN_SLIP_SPEED,
) -> WheelActuators:  # fmt: skip
    """The :class:`WheelActuators` of ``batch_size`` cars ``params`` (a VehicleParams) stepping at
    ``dt`` [s], with slip control switched by ``abs`` and ``tcs``; bad settings raise ValueError
    naming them."""
    for name, value in (("abs", abs), ("tcs", tcs)):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{name} must be True or False, got {value!r}")
    for name, value in (("peak_slip", peak_slip), ("slip_band", slip_band), ("min_speed", min_speed)):
        if not (is_number(value) and math.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    if not peak_slip - 0.5 * slip_band > 0.0:
        raise ValueError(
            f"peak_slip - slip_band / 2 must be > 0 (full demand at low slip), got {peak_slip!r}, {slip_band!r}"
        )
    return WheelActuators(
        bool(abs), bool(tcs), float(peak_slip), float(slip_band), float(min_speed), params.wheel_radius,
        params.motor_peak_torque, params.motor_peak_power, params.brake_gain, params.brake_max_pressure,
        params.track_front, params.track_rear, np.zeros((batch_size, 2)), float(dt),
    )  # fmt: skip


@numba.njit(inline="always", **JIT)
def slip_scale(actuators: WheelActuators, demand: float, omega: float, speed: float, mu: float) -> float:
    """The factor [0, 1] slip control applies to a wheel's net torque ``demand`` [N m] at its
    measured speed ``omega`` [rad/s], the estimated forward speed ``speed`` [m/s] and friction ``mu``."""
    a = actuators
    slip = (a.wheel_radius * omega - speed) / max(speed, a.min_speed)
    grip = max(mu, MIN_SLIP_MU)
    band = max(a.slip_band * grip, MIN_SLIP_BAND)
    edge = a.peak_slip * grip + 0.5 * band
    if demand < 0.0 and a.abs and speed > a.min_speed:
        return min(max((edge + slip) / band, 0.0), 1.0)
    if demand > 0.0 and a.tcs:
        return min(max((edge - slip) / band, 0.0), 1.0)
    return 1.0


@numba.njit(inline="always", **JIT)
def lateral_position(actuators: WheelActuators, w: int) -> float:
    """Wheel w's lateral position y [m] (left positive; FL, FR, RL, RR)."""
    half = 0.5 * (actuators.track_front if w < 2 else actuators.track_rear)
    return half if w % 2 == 0 else -half


@numba.njit(inline="always", **JIT)
def _ramped(reference: float, wheel: float, ax: float, dt: float) -> float:
    """A wheel-speed reference [m/s] moved to ``wheel`` [m/s] within ``ax`` +/- REFERENCE_MARGIN
    [m/s^2] over ``dt`` [s] (``reference`` 0: none yet, it starts at ``wheel``)."""
    if reference > 0.0 and math.isfinite(ax):
        return min(max(wheel, reference + (ax - REFERENCE_MARGIN) * dt), reference + (ax + REFERENCE_MARGIN) * dt)
    return wheel


@numba.njit(inline="always", **JIT)
def reference_speeds(
    actuators: WheelActuators, b: int, omega: np.ndarray, ax: float, speed: float, yaw_rate: float
) -> tuple[float, float]:
    """Vehicle b's slip reference speeds at the CG [m/s], ABS's and TCS's, from its measured wheel
    speeds ``omega`` (4,) [rad/s], measured longitudinal specific force ``ax`` [m/s^2], estimated
    speed ``speed`` [m/s] and yaw rate ``yaw_rate`` [rad/s], advancing its wheel-speed references by
    one step."""
    a = actuators
    fastest, slowest = -math.inf, math.inf
    for w in range(4):
        rim = a.wheel_radius * omega[w] + yaw_rate * lateral_position(a, w)
        fastest, slowest = max(fastest, rim), min(slowest, rim)
    a.reference[b, 0] = _ramped(a.reference[b, 0], fastest, ax, a.dt)
    a.reference[b, 1] = _ramped(a.reference[b, 1], slowest, ax, a.dt)
    return max(speed, a.reference[b, 0]), min(speed, a.reference[b, 1])


@numba.njit(inline="always", **JIT)
def actuate(
    actuators: WheelActuators, demand: np.ndarray, omega: np.ndarray, braking_speed: float, drive_speed: float,
    yaw_rate: float, mu: np.ndarray, motor: np.ndarray, pressure: np.ndarray,
) -> None:  # fmt: skip
    """One car's net torque demands ``demand`` (4,) [N m] after slip control, split into motor
    torque commands ``motor`` (4,) [N m] and brake pressure commands ``pressure`` (4,) [Pa], at the
    measured wheel speeds ``omega`` (4,) [rad/s], the reference speeds at the CG [m/s] a braking
    and a drive demand's slip is taken against (:func:`reference_speeds`), the estimated yaw rate
    ``yaw_rate`` [rad/s] and friction ``mu`` (4,)."""
    a = actuators
    for w in range(4):
        speed = braking_speed if demand[w] < 0.0 else drive_speed
        wheel_speed = speed - yaw_rate * lateral_position(a, w)
        net = demand[w] * slip_scale(a, demand[w], omega[w], wheel_speed, mu[w])
        limit = min(a.motor_peak_torque, a.motor_peak_power / max(abs(omega[w]), 1e-6))
        motor[w] = min(max(net, -limit), limit)
        pressure[w] = min(max(motor[w] - net, 0.0) / a.brake_gain, a.brake_max_pressure)


def actuate_batch(
    actuators: WheelActuators,
    demand: np.ndarray,
    omega: np.ndarray,
    speed: np.ndarray,
    mu: np.ndarray,
    yaw_rate: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`actuate` of B cars: demands, wheel speeds and friction (B, 4), reference speeds (B,)
    (for braking and drive alike) and yaw rates (B,) (None: straight); returns the motor torque
    (B, 4) [N m] and brake pressure (B, 4) [Pa] commands."""
    demand, omega = np.ascontiguousarray(demand, dtype=float), np.ascontiguousarray(omega, dtype=float)
    speed, mu = np.ascontiguousarray(speed, dtype=float), np.ascontiguousarray(mu, dtype=float)
    yaw_rate = np.zeros(len(speed)) if yaw_rate is None else np.ascontiguousarray(yaw_rate, dtype=float)
    motor, pressure = np.empty_like(demand), np.empty_like(demand)
    _actuate_rows(actuators, demand, omega, speed, yaw_rate, mu, motor, pressure)
    return motor, pressure


@numba.njit(**JIT)
def _actuate_rows(actuators, demand, omega, speed, yaw_rate, mu, motor, pressure):
    for b in range(demand.shape[0]):
        actuate(actuators, demand[b], omega[b], speed[b], speed[b], yaw_rate[b], mu[b], motor[b], pressure[b])

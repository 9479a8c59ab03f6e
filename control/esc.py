"""A brake-based electronic stability control baseline: the production kind.

Like a production ESC (van Zanten, SAE 2000-01-1633) it compares the estimated yaw rate with the
friction-bounded 2-DOF reference and the estimated sideslip with its mu-dependent bound, switches
on when the car leaves its stable region (:func:`fourwis.control.reference.outside_stable_region`)
and off once both errors are below exit thresholds (hysteresis), and brakes a single wheel: the
one whose braking force turns the car the way the correction asks. A corrective moment
``Mz = -K_r (r - r_ref) + K_beta (beta - clip(beta, -beta_on, beta_on))`` (counter-clockwise
positive; beta_on = STABLE_SIDESLIP x the bound: :func:`fourwis.control.reference.sideslip_moment`)
is asked of the left wheels if positive, the right ones if negative; of the front wheel when it
opposes the car's yaw (oversteer: braking the outer front wheel) and of the rear wheel when it
turns the car further (understeer: the inner rear wheel). The brake torque is
``|Mz| R / (track / 2)``, within the wheel's estimated grip mu_hat Fz R. While active, the
driver's positive drive torques are cut (a production ESC's engine-torque request). Every command
is a net wheel torque: the wheels' actuators (:mod:`control.wheel_slip`) brake it, with ABS.

The step is compiled once (:func:`esc_torques`): the closed loop runs it as the controller's stage
(:class:`EscKernel`) or beneath an agent's action (the env's ``esc=True``), and
:class:`BrakeESC`'s call runs it per vehicle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np

from fourwis.control.reference import (
    axle_friction,
    outside_stable_region,
    sideslip_bound_of,
    sideslip_moment,
    steady_yaw_rate,
    understeer_gradient,
)
from fourwis.core.checks import check_step, check_vehicle_params
from fourwis.core.kernels import JIT
from fourwis.core.types import Command, Estimate

#: the ESC switches off once |r - r_ref| < EXIT_YAW_ERROR [rad/s] and |beta| < EXIT_SIDESLIP x its
#: bound (it switches on outside the stable region: reference.STABLE_YAW_ERROR, STABLE_SIDESLIP)
EXIT_YAW_ERROR = 0.03
EXIT_SIDESLIP = 0.4
#: yaw-rate gain [N m per rad/s]: Iz / 0.15 s for the paper's car (a yaw error corrected in ~0.15 s)
YAW_GAIN_TIME = 0.15
ESC_MIN_SPEED = 5.0  #: no intervention below this estimated speed [m/s] (production: ~15-20 km/h)


class EscSettings(NamedTuple):
    """The ESC's car and gains as its compiled step takes them: wheelbase [m] and understeer
    gradient [rad s^2/m] of the yaw reference, the yaw-rate gain [N m s/rad], wheel radius [m],
    front and rear tracks [m], the speed below which it rests [m/s]."""

    wheelbase: float
    understeer: float
    yaw_gain: float
    wheel_radius: float
    track_front: float
    track_rear: float
    min_speed: float


class EscKernel(NamedTuple):
    """A :class:`BrakeESC` as the compiled loop takes it: its settings and whether it acts on each
    of B vehicles (B,) bool (updated in place)."""

    settings: EscSettings
    active: np.ndarray


def esc_settings(params) -> EscSettings:
    """The :class:`EscSettings` of duck-typed vehicle ``params`` (the reference's understeer
    gradient the car's own, floored at neutral, as
    :func:`fourwis.control.reference.reference_yaw_rate` takes it)."""
    return EscSettings(
        wheelbase=float(params.wheelbase),
        understeer=max(float(understeer_gradient(params)), 0.0),
        yaw_gain=float(params.yaw_inertia) / YAW_GAIN_TIME,
        wheel_radius=float(params.wheel_radius),
        track_front=float(params.track_front),
        track_rear=float(params.track_rear),
        min_speed=ESC_MIN_SPEED,
    )


@numba.njit(inline="always", **JIT)
def stability_errors(settings: EscSettings, b: int, estimate: Estimate, front: float) -> tuple[float, float]:
    """Vehicle b's yaw-rate error r - r_ref [rad/s] against the 2-DOF reference bounded by the
    weaker axle's friction, and its sideslip bound [rad] (of the mean friction), from row b of
    ``estimate`` at the front road-wheel angle ``front`` [rad]: what the stable region is judged on."""
    mu = estimate.mu[b]
    u = estimate.u[b]
    r_ref = steady_yaw_rate(
        u, front, axle_friction(mu[0], mu[1], mu[2], mu[3]), settings.wheelbase, settings.understeer
    )
    return estimate.r[b] - r_ref, sideslip_bound_of((mu[0] + mu[1] + mu[2] + mu[3]) / 4.0)


@numba.njit(inline="always", **JIT)
def unstable(settings: EscSettings, b: int, estimate: Estimate, front: float) -> bool:
    """Whether vehicle b, faster than the ESC's ``min_speed``, is outside its stable region
    (:func:`fourwis.control.reference.outside_stable_region` of :func:`stability_errors`)."""
    error, bound = stability_errors(settings, b, estimate, front)
    return estimate.u[b] > settings.min_speed and outside_stable_region(error, estimate.beta[b], bound)


@numba.njit(**JIT)
def _unstable_rows(settings: EscSettings, estimate: Estimate, front: np.ndarray, out: np.ndarray) -> None:
    for b in range(front.size):
        out[b] = unstable(settings, b, estimate, front[b])


def outside_stable(settings: EscSettings, estimate: Estimate, front_steer: np.ndarray) -> np.ndarray:
    """:func:`unstable` of each of B vehicles (B,) bool, from an Estimate-like ``estimate`` and the
    front road-wheel angles ``front_steer`` (B,) [rad]."""
    front = np.ascontiguousarray(front_steer, dtype=float)
    out = np.empty(len(front), dtype=np.bool_)
    _unstable_rows(settings, estimate_rows(estimate, len(front)), front, out)
    return out


def estimate_rows(estimate, batch: int) -> Estimate:
    """An :class:`Estimate` of ``batch`` rows from an Estimate-like object, as contiguous float
    arrays (fields it lacks: zeros; the ESC reads u, beta, r, mu and fz)."""

    def read(name: str) -> np.ndarray:
        value = getattr(estimate, name, None)
        shape = (batch, 4) if name in ("mu", "fz", "mu_std") else (batch,)
        return np.ascontiguousarray(np.zeros(shape) if value is None else value, dtype=float)

    return Estimate(*(read(name) for name in Estimate._fields))


@numba.njit(inline="always", **JIT)
def esc_torques(esc: EscKernel, b: int, estimate: Estimate, front: float, torques: np.ndarray) -> None:
    """Vehicle b's ESC step (the module docstring) on row b of ``estimate`` (u, beta, r, per-wheel
    mu and fz) at the front road-wheel angle ``front`` [rad]: updates ``esc.active[b]`` and, while
    active, cuts the drive and adds the brake torque to the net wheel torques ``torques`` (4,) [N m]
    in place."""
    s = esc.settings
    u, r, beta = estimate.u[b], estimate.r[b], estimate.beta[b]
    mu, fz = estimate.mu[b], estimate.fz[b]
    error, bound = stability_errors(s, b, estimate, front)
    leave = abs(error) < EXIT_YAW_ERROR and abs(beta) < EXIT_SIDESLIP * bound
    active = u > s.min_speed and ((esc.active[b] and not leave) or outside_stable_region(error, beta, bound))
    esc.active[b] = active
    if not active:
        return
    moment = -s.yaw_gain * error + sideslip_moment(beta, bound)
    left, oversteer = moment > 0.0, moment * r < 0.0
    wheel = (0 if left else 1) if oversteer else (2 if left else 3)  # FL, FR, RL, RR
    half_track = 0.5 * (s.track_front if wheel < 2 else s.track_rear)
    grip = max(mu[wheel] * fz[wheel] * s.wheel_radius, 0.0)
    for w in range(4):
        torques[w] = min(torques[w], 0.0)  # the drive torque request cut
    torques[wheel] -= min(abs(moment) * s.wheel_radius / half_track, grip)


@numba.njit(**JIT)
def _esc_rows(esc: EscKernel, estimate: Estimate, front: np.ndarray, torques: np.ndarray) -> None:
    """:func:`esc_torques` of each vehicle (rows of ``estimate``, ``front`` (B,), ``torques`` (B, 4))."""
    for b in range(front.size):
        esc_torques(esc, b, estimate, front[b], torques[b])


@dataclass
class BrakeESC:
    """Single-wheel braking ESC for vehicle ``params`` stepping at ``dt`` [s] (see the module
    docstring); the Controller protocol, batched over B vehicles, with per-vehicle on/off memory."""

    params: object
    dt: float = 0.002
    active: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self) -> None:
        check_vehicle_params(self.params)
        check_step(self.dt)
        self.settings = esc_settings(self.params)

    def reset(self, members: np.ndarray | None = None) -> None:
        """Every vehicle off, or those selected by ``members`` (B,) bool."""
        if members is None or self.active.shape != np.shape(members):
            self.active = np.zeros(0, dtype=bool)
        else:
            self.active[np.asarray(members, dtype=bool)] = False

    def kernel(self, batch: int) -> EscKernel:
        """This ESC as the compiled loop takes it for ``batch`` vehicles (its on/off array itself)."""
        if self.active.shape != (batch,):
            self.active = np.zeros(batch, dtype=bool)
        return EscKernel(self.settings, self.active)

    def __call__(self, t: np.ndarray, estimate: Estimate, front_steer: np.ndarray, base_torques: np.ndarray) -> Command:
        """The command (B vehicles) at the estimate (u, beta, r, mu, fz read), the driver's front
        road-wheel angles (B,) [rad] and base net torques (B, 4) [N m]."""
        front = np.ascontiguousarray(front_steer, dtype=float)
        rows = estimate_rows(estimate, len(front))
        torques = np.array(base_torques, dtype=float, copy=True)
        _esc_rows(self.kernel(len(front)), rows, front, torques)
        return Command(torques, np.zeros(len(front)))

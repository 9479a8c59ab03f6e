"""A brake-based electronic stability control baseline: the production kind.

Like a production ESC (van Zanten, SAE 2000-01-1633) it compares the estimated yaw rate with the
friction-bounded 2-DOF reference and the estimated sideslip with its mu-dependent bound, switches
on past entry thresholds and off below exit thresholds (hysteresis), and brakes a single wheel:
the one whose braking force turns the car the way the correction asks. A corrective moment
``Mz = -K_r (r - r_ref) + K_beta (beta - clip(beta, -beta_on, beta_on))`` (counter-clockwise
positive) is asked of the left wheels if positive, the right ones if negative; of the front wheel
when it opposes the car's yaw (oversteer: braking the outer front wheel) and of the rear wheel when
it turns the car further (understeer: the inner rear wheel). The brake torque is
``|Mz| R / (track / 2)``, within the wheel's estimated grip mu_hat Fz R. While active, the
driver's positive drive torques are cut (a production ESC's engine-torque request). Every command
is a net wheel torque: the wheels' actuators (:mod:`control.wheel_slip`) brake it, with ABS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fourwis.control.reference import reference_yaw_rate, sideslip_bound, weaker_axle_friction
from fourwis.core.checks import check_step, check_vehicle_params
from fourwis.core.types import Command, Estimate

#: the ESC switches on past |r - r_ref| > ENTRY_YAW_ERROR [rad/s] (4 deg/s) or |beta| > ENTRY_SIDESLIP
#: x its bound, and off once both are below the EXIT_* values (hysteresis)
ENTRY_YAW_ERROR = 0.07
EXIT_YAW_ERROR = 0.03
ENTRY_SIDESLIP = 0.6
EXIT_SIDESLIP = 0.4
#: yaw-rate gain [N m per rad/s]: Iz / 0.15 s for the paper's car (a yaw error corrected in ~0.15 s)
YAW_GAIN_TIME = 0.15
SIDESLIP_GAIN = 4.0e4  #: moment per rad of sideslip beyond ENTRY_SIDESLIP x the bound [N m/rad]
ESC_MIN_SPEED = 5.0  #: no intervention below this estimated speed [m/s] (production: ~15-20 km/h)


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

    def reset(self) -> None:
        """Every vehicle off."""
        self.active = np.zeros(0, dtype=bool)

    def __call__(self, t: np.ndarray, estimate: Estimate, front_steer: np.ndarray, base_torques: np.ndarray) -> Command:
        p = self.params
        u, r, beta = (np.asarray(x, dtype=float) for x in (estimate.u, estimate.r, estimate.beta))
        mu, fz = np.asarray(estimate.mu, dtype=float), np.asarray(estimate.fz, dtype=float)
        batch = len(u)
        if self.active.shape != (batch,):
            self.active = np.zeros(batch, dtype=bool)
        r_ref = reference_yaw_rate(u, front_steer, np.repeat(weaker_axle_friction(mu)[:, None], 4, axis=1), p)
        error = r - r_ref
        bound = sideslip_bound(mu)
        moving = u > ESC_MIN_SPEED
        enter = (np.abs(error) > ENTRY_YAW_ERROR) | (np.abs(beta) > ENTRY_SIDESLIP * bound)
        leave = (np.abs(error) < EXIT_YAW_ERROR) & (np.abs(beta) < EXIT_SIDESLIP * bound)
        self.active = moving & ((self.active & ~leave) | enter)
        limit = ENTRY_SIDESLIP * bound
        moment = -p.yaw_inertia / YAW_GAIN_TIME * error + SIDESLIP_GAIN * (beta - np.clip(beta, -limit, limit))
        left = moment > 0.0
        oversteer = moment * r < 0.0
        wheel = np.where(oversteer, np.where(left, 0, 1), np.where(left, 2, 3))  # FL, FR, RL, RR
        half_track = np.where(wheel < 2, p.track_front, p.track_rear) / 2.0
        grip = mu[np.arange(batch), wheel] * fz[np.arange(batch), wheel] * p.wheel_radius
        brake = np.minimum(np.abs(moment) * p.wheel_radius / half_track, np.maximum(grip, 0.0))
        torques = np.array(base_torques, dtype=float, copy=True)
        on = np.flatnonzero(self.active)
        torques[on] = np.minimum(torques[on], 0.0)  # the drive torque request cut
        torques[on, wheel[on]] -= brake[on]
        return Command(torques, np.zeros(batch))

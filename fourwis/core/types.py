"""The contracts every layer shares: what an estimator reads (the sensor channel layout and
:class:`SensorReading`) and returns (:class:`Estimate`), what a controller returns
(:class:`Command`), and the :class:`Estimator` and :class:`Controller` protocols a closed loop
drives."""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np

#: Channel order of every sensor reading (16 channels), the layout estimators read: the
#: accelerometers' specific forces ax, ay [m/s^2] and the gyro's yaw rate [rad/s]; four wheel
#: speeds [rad/s]; four road-wheel steer angles [rad]; four net wheel torques [N m] (drive minus
#: brake: :func:`net_wheel_torque`); and a measured forward speed at the CG [m/s] (a GNSS-aided
#: INS, an optical sensor). Wheels FL, FR, RL, RR. fourwis.envs.sensors produces them from the
#: simulated car's 13 sensors (one steer sensor per axle feeds both of its wheels' channels; it
#: has no forward-speed sensor, whose channel it reports invalid); recorded logs fill what they
#: have (fourwis.training.logs).
CHANNELS = (
    "ax",
    "ay",
    "yaw_rate",
    "omega_fl",
    "omega_fr",
    "omega_rl",
    "omega_rr",
    "delta_fl",
    "delta_fr",
    "delta_rl",
    "delta_rr",
    "torque_fl",
    "torque_fr",
    "torque_rl",
    "torque_rr",
    "speed",
)
N_CHANNELS = len(CHANNELS)
#: the first column of each group of CHANNELS (the wheel groups run FL, FR, RL, RR)
CH_AX, CH_AY, CH_YAW_RATE, CH_OMEGA, CH_DELTA, CH_TORQUE, CH_SPEED = 0, 1, 2, 3, 7, 11, 15
#: the channels that are measurements only (the inertial sensors and the forward speed): an
#: invalid one may hold anything, NaN included. Every other channel is also an input of the
#: estimators' model, which needs a finite value every step (a sensor that is out holds its
#: last value and flags it invalid).
MEASUREMENT_CHANNELS = (CH_AX, CH_AY, CH_YAW_RATE, CH_SPEED)


def net_wheel_torque(drive_torque, brake_pressure=0.0, brake_gain=0.0):
    """The torque channel's quantity, the net torque a wheel's tyre must balance [N m]: the drive
    (motor, or engine through the driveline) ``drive_torque`` [N m] less the friction brake's
    ``brake_gain`` [N m/Pa] x ``brake_pressure`` [Pa] (forward driving: the brake opposes a wheel
    spinning forwards). Arrays broadcast."""
    return np.asarray(drive_torque, dtype=float) - np.asarray(brake_gain, dtype=float) * np.asarray(
        brake_pressure, dtype=float
    )


class SensorReading(NamedTuple):
    """One sample for B vehicles: ``values`` (B, N_CHANNELS) in :data:`CHANNELS` order and units,
    ``valid`` (B, N_CHANNELS) bool (False: a dropout, or a channel the car has no sensor for;
    ``values`` then holds the last good value, or anything on a :data:`MEASUREMENT_CHANNELS`
    channel), times ``t`` (B,) [s] (fourwis's estimators step by the time since the previous
    sample; an empty ``t`` steps by their nominal dt)."""

    values: np.ndarray
    valid: np.ndarray
    t: np.ndarray


class Estimate(NamedTuple):
    """One estimator step's output for a batch of B vehicles (SI units).

    u, v: body velocities [m/s] (B,); beta = atan2(v, |u|) [rad] (B,) (the filters floor |u| at
    1 m/s: a car at rest has no defined sideslip); r: yaw rate [rad/s] (B,); ax, ay: body
    specific forces [m/s^2] (B,) (the joint estimator's are its model's, whose lack of rolling
    resistance and drag reads ~0.1 m/s^2 high on the paper's sine); mu: road friction per wheel
    (B, 4); fz: normal loads per wheel [N] (B, 4); beta_std [rad] (B,) and mu_std (B, 4): the
    filter's own one-sigma uncertainty, from its covariance (zero for the oracle; mu_std also zero
    for the filters that assume a nominal mu). The covariance leaves out the estimation model's
    error, so beta_std is far too confident where the tyres work; the joint estimator's mu_std
    matches its mu error open loop but not just after a friction change nor where the DYC works
    (docs/limitations.md). The DYC plans with mu - k mu_std (control.MU_MARGIN), so an
    estimator's mu_std moves the closed loop (docs/decisions/0026-cautious-friction-margin.md).
    """

    u: np.ndarray
    v: np.ndarray
    beta: np.ndarray
    r: np.ndarray
    ax: np.ndarray
    ay: np.ndarray
    mu: np.ndarray
    fz: np.ndarray
    beta_std: np.ndarray
    mu_std: np.ndarray


class Command(NamedTuple):
    """Controller output for a batch: wheel torques [N m] (B, 4) and rear steer [rad] (B,)."""

    torques: np.ndarray
    rear_steer: np.ndarray


class Controller(Protocol):
    """A stability controller: sees the estimate and the driver's commands, never the truth.

    ``t`` (B,) [s]; ``estimate`` an :class:`Estimate` of B rows; ``front_steer`` (B,) the
    driver's road-wheel angle [rad]; ``base_torques`` (B, 4) the speed-holding driver's wheel
    torques [N m]. Returns the :class:`Command` the wheels and rear servo get."""

    def reset(self) -> None: ...

    def __call__(
        self, t: np.ndarray, estimate: Estimate, front_steer: np.ndarray, base_torques: np.ndarray
    ) -> Command: ...


class Estimator(Protocol):
    """A batched estimator: sensor readings in, estimate out (``needs_truth``: oracle only).

    ``reading`` is a :class:`SensorReading`. ``reset`` (re)initialises the members selected by
    ``mask`` (B,) bool (all if None) from a reading and the initial speed [m/s] (B,) (a car
    starts from a known speed, like a vehicle's speed estimate that has been running since
    standstill); then every reading is stepped, the one reset from first, as ``simulate``, the
    envs and the log replay do (a loop that steps from the second reading runs another filter).
    ``step`` with ``members`` (M,) row indices (the vector env's partial resets)
    steps only those rows: the reading still has all B rows, ``truth`` only the M, and the
    estimate must have M rows. The estimate's mu, mu_std and fz steer the DYC (it plans with a
    cautious mu_hat - k mu_std), so a friction estimator's mu_std should be calibrated; an
    estimator holding a nominal mu keeps mu_hat constant (the reports read a constant mu_hat
    without mu_std as 'not estimated')."""

    needs_truth: bool

    def reset(self, reading: SensorReading, initial_speed: np.ndarray, mask: np.ndarray | None = None) -> None: ...

    def step(
        self, reading: SensorReading, truth: Estimate | None = None, members: np.ndarray | None = None
    ) -> Estimate:
        """Step every vehicle, or only the rows ``members`` (the estimate then has those rows)."""

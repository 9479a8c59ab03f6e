"""State and road-friction estimators on the estimation model, one step interface.

Every estimator here takes a sensor reading (values and valid (B, N_CHANNELS) in the layout of
:data:`fourwis.core.types.CHANNELS`: ax, ay, yaw rate, four wheel speeds, four road-wheel steer
angles, four net wheel torques, a measured forward speed; times t (B,) [s]) and returns a
:class:`fourwis.core.types.Estimate`. Variants (``StateEstimator(kind=...)``):

* ``ekf``: extended Kalman filter (finite-difference Jacobians of the same model), all
  measurements, nominal mu;
* ``ckf``: one cubature Kalman filter, all measurements, nominal mu;
* ``fkf``: federated CKF, sub-filter 1 [ax, ay, r, wheel speeds], sub-filter 2 [ay, r];
* ``alo-fkf``: the paper's section 3: robust (Huber, :data:`HUBER_C`) sub-filters, nominal mu;
* ``joint-paper``: the paper's section 4: the robust state FKF plus a mu FKF (random-walk mu per
  wheel, measured [ax, ay, r] / [ay, r] predicted from the tyre forces) exchanging estimates
  every step, with the deviations below as fourwis shipped it before issue 41;
* ``joint``: ``joint-paper`` with issue 41's fixes: the grip floor (GRIP_FLOOR_TIME_CONSTANT) and,
  from ``make_estimator``, the combined slip from the measured longitudinal force (``ModelParams.force_ellipse``;
  docs/decisions/0034-combined-slip-from-the-measured-force.md).

``estimation.make_estimator`` gives ``alo-fkf``, ``joint-paper`` and ``joint`` the ALO-tuned noise
(estimation/data/tuned_noise.json, written by ``fourwis tune``); a StateEstimator built
directly uses ``noise`` (default: the hand-set :class:`NoiseParams`).

Time: each step advances by the time since the previous sample (the reading's ``t``; a step
within CLOCK_TOLERANCE of the nominal ``dt``, a reading without a time, or one at the previous
one's time takes ``dt`` itself, so a fixed-rate clock keeps the arithmetic of a fixed step; a
time before the previous one is refused). The model integrates it in substeps of at most
MODEL_STEP (2 ms), and the process noise grows with the elapsed time, so a log at 50-1000 Hz,
its jitter and its gaps are coasted through (docs/decisions/0033-recorded-logs.md). A measured
forward speed (the ``speed`` channel, where valid) updates u after the filters' own
measurements (a scalar update with ``speed_std`` noise).

Deviations from the paper, on purpose (where a :class:`StateEstimator` option is named, it restores
the paper's filter):

* wheel speeds: sub-filter 1 also measures the four wheel-centre speeds R*omega (zero-slip model,
  variance allowing 2% slip), as production ESC speed observers do; the paper's [ax, ay, r] leave u
  unobservable (docs/decisions/0010-estimation-model-and-paper-deviations.md);
* held and frozen samples: every estimator first counts a measured channel's reading repeated
  exactly STUCK_SAMPLES times as invalid until it changes (``stuck_samples=math.inf``: off;
  docs/decisions/0019-frozen-sensor-check.md);
* zero point: every estimator learns the lateral accelerometer's offset in steady driving
  (ZERO_POINT_*), as production ESC units do, and subtracts it before filtering
  (``zero_point_time_constant=math.inf``: the raw sensors; docs/decisions/0017-zero-point-learning.md);
* friction gate (``joint``): with Dugoff's lambda >= 1 dF/dmu = 0, so mu is unobservable; a
  wheel's mu is updated only while its lateral lambda at the current estimate is below
  EXCITATION_LAMBDA (all four while any wheel is; the longitudinal slip is left out because Fx is
  measured), not below MU_MIN_SPEED, and its random-walk growth is capped at ``mu_max_std``. The
  covariance still takes the update, so a held mu's reported sigma shrinks slowly without
  excitation. Judged from mu_hat itself, a high mu_hat can keep the gate shut after a friction drop
  (``friction_gate=False``: the paper's update; docs/decisions/0015-friction-gate.md); so
  ``joint`` judges it again a sigma below mu_hat, where mu may then only fall (``gate_sigmas``),
  and opens it, restarting the friction covariance, while the friction filter's low-passed NIS
  says its mu is refuted (``friction_alarm``; docs/decisions/0047-friction-alarm.md);
* slide detection (``joint``): an outward slide in a steady turn that the sensors alone show
  (SLIDE_*) reopens the gate, mu then only allowed to fall (``slide_rate=math.inf``: off;
  docs/decisions/0016-slide-detection.md);
* correlated friction (``joint``): the four mu share a prior and random walk correlated at
  MU_CORRELATION (docs/decisions/0012-friction-correlation.md);
* yaw balance (``joint``): in steady driving state sub-filter 2 also measures the net yaw moment
  Gamma = 0 (YAW_BALANCE_STD), which keeps friction and sideslip from drifting together in a long
  turn at the limit (``yaw_balance_std=math.inf``: off; docs/decisions/0018-yaw-balance.md).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import numba
import numpy as np

from fourwis.core.checks import check_step, is_number, member_rows
from fourwis.core.constants import GRAVITY
from fourwis.core.kernels import JIT, borrowed, dot, matmul, run_parallel, scratch
from fourwis.core.types import (
    CH_AX,
    CH_AY,
    CH_DELTA,
    CH_OMEGA,
    CH_SPEED,
    CH_TORQUE,
    CH_YAW_RATE,
    CHANNELS,
    MEASUREMENT_CHANNELS,
    N_CHANNELS,
    Estimate,
    SensorReading,
)
from fourwis.estimation.ckf import (
    NO_HUBER,
    cholesky,
    cholesky_solve,
    cubature_points,
    innovation,
    innovation_nll,
    measurement_update,
    normalised_innovation,
    predicted_moments,
)
from fourwis.estimation.federated import fuse, sharing_coefficients
from fourwis.estimation.lanes import (
    cubature_points_lanes,
    fuse_lanes,
    measurement_update_lanes,
    predicted_moments_lanes,
    sharing_coefficients_lanes,
)
from fourwis.estimation.model import (
    MIN_SPEED,
    ModelInputs,
    ModelKernel,
    ModelParams,
    axle_tyre,
    body_forces,
    body_forces_lanes,
    dugoff_lambdas,
    fill_steer_trig,
    shared_state_forces_lanes,
    transition,
    transition_lanes,
    wheel_kinematics,
    wheel_loads,
    wheel_trig,
)

N_STATE = 6
I_U, I_V, I_AX, I_AY, I_R, I_GAMMA = range(N_STATE)
KINDS = ("ekf", "ckf", "fkf", "alo-fkf", "joint-paper", "joint")
ROBUST_KINDS = ("alo-fkf", "joint-paper", "joint")  #: the kinds that update with Huber weights (huber_c)
FRICTION_KINDS = ("joint-paper", "joint")  #: the kinds that estimate the friction
#: the kinds make_estimator gives the ALO-tuned noise (estimation/data/tuned_noise.json)
TUNED_KINDS = ("alo-fkf", "joint-paper", "joint")
MU_BOUNDS = (0.1, 1.2)  #: estimated mu stays inside these bounds
EXCITATION_LAMBDA = 1.0  #: a wheel's mu is updated only while its lateral Dugoff lambda is below this
#: below this estimated forward speed [m/s] the friction filter does not run (mu and its
#: covariance are held): slip angles vy / max(|vx|, MIN_SPEED) of a car at rest are sensor noise
#: over a floored speed, which opens the gate and lets mu collapse (docs/decisions/0015-friction-gate.md)
MU_MIN_SPEED = 3.0


#: prior and random-walk correlation of the four wheels' mu (0-1). The contact patches nearly
#: always share one surface and the split between wheels is barely observable (a turn unloads the
#: inner wheels), so a saturating outer wheel informs the inner one; the differential modes keep
#: 1% of the variance, so a real split is learnt where it is excited, slowly
#: (docs/decisions/0012-friction-correlation.md)
MU_CORRELATION = 0.99
#: Huber threshold c of the robust filters (alo-fkf, joint; eq. 27) in standardised innovations:
#: above Huber's 95%-efficiency 1.5, which also down-weights the persistent innovations of a
#: friction change, and still rejecting sensor outliers (docs/decisions/0014-huber-threshold.md)
HUBER_C = 3.0


@numba.njit(inline="always", **JIT)
def _fill_correlated(variance: float, out: np.ndarray) -> None:
    """out (4, 4): ``variance`` on the diagonal and MU_CORRELATION between wheels."""
    for i in range(4):
        for j in range(4):
            out[i, j] = variance * (MU_CORRELATION + (1.0 - MU_CORRELATION) * (1.0 if i == j else 0.0))


def _correlated(variance: float) -> np.ndarray:
    """:func:`_fill_correlated` as a new array."""
    out = np.empty((4, 4))
    _fill_correlated(variance, out)
    return out


NOISE_STEP = 0.002  #: [s] the step NoiseParams' process noise and mu random walk are given per
#: a step whose time since the previous sample is within this fraction of the nominal dt takes
#: the nominal dt (a fixed-rate clock's rounding does not move the results)
CLOCK_TOLERANCE = 1e-6


#: NoiseParams' per-sample sensor noise fields, in the filters' order (FilterNoise.sensor_var)
SENSOR_NOISE = ("ax_std", "ay_std", "gyro_std", "wheel_speed_std", "speed_std")


@dataclass(frozen=True)
class NoiseParams:
    """Filter noise (standard deviations, SI). Process: per 2 ms step (NOISE_STEP; a filter at
    another step scales the variances, StateEstimator.set_noise) on u, v, ax, ay, r, Gamma;
    measurement, per sample: the longitudinal and lateral accelerometers ax_std, ay_std
    [m/s^2] and the gyro gyro_std [rad/s] (sensor noise plus model error), the wheel-speed
    pseudo measurement wheel_speed_std [m/s], a measured forward speed speed_std [m/s]; mu
    random walk per step. ALO tuning rescales these (:meth:`scaled`)."""

    process_std: tuple[float, ...] = (0.01, 0.001, 0.3, 0.3, 0.002, 80.0)
    ax_std: float = 0.15
    ay_std: float = 0.15
    gyro_std: float = 0.005
    wheel_speed_std: float = 0.15
    #: a forward-speed sensor's error [m/s] (hand-set: GNSS Doppler and optical speed sensors
    #: are good to a few cm/s; the simulated car has none)
    speed_std: float = 0.05
    mu_walk_std: float = 2e-3
    #: the mu filter's ax, ay "noise" [m/s^2]: the error of the Dugoff-predicted body
    #: accelerations (model error, correlated in time, far above the accelerometer's); smaller,
    #: the filter over-trusts the model and reads mu high. Chosen by ``fourwis tune --mu-noise``
    #: (docs/decisions/0013-friction-model-error-noise.md)
    mu_accel_std: float = 0.6
    #: each wheel's mu prior sigma (at reset and when a slide restarts the friction filter) and the
    #: cap of its random walk's growth where mu is unobservable
    mu_max_std: float = 0.3

    def __post_init__(self) -> None:
        process = np.asarray(self.process_std, dtype=float)
        if process.ndim not in (1, 2) or process.shape[-1] != N_STATE:
            raise ValueError(
                f"process_std needs {N_STATE} values (u, v, ax, ay, r, Gamma), or (B, {N_STATE}), "
                f"got shape {process.shape}: {self.process_std!r}"
            )
        per_member = SENSOR_NOISE  # (B,) allowed: one per batch member
        # field: (may it be 0, largest ndim); process_std's shape is checked above
        rules = {
            "process_std": (True, 2),
            "mu_walk_std": (True, 0),
            **{name: (False, 1) for name in per_member},
            "mu_accel_std": (False, 0),
            "mu_max_std": (False, 0),
        }
        shapes = {0: " (a scalar)", 1: " (scalar or (B,))", 2: ""}
        with np.errstate(over="ignore"):  # (a standard deviation whose variance overflows is refused)
            for name, (may_be_zero, ndim) in rules.items():
                value = np.asarray(getattr(self, name), dtype=float)
                in_range = value >= 0.0 if may_be_zero else value > 0.0
                if value.ndim > ndim or not np.all(np.isfinite(value**2) & in_range):
                    raise ValueError(
                        f"{name} must be finite and {'>= 0' if may_be_zero else '> 0'}{shapes[ndim]}, "
                        f"got {getattr(self, name)!r}"
                    )
        sizes = {len(process) if process.ndim == 2 else 1} | {
            np.asarray(getattr(self, name)).size for name in per_member
        }
        if len(sizes - {1}) > 1:
            raise ValueError(f"per-member noise fields disagree on the number of members: {sorted(sizes)}")

    def scaled(self, log10_factors: np.ndarray) -> NoiseParams:
        """Scale the noise by 10**factors: (4,) on (process_std, ax_std and ay_std together,
        gyro_std, wheel_speed_std), as ``fourwis tune`` finds them, or (6,) on (process_std,
        ax_std, ay_std, gyro_std, wheel_speed_std, speed_std); (B, 4) or (B, 6) for a batch whose
        members each get their own noise (the scaled fields become arrays: process_std (B, 6),
        the others (B,))."""
        f = 10.0 ** np.asarray(log10_factors, dtype=float)
        if f.shape[-1:] not in ((4,), (6,)) or f.ndim > 2 or not np.all(np.isfinite(f)):
            raise ValueError(
                f"log10 noise factors must be finite with shape (4,), (6,), (B, 4) or (B, 6), got {log10_factors!r}"
            )
        if f.shape[-1] == 4:  # (process, accelerometers, gyro, wheel speed; the speed sensor as it is)
            f = np.concatenate([f[..., :2], f[..., 1:], np.ones(f.shape[:-1] + (1,))], axis=-1)
        if f.ndim == 1:
            return replace(
                self,
                process_std=tuple(float(s * f[0]) for s in self.process_std),
                **{name: getattr(self, name) * f[1 + k] for k, name in enumerate(SENSOR_NOISE)},
            )
        return replace(
            self,
            process_std=np.asarray(self.process_std) * f[:, :1],
            **{name: getattr(self, name) * f[:, 1 + k] for k, name in enumerate(SENSOR_NOISE)},
        )


TUNED_NOISE_FILE = "data/tuned_noise.json"  #: inside the estimation package; written by ``fourwis tune``


def tuned_noise(path=None) -> NoiseParams | None:
    """The tuned noise in ``path`` (default: the package's :data:`TUNED_NOISE_FILE`, shipped with
    the ALO result of ``fourwis tune``); None only if that shipped file does not exist (then
    alo-fkf runs the hand-set noise, as documented in make_estimator). A ``path`` given that is
    not a file raises FileNotFoundError, a corrupted file ValueError naming it: never a silent
    default."""
    if path is not None and not Path(path).is_file():
        raise FileNotFoundError(f"no tuning file {str(path)!r}; `fourwis tune --out {path}` writes one")
    path = resources.files("fourwis.estimation").joinpath(TUNED_NOISE_FILE) if path is None else Path(path)
    if not path.is_file():
        return None
    try:
        factors = np.asarray(json.loads(path.read_text())["log10_factors"], dtype=float)
        return NoiseParams().scaled(factors)
    except (ValueError, KeyError, TypeError) as err:
        raise ValueError(f"corrupted tuning file {path}: {err!r}; rerun `fourwis tune` or delete it") from None


#: batches at least this large step on all cores (:func:`fourwis.core.kernels.run_parallel`)
PARALLEL_MIN_BATCH = 2
#: low-pass of the differentiated wheel speed [s]. The estimators' low-passes (this one, ZERO_POINT_*,
#: SLIDE_TAU) take Euler steps with their gain dt / tau capped at 1, so a step longer than a time
#: constant (a 20 Hz log) follows the input instead of diverging (docs/decisions/0017-zero-point-learning.md)
OMEGA_DOT_TIME_CONSTANT = 0.02
#: plausibility check of the measured channels (HELD_CHANNELS: ax, ay, yaw rate, forward speed
#: and the wheel speeds sub-filter 1 measures): a reading identical to the previous one this
#: many times in a row counts as invalid until it changes. A MEMS sensor's white noise never
#: repeats a value exactly; a frozen output does, and so does a slower sensor's sample held in a
#: faster log: counted again it would make the filter overconfident, so from the first repeat
#: on (docs/decisions/0019-frozen-sensor-check.md, docs/decisions/0033-recorded-logs.md)
STUCK_SAMPLES = 1
#: Zero-point learning of the lateral accelerometer, as production ESC units learn sensor
#: offsets in steady driving (van Zanten, "Bosch ESP systems: 5 years of experience", SAE
#: 2000-01-1633). In steady state v_dot = 0, so ay = u r: while the steering has not moved by
#: more than ZERO_POINT_STEER_TOL [rad] and the yaw rate has stayed within ZERO_POINT_YAW_TOL
#: [rad/s] of its ZERO_POINT_YAW_LOWPASS [s] low-pass for ZERO_POINT_SETTLE [s], above
#: ZERO_POINT_MIN_SPEED [m/s], the residual ay - u r low-passes (ZERO_POINT_TIME_CONSTANT [s])
#: into an offset that every filter subtracts from ay. The residual holds b_ay - u b_r of the two
#: sensors' biases, exactly what makes the sideslip integrated from v_dot = ay - u r drift once the
#: tyres saturate (docs/decisions/0017-zero-point-learning.md).
ZERO_POINT_STEER_TOL = 0.002
ZERO_POINT_YAW_TOL = 0.02
ZERO_POINT_YAW_LOWPASS = 0.5
ZERO_POINT_SETTLE = 1.5
ZERO_POINT_MIN_SPEED = 3.0
ZERO_POINT_TIME_CONSTANT = 2.0
#: Slide detection of the joint estimator (the friction gate's blind spot). In a steady turn
#: (steering held, yaw rate steady: ZP_STEADY) a gripping car keeps its sideslip, so the kinematic
#: sideslip rate ay / u - r that the sensors give without any tyre model stays near zero (the
#: sensors' 3-sigma turn-on biases fake at most 1.4 deg/s of it above SLIDE_MIN_SPEED [m/s]). Its
#: SLIDE_TAU [s] low-pass beyond SLIDE_RATE [rad/s], outwards (ay short of u r), after SLIDE_TAU of
#: steady driving, while the friction gate is shut, means the car slides on a road slipperier than
#: mu_hat: the state filter then follows the accelerometer (ax, ay process noise at least
#: SLIDE_ACCEL_STD [m/s^2] per NOISE_STEP, above the accelerometer's 0.17), and the friction filter
#: restarts from its prior covariance with the gate open, mu only allowed to fall. SLIDE_TAU <
#: ZERO_POINT_SETTLE, so a slide from the start of a steady turn is caught before the zero-point
#: learning starts. False alarm: an accelerometer offset fault of about -1 m/s^2 appearing in a
#: steady turn reads as a slide (docs/decisions/0016-slide-detection.md).
SLIDE_RATE = math.radians(2.0)
SLIDE_TAU = 0.25
SLIDE_ACCEL_STD = 1.0
SLIDE_MIN_SPEED = 5.0
#: Yaw balance in steady driving (the joint estimator's state sub-filter 2). In the steady state
#: the zero-point learning detects (ZERO_POINT_*) the yaw rate does not change, so the tyre forces'
#: net yaw moment is zero: sub-filter 2 then also measures the model's Gamma = 0, with this standard
#: deviation [N m], the yaw acceleration the steady window still allows (|r_dot| up to 0.04 rad/s^2)
#: times I_z (1110 kg m^2). Without it the balance reaches the filters only through the gyro, far
#: under its noise, and in a long turn at the limit friction and sideslip drift together. math.inf:
#: off (the paper's sub-filter 2, [ay, r]). Only the joint estimator measures it: a filter holding a
#: wrong nominal friction cannot meet the balance and ay together (docs/decisions/0018-yaw-balance.md).
YAW_BALANCE_STD = 45.0
#: The grip floor (``joint``): the tyres cannot carry more than the road's friction, so the
#: horizontal acceleration the accelerometers measure bounds it from below, mu >= |a| / (k g) with
#: k the tyres' friction scale (the sum of the four loads is m g whatever the load transfer).
#: |a| is the magnitude of the measured ax, ay (ay less its learnt offset) low-passed over this
#: time constant [s], which takes the sensors' noise (0.17 m/s^2 per sample) to ~0.02 m/s^2;
#: each wheel's mu is kept at or above the floor (a projection of the estimate onto the
#: constraint, its covariance kept: Simon, "Kalman filtering with state constraints", IET CTA
#: 2010). It is what keeps a wrongly low mu from capping the model's lateral force under what the
#: car is measured to carry, which drove the sideslip into both axles' saturation on the fuzz's
#: random-torque case, and keeps a dry road in a 0.4 g turn from reading as an icy one
#: (docs/decisions/0034-combined-slip-from-the-measured-force.md). math.inf: off.
GRIP_FLOOR_TIME_CONSTANT = 0.1
#: The consider term of the sideslip's standard deviation (``joint``, ``consider_std``): the
#: relative error of each axle's modelled lateral force, which the filter's covariance leaves out
#: (it takes the tyre model as exact), propagated to v with mu's own uncertainty
#: (:func:`_considered_v_var`; docs/decisions/0045-friction-and-sideslip-consistency.md). math.inf is
#: not allowed; 0: off (the filter's covariance alone).
CONSIDER_FORCE_STD = 0.05
#: the kinds whose sideslip sigma carries the consider term (alo-fkf and joint-paper: the paper's, as they were)
CONSIDER_KINDS = ("ekf", "ckf", "fkf", "joint")
#: Covariance matching of the wheel-speed pseudo-measurements (``joint``, ``adaptive_time_constant``):
#: their zero-slip model is off by the tyres' longitudinal slip, which drive torques, load transfer
#: and a wheel spinning up make persistent and far above the tuned noise; their noise variance
#: is scaled, wheel by wheel, by the low-passed (this time constant [s]) square of its
#: standardised innovation where it exceeds 1 (Mehra, "Approaches to adaptive filtering", IEEE TAC 17(5),
#: 1972). The inertial channels are left alone: their model error is absorbed by the state, so
#: their innovations stay small while the model is wrong, and scaling them diverged on a real log
#: (docs/decisions/0045-friction-and-sideslip-consistency.md). math.inf: off.
ADAPTIVE_TIME_CONSTANT = 0.5
ADAPTIVE_KINDS = ("joint",)  #: the kinds with the wheel speeds' covariance matching
CONSIDER_V_STEP = 1e-3  #: the finite-difference step of v [m/s per m/s of u]
CONSIDER_MAX_V_STD = 0.35  #: the consider term's cap [m/s per m/s of u]: about 20 deg of sideslip
#: columns of the zero-point state: learnt ay offset [m/s^2], steady time [s], steering angle
#: the steady time counts from [rad], low-passed yaw rate [rad/s], low-passed kinematic
#: sideslip rate ay / u - r [rad/s] (SLIDE_TAU)
ZP_OFFSET, ZP_STEADY, ZP_STEER, ZP_YAW, ZP_SLIDE = range(5)
#: the measurement updates of a step whose NIS the filter state keeps (FilterState.nis): the state
#: filter's sub-filter 1 (or its single filter), sub-filter 2, and the friction filter's two
UPDATES = ("state 1", "state 2", "friction 1", "friction 2")
#: the innovations a step keeps (FilterState.innovation), update by update: state sub-filter 1 (or
#: the single filter) [ax, ay, r, four wheel-centre speeds], state sub-filter 2 [ay, r, Gamma (the
#: yaw balance)], friction sub-filter 1 [ax, ay, r], friction sub-filter 2 [ay, r]
INNOVATIONS = (
    *("state 1 " + c for c in ("ax", "ay", "r", "wheel FL", "wheel FR", "wheel RL", "wheel RR")),
    *("state 2 " + c for c in ("ay", "r", "Gamma")),
    *("friction 1 " + c for c in ("ax", "ay", "r")),
    *("friction 2 " + c for c in ("ay", "r")),
)
N_INNOVATIONS = len(INNOVATIONS)

#: The joint estimator's gate where mu_hat reads the road too high (its blind spot: judged at
#: mu_hat, a turn on a road far slipperier looks far from saturation, so the gate and the steady
#: hold keep mu shut). GATE_SIGMAS: where the gate is shut at mu_hat it is judged again at mu_hat
#: minus this many of mu's sigmas, a friction the filter still finds plausible; opened only there,
#: mu may only fall (the saturation it sees says only that the road is slipperier). FRICTION_ALARM:
#: the friction filter's NIS per degree of freedom, low-passed with FRICTION_ALARM_TIME_CONSTANT
#: [s], above this (several times its level where mu is right: its model-error noise is generous)
#: opens the gate either way, lifts the hold and restarts the friction covariance from its prior
#: (mu_max_std) until the filter explains the sensors again (docs/decisions/0047-friction-alarm.md)
GATE_SIGMAS = 1.0
FRICTION_ALARM = 2.0
FRICTION_ALARM_TIME_CONSTANT = 0.5


# ---- the compiled step's bundles -----------------------------------------------------------
class FilterSettings(NamedTuple):
    """How a :class:`StateEstimator`'s compiled step runs: which parts it has (named flags, from
    its ``kind`` and options) and its numbers (:class:`StateEstimator` documents each)."""

    extended: bool  #: EKF on finite-difference Jacobians (else the cubature rule)
    federated: bool  #: two sub-filters fused (else one filter of all measurements)
    robust: bool  #: Huber-weighted measurement updates (huber_c)
    friction: bool  #: the friction filter runs (else mu is held at its nominal value)
    yaw_balance: bool  #: state sub-filter 2 measures Gamma = 0 in steady driving (yaw_balance_std)
    slide_detection: bool  #: a slide in a steady turn opens the friction gate (slide_rate)
    friction_gate: bool  #: mu is updated only while a tyre's lateral demand makes it observable
    grip_floor: bool  #: mu kept at or above the measured acceleration's (grip_floor_time_constant)
    #: the friction filter's innovation against the model at mu_hat, not its points' mean
    centred_friction: bool
    steady_hold: bool  #: mu held in steady driving, where it is unobservable (steady_hold)
    held_covariance: bool  #: a held mu's covariance takes no update either (HELD_COVARIANCE)
    consider_std: float  #: the sideslip's consider term, each axle's relative force error (0: off)
    adaptive: bool  #: the wheel speeds' noise follows their innovations (adaptive_time_constant)
    adaptive_time_constant: float  #: [s]
    dt: float  #: [s]
    huber_c: float
    zero_point_time_constant: float  #: [s] (inf: no learning)
    stuck_samples: float  #: (inf: no check)
    #: which channel of the reading is the measured forward speed (CH_SPEED), a scalar update of u
    speed_channel: int
    slide_rate: float  #: [rad/s]
    yaw_balance_std: float  #: [N m]
    grip_floor_time_constant: float  #: [s]
    #: the low-passed friction NIS per degree of freedom that opens the gate (inf: off)
    friction_alarm: float
    gate_sigmas: float  #: the gate is judged at mu_hat minus this many of mu's sigmas


class FilterNoise(NamedTuple):
    """The filters' noise variances per step (at the nominal dt): process (M, 6) and sensor (M,
    5: ax, ay, gyro, wheel speed, forward speed) for one member (M = 1) or each (M = B), the
    friction filter's (3,): random walk, acceleration model error, prior."""

    process_var: np.ndarray
    sensor_var: np.ndarray
    mu_var: np.ndarray


class FilterState(NamedTuple):
    """Each vehicle's filter state (leading axis B, float64), which the compiled step updates in
    place: the state x (B, 6) and its covariance P (B, 6, 6), friction mu (B, 4) and P_mu
    (B, 4, 4), the federated sharing coefficients of the state and friction filters (B, 2) each,
    the previous wheel speeds and their low-passed derivative (B, 4), the previous readings of
    the measured channels (HELD_CHANNELS) and how often each repeated (B, 8), the
    zero-point state (B, 5: ZP_*), the latest innovation NLL (B,), the relaxed slip of each tyre
    (B, 4; NaN: not started), the time of the previous reading (B,) [s] (NaN: none), the
    low-passed measured horizontal acceleration of the grip floor (B,) [m/s^2], and the last
    step's innovations and their standard deviations (B, N_INNOVATIONS: INNOVATIONS; NaN where a
    channel had no valid reading or an update did not run) and each update's NIS and its valid
    channel count (B, 4: UPDATES; NaN and 0 where it did not run), for the consistency reports;
    the low-passed squared standardised innovation of each wheel speed (B, 4)
    (ADAPTIVE_TIME_CONSTANT), the consider term's variance of v (B,) [m^2/s^2] (CONSIDER_*) and the
    low-passed NIS per degree of freedom of the friction filter (B,) (FRICTION_ALARM_*)."""

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray
    P_mu: np.ndarray
    beta: np.ndarray
    beta_mu: np.ndarray
    omega_prev: np.ndarray
    omega_dot: np.ndarray
    inertial_prev: np.ndarray
    inertial_repeats: np.ndarray
    zero_point: np.ndarray
    last_nll: np.ndarray
    slip_relaxed: np.ndarray
    t_prev: np.ndarray
    grip_accel: np.ndarray
    innovation: np.ndarray
    innovation_std: np.ndarray
    nis: np.ndarray
    nis_dof: np.ndarray
    wheel_nis: np.ndarray
    consider_var: np.ndarray
    friction_nis: np.ndarray


class FilterKernel(NamedTuple):
    """A :class:`StateEstimator` as its compiled step takes it (:meth:`StateEstimator.kernel`)."""

    settings: FilterSettings
    model: ModelKernel
    noise: FilterNoise
    state: FilterState


class MeasurementInputs(NamedTuple):
    """What the state measurement models need besides the points: the steer table (4, 4) and the model."""

    steer: np.ndarray
    model: ModelKernel


class FrictionInputs(NamedTuple):
    """What the friction filter's measurement model needs besides its points (the mu): the state
    filter's estimate x (6,), the steer table (4, 4), wheel speeds, torques and wheel
    accelerations (4,), the model and the step dt [s]."""

    x: np.ndarray
    steer: np.ndarray
    omega: np.ndarray
    torque: np.ndarray
    omega_dot: np.ndarray
    model: ModelKernel
    dt: float


class ModelArgs(NamedTuple):
    """The inputs of every model one step evaluates: the process model's, the state
    measurements' and the friction measurements'."""

    process: ModelInputs
    measurement: MeasurementInputs
    friction: FrictionInputs


#: status codes of the compiled step
OK, BAD_MEASUREMENT, FILTER_FAILED, BAD_TIME = 0, 1, 2, 3
#: the channels the held-sample check watches: the measurement channels and the wheel speeds
#: (measured by sub-filter 1; as the model's inputs they are used all the same)
HELD_CHANNELS = (*MEASUREMENT_CHANNELS, CH_OMEGA, CH_OMEGA + 1, CH_OMEGA + 2, CH_OMEGA + 3)
N_HELD = len(HELD_CHANNELS)


# ---- measurement models (compiled, from the points (K, n) into out (K, m), row by row) -------------
@numba.njit(inline="always", **JIT)
def measure_state_1(points, k, out, inputs: MeasurementInputs) -> None:
    """State sub-filter 1: [ax, ay, r, wheel-centre speeds along each wheel (4)]."""
    steer, pk = inputs
    u, v, r = points[k, I_U], points[k, I_V], points[k, I_R]
    out[k, 0], out[k, 1], out[k, 2] = points[k, I_AX], points[k, I_AY], r
    for w in range(4):
        out[k, 3 + w] = wheel_kinematics(u, v, r, wheel_trig(steer, w), pk, w)[1]


@numba.njit(inline="always", **JIT)
def measure_state_2(points, k, out, inputs: MeasurementInputs) -> None:
    """State sub-filter 2: [ay, r], and Gamma where out has a third column (the joint estimator's
    yaw balance, YAW_BALANCE_STD)."""
    out[k, 0], out[k, 1] = points[k, I_AY], points[k, I_R]
    if out.shape[1] > 2:
        out[k, 2] = points[k, I_GAMMA]


@numba.njit(inline="always", **JIT)
def _mu_predictions(points: np.ndarray, inputs: FrictionInputs, out: np.ndarray) -> None:
    """[ax, ay, r] predicted by the tyre model with the friction of each row of points (K, 4)
    at the state filter's estimate x (r one step ahead of the previous yaw rate), into the
    rows of out (3, K)."""
    x, steer, omega, torque, omega_dot, pk, dt = inputs
    K = points.shape[0]
    state, mu = scratch((5, K)), scratch((4, K))
    for k in range(K):
        state[0, k], state[1, k], state[2, k], state[3, k], state[4, k] = x[I_U], x[I_V], x[I_R], x[I_AX], x[I_AY]
        for w in range(4):
            mu[w, k] = points[k, w]
    body_forces(state, mu, steer, omega, torque, omega_dot, pk, out)
    r_prev = x[I_R] - dt * x[I_GAMMA] / pk.yaw_inertia
    for k in range(K):
        out[2, k] = r_prev + dt * out[2, k] / pk.yaw_inertia


@numba.njit(inline="always", **JIT)
def random_walk(points, k, out) -> None:
    """mu's process model: held (the random walk is in its Q)."""
    for i in range(points.shape[1]):
        out[k, i] = points[k, i]


#: model ids of the compiled step (numba cannot cache code that passes functions around)
TRANSITION, STATE_1, STATE_2, RANDOM_WALK, MU_1, MU_2 = range(6)


@numba.njit(**JIT)
def _evaluate(model, points, out, args: ModelArgs) -> None:
    """Model ``model`` at every row of points (K, n) into out (K, k) (one dispatch per point
    set, not per point)."""
    K = points.shape[0]
    if model == TRANSITION:
        transition(points, out, args.process)
    elif model == STATE_1:
        for k in range(K):
            measure_state_1(points, k, out, args.measurement)
    elif model == STATE_2:
        for k in range(K):
            measure_state_2(points, k, out, args.measurement)
    elif model == RANDOM_WALK:
        for k in range(K):
            random_walk(points, k, out)
    else:  # the mu sub-filters' measurements: [ax, ay, r] (MU_1) or [ay, r] (MU_2)
        predicted = scratch((3, K))
        _mu_predictions(points, args.friction, predicted)
        first = 0 if model == MU_1 else 1
        for k in range(K):
            for i in range(first, 3):
                out[k, i - first] = predicted[i, k]


@numba.njit(**JIT)
def _ckf_predict(x, P, Q, model, args, x_out, P_out) -> bool:
    """CKF time update through ``model``; False if P is not finite."""
    n = x.shape[0]
    points, moved = scratch((2 * n, n)), scratch((2 * n, n))
    if not cubature_points(x, P, points):
        return False
    _evaluate(model, points, moved, args)
    predicted_moments(moved, Q, x_out, P_out)
    return True


@numba.njit(**JIT)
def _ckf_update(x, P, z, valid, R, huber_c, model, args, x_out, P_out, nu, S, centred=False) -> float:
    """CKF measurement update through ``model``; returns the innovation NLL (NaN on failure) and
    writes the innovation nu (m,) and its covariance S (m, m). ``centred``: the innovation
    against the model at x itself (:func:`measurement_update`'s ``z_centre``), not the points'
    mean."""
    n, m = x.shape[0], z.shape[0]
    if not centred:
        points, Z = scratch((2 * n, n)), scratch((2 * n, m))
        if not cubature_points(x, P, points):
            return math.nan
        _evaluate(model, points, Z, args)
        return measurement_update(x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nu, S, scratch((m,)))
    points, Z = scratch((2 * n + 1, n)), scratch((2 * n + 1, m))
    if not cubature_points(x, P, points[: 2 * n]):
        return math.nan
    points[2 * n] = x
    _evaluate(model, points, Z, args)
    return measurement_update(
        x, P, points[: 2 * n], Z[: 2 * n], z, valid, R, huber_c, x_out, P_out, nu, S, scratch((m,)), Z[2 * n]
    )


@numba.njit(**JIT)
def _federated(
    x,
    P,
    Q,
    beta,
    f_model,
    z1,
    valid1,
    R1,
    h1_model,
    z2,
    valid2,
    R2,
    h2_model,
    huber_c,
    args,
    x_out,
    P_out,
    beta_out,
    nu1,
    S1,
    nu2,
    S2,
    centred=False,
) -> float:
    """One federated cycle (estimation/federated.py) with two sub-filters; returns the summed
    innovation NLL (NaN on failure) and writes each sub-filter's innovation and its covariance
    (nu1, S1, nu2, S2). ``centred``: see :func:`_ckf_update`."""
    n = x.shape[0]
    xs, Ps = scratch((2, n)), scratch((2, n, n))
    x_pred, P_pred = scratch((n,)), scratch((n, n))
    P_shared, Q_shared = scratch((n, n)), scratch((n, n))
    total = 0.0
    for s in range(2):
        for i in range(n):
            for j in range(n):
                P_shared[i, j], Q_shared[i, j] = P[i, j] / beta[s], Q[i, j] / beta[s]
        if not _ckf_predict(x, P_shared, Q_shared, f_model, args, x_pred, P_pred):
            return math.nan
        if s == 0:
            nll = _ckf_update(x_pred, P_pred, z1, valid1, R1, huber_c, h1_model, args, xs[0], Ps[0], nu1, S1, centred)
        else:
            nll = _ckf_update(x_pred, P_pred, z2, valid2, R2, huber_c, h2_model, args, xs[1], Ps[1], nu2, S2, centred)
        if not math.isfinite(nll):
            return math.nan
        total += nll
    confidence = scratch((2,))
    if not fuse(xs, Ps, x_out, P_out, confidence):
        return math.nan
    sharing_coefficients(confidence, beta_out)
    return total


@numba.njit(inline="always", **JIT)
def _fill_diagonal(variances, out: np.ndarray) -> None:
    """out (m, m): the diagonal matrix of ``variances`` (m,) (an array or a tuple)."""
    out[:, :] = 0.0
    for i in range(len(variances)):
        out[i, i] = variances[i]


@numba.njit(**JIT)
def _finite_difference_jacobian(model, x, eps, centre, J, args) -> None:
    """model(x) into centre (m,) and its central-difference Jacobian into J (m, n), steps eps (n,)."""
    n, m = x.shape[0], centre.shape[0]
    probes = scratch((2 * n + 1, n))  # x, then x + eps_k e_k, then x - eps_k e_k
    for k in range(2 * n + 1):
        probes[k] = x
    for k in range(n):
        probes[1 + k, k] += eps[k]
        probes[1 + n + k, k] -= eps[k]
    values = scratch((2 * n + 1, m))
    _evaluate(model, probes, values, args)
    for k in range(n):
        for i in range(m):
            J[i, k] = (values[1 + k, i] - values[1 + n + k, i]) / (2.0 * eps[k])
    centre[:] = values[0]


@numba.njit(**JIT)
def _ekf_step(x, P, Q, z, valid, R, args, x_out, P_out, nu, S) -> float:
    """EKF on the same model (central-difference Jacobians, Joseph-form update); returns the
    innovation negative log-likelihood, as the CKF's update (NaN if S is not positive definite),
    and writes the innovation nu (m,) and its covariance S (m, m)."""
    n, m = x.shape[0], z.shape[0]
    eps = scratch((n,))
    for k in range(n):
        eps[k] = 1e-4 * max(abs(x[k]), 1e-2)
    x_pred, F, FP, P_pred = scratch((n,)), scratch((n, n)), scratch((n, n)), scratch((n, n))
    _finite_difference_jacobian(TRANSITION, x, eps, x_pred, F, args)
    matmul(F, P, FP)
    matmul(FP, F.T, P_pred)
    P_pred += Q
    z_pred, H = scratch((m,)), scratch((m, n))
    _finite_difference_jacobian(STATE_1, x_pred, eps, z_pred, H, args)
    Rv = scratch((m, m))
    m_valid = innovation(z, z_pred, valid, R, nu, Rv)
    PHt, L = scratch((n, m)), scratch((m, m))
    matmul(P_pred, H.T, PHt)
    matmul(H, PHt, S)
    S += Rv
    if not cholesky(S, L):
        return math.nan
    K = scratch((n, m))
    for i in range(n):
        cholesky_solve(L, PHt[i], K[i])
    for i in range(n):
        x_out[i] = x_pred[i] + dot(K[i], nu)
    I_KH, I_KH_P, P_new, KR, KRK = scratch((n, n)), scratch((n, n)), scratch((n, n)), scratch((n, m)), scratch((n, n))
    matmul(K, H, I_KH)
    for i in range(n):
        for j in range(n):
            I_KH[i, j] = (1.0 if i == j else 0.0) - I_KH[i, j]
    matmul(I_KH, P_pred, I_KH_P)
    matmul(I_KH_P, I_KH.T, P_new)
    matmul(K, Rv, KR)
    matmul(KR, K.T, KRK)
    P_new += KRK
    for i in range(n):
        for j in range(n):
            P_out[i, j] = 0.5 * (P_new[i, j] + P_new[j, i])
    return innovation_nll(L, nu, m_valid)


# ---- one estimator step (compiled) -----------------------------------------------------------
@numba.njit(inline="always", **JIT)
def _low_pass(value: float, target: float, dt: float, time_constant: float) -> float:
    """``value`` after one Euler step of ``dt`` [s] of a first-order low-pass towards ``target``,
    the gain dt / ``time_constant`` capped at 1 (see OMEGA_DOT_TIME_CONSTANT; inf: held)."""
    return value + (target - value) * min(dt / time_constant, 1.0)


@numba.njit(inline="always", **JIT)
def _settled(zero_point, speed: float) -> bool:
    """The steady state of the zero-point state (5,) at ``speed`` [m/s]: steering held and yaw
    rate steady for ZERO_POINT_SETTLE s, above ZERO_POINT_MIN_SPEED (ZERO_POINT_*), where ay = u r
    (the offset is learnt) and the net yaw moment is zero (YAW_BALANCE_STD)."""
    return zero_point[ZP_STEADY] > ZERO_POINT_SETTLE and speed > ZERO_POINT_MIN_SPEED


@numba.njit(inline="always", **JIT)
def front_steer(reading) -> float:
    """The mean of the front wheels' road-wheel steer angles [rad] of a reading row (N_CHANNELS,)."""
    return 0.5 * (reading[CH_DELTA] + reading[CH_DELTA + 1])


@numba.njit(**JIT)
def _learn_zero_point(zero_point, reading, valid, speed, dt, time_constant) -> None:
    """Advance the zero-point state (5,) by one reading (see ZERO_POINT_*, SLIDE_*); ``speed`` [m/s];
    ``time_constant`` [s] of the offset's low-pass (inf: no learning)."""
    steer, yaw_rate = front_steer(reading), reading[CH_YAW_RATE]
    moved = not (valid[CH_DELTA] and valid[CH_DELTA + 1]) or abs(steer - zero_point[ZP_STEER]) > ZERO_POINT_STEER_TOL
    if moved:
        zero_point[ZP_STEER] = steer
    if valid[CH_YAW_RATE]:
        zero_point[ZP_YAW] = _low_pass(zero_point[ZP_YAW], yaw_rate, dt, ZERO_POINT_YAW_LOWPASS)
    steady = not moved and valid[CH_YAW_RATE] and abs(yaw_rate - zero_point[ZP_YAW]) < ZERO_POINT_YAW_TOL
    zero_point[ZP_STEADY] = zero_point[ZP_STEADY] + dt if steady else 0.0
    if _settled(zero_point, speed) and valid[CH_AY]:
        residual = reading[CH_AY] - speed * yaw_rate
        zero_point[ZP_OFFSET] = _low_pass(zero_point[ZP_OFFSET], residual, dt, time_constant)
    if speed > SLIDE_MIN_SPEED and valid[CH_AY] and valid[CH_YAW_RATE]:
        rate = (reading[CH_AY] - zero_point[ZP_OFFSET]) / speed - yaw_rate
        zero_point[ZP_SLIDE] = _low_pass(zero_point[ZP_SLIDE], rate, dt, SLIDE_TAU)
    else:  # (no stale value: the rate restarts from zero once it can be measured again)
        zero_point[ZP_SLIDE] = 0.0


@numba.njit(inline="always", **JIT)
def _relax_slip(x, steer, slip_relaxed, pk, dt, relaxed_new) -> None:
    """Advance each wheel's relaxed tan(slip angle) (4,) one step towards the kinematic one at
    the previous estimate x, over its axle's relaxation length (estimation.model), into
    relaxed_new, and write the lag (kinematic less relaxed) into row 3 of the wheel table
    ``steer`` (4, 4). The lag is then held for the whole step: at the filters' predicted state
    and cubature points the slip still moves with v and r one for one, as the instantaneous
    tyre's does (which keeps v observable through ay); only its offset lags. Without a
    relaxation length no lag (row 3 keeps :func:`estimation.model.fill_steer_trig`'s zeros, and
    NaN is kept); on the first step (NaN) the relaxed slip starts at the kinematic one, which
    that zero row lets :func:`wheel_kinematics` give. A wheel rolling slower than MIN_SPEED has
    no lag either (its relaxed slip is the kinematic one): its slip angle is noise over the
    floored speed, which a lag would let the state filter chase (docs/decisions/0045)."""
    for w in range(4):
        sigma = axle_tyre(pk, w).relaxation_length
        if sigma <= 0.0:
            relaxed_new[w] = math.nan
            continue
        tan_kin, along = wheel_kinematics(x[I_U], x[I_V], x[I_R], wheel_trig(steer, w), pk, w)
        relaxed_new[w] = (
            _low_pass(slip_relaxed[w], tan_kin, dt, sigma / abs(along))
            if math.isfinite(slip_relaxed[w]) and abs(along) >= MIN_SPEED
            else tan_kin
        )
        steer[3, w] = tan_kin - relaxed_new[w]


@numba.njit(inline="always", **JIT)
def _is_input(c: int) -> bool:
    """Whether channel c of CHANNELS drives the model (not one of MEASUREMENT_CHANNELS)."""
    return c != CH_AX and c != CH_AY and c != CH_YAW_RATE and c != CH_SPEED


@numba.njit(inline="always", **JIT)
def _speed_update(x, P, z: float, variance: float, huber_c: float) -> float:
    """Scalar measurement update of u by a measured forward speed ``z`` [m/s] with noise
    ``variance`` [m^2/s^2], in place on x (6,) and P (6, 6) (linear: the Kalman update itself;
    Huber-weighted beyond ``huber_c`` standardised innovations, inf: plain); returns its
    innovation negative log-likelihood (NaN if the innovation variance is not positive)."""
    nu = z - x[I_U]
    s = P[I_U, I_U] + variance
    if not s > 0.0:
        return math.nan
    a = abs(nu) / math.sqrt(s)
    if huber_c < math.inf and a > huber_c:
        s = P[I_U, I_U] + variance * a / huber_c
    gain = scratch((N_STATE,))
    for k in range(N_STATE):
        gain[k] = P[k, I_U] / s
    for k in range(N_STATE):
        x[k] += gain[k] * nu
    for a_ in range(N_STATE):
        for b in range(N_STATE):
            P[a_, b] -= gain[a_] * gain[b] * s
    for a_ in range(N_STATE):  # (symmetric to the last bit)
        for b in range(a_ + 1, N_STATE):
            P[b, a_] = P[a_, b]
    return 0.5 * (nu * nu / s + math.log(s) + math.log(2.0 * math.pi))


@numba.njit(**JIT)
def _considered_v_var(x, mu, P_mu, steer, omega, torque, omega_dot, pk, force_std: float) -> float:
    """The variance [m^2/s^2] that the model's error adds to the lateral speed v of the estimate x
    (6,): a consider term (Schmidt) for the tyre-force parameters the filter takes as exact. The
    filter finds v where the model's lateral acceleration ay(v) meets the measured one, so an
    error d ay of the model moves v by d ay / (d ay / d v); the model's error is each axle's force
    off by ``force_std`` of itself (std, relative; the axles' errors independent: (force_std
    ay)^2 / 2 for a car whose axles carry half each) and mu off by its standard deviation
    (the four wheels together, sqrt of P_mu's mean). Near the peak d ay / d v falls to zero and
    the term grows (capped at CONSIDER_MAX_V_STD): there the sensors no longer tell v. The model
    at the five points of :func:`_consider_points`, :func:`_consider_variance` of its ay there."""
    state, mus, out = scratch((5, 5)), scratch((4, 5)), scratch((3, 5))
    h = _consider_points(x, mu, P_mu, state, mus)
    body_forces(state, mus, steer, omega, torque, omega_dot, pk, out)
    return _consider_variance(out[1, 0], out[1, 1], out[1, 2], out[1, 3], out[1, 4], h, x[I_U], force_std)


@numba.njit(inline="always", **JIT)
def _consider_points(x, mu, P_mu, state, mus) -> float:
    """The five model evaluations of :func:`_considered_v_var` into state (5, 5) and mus (4, 5):
    v less and plus the finite-difference step h, the estimate itself, mu plus and less its
    standard deviation; returns h [m/s]."""
    h = CONSIDER_V_STEP * max(abs(x[I_U]), MIN_SPEED)
    sigma_mu = math.sqrt(max((P_mu[0, 0] + P_mu[1, 1] + P_mu[2, 2] + P_mu[3, 3]) / 4.0, 0.0))
    for k in range(5):
        state[0, k], state[1, k], state[2, k], state[3, k], state[4, k] = x[I_U], x[I_V], x[I_R], x[I_AX], x[I_AY]
        for w in range(4):
            mus[w, k] = mu[w]
    state[1, 0] -= h
    state[1, 1] += h
    for w in range(4):
        mus[w, 3] = mu[w] + sigma_mu
        mus[w, 4] = max(mu[w] - sigma_mu, MU_BOUNDS[0])
    return h


@numba.njit(inline="always", **JIT)
def _consider_variance(ay_less, ay_more, ay, ay_mu_more, ay_mu_less, h, u, force_std) -> float:
    """:func:`_considered_v_var` from the model's ay [m/s^2] at its five points
    (:func:`_consider_points`), the step h [m/s] and the forward speed u [m/s]."""
    slope = abs(ay_more - ay_less) / (2.0 * h)
    from_mu = 0.5 * (ay_mu_more - ay_mu_less)
    error_var = 0.5 * (force_std * ay) ** 2 + from_mu * from_mu
    cap = CONSIDER_MAX_V_STD * max(abs(u), MIN_SPEED)
    if error_var >= (cap * slope) ** 2:
        return cap * cap
    return error_var / (slope * slope)


@numba.njit(inline="always", **JIT)
def _record_innovation(nu, S, valid, update: int, first: int, innov, innov_std, nis, dof) -> None:
    """Write one update's innovation nu (m,) and the square roots of its covariance S's diagonal
    into innov, innov_std (N_INNOVATIONS,) from ``first`` on (NaN for a channel without a valid
    reading), and its NIS and valid channel count into nis[update], dof[update]."""
    for k in range(nu.shape[0]):
        innov[first + k] = nu[k] if valid[k] else math.nan
        innov_std[first + k] = math.sqrt(S[k, k]) if valid[k] else math.nan
    value, count = normalised_innovation(nu, S, valid)
    nis[update], dof[update] = value if count > 0 else math.nan, count


class StepWork(NamedTuple):
    """One step of a block of cars between its opening (:func:`_open_step`) and its filters, one row
    per car (leading axis: the block's lanes; a single car's step has one): the step dt [s] and
    its multiple of the nominal one (L,), the readings less the learnt ay offset and their
    validity after the held-sample check (L, N_CHANNELS), the repeat counts (L, N_HELD), the
    advanced zero-point state (L, 5), the grip floor's acceleration (L,), the wheel accelerations
    (L, 4), the wheel table (L, 4, 4), the relaxed slips (L, 4), the state filters' measurements
    and noise (z1 (L, 7), R1 (L, 7, 7); z2, valid2 (L, 3), R2 (L, 3, 3): [ay, r, Gamma], Gamma
    with the yaw balance only), the process noise Q (L, 6, 6) and whether a slide goes unseen by
    the friction gate (L,)."""

    dt: np.ndarray
    elapsed_steps: np.ndarray
    values: np.ndarray
    valid: np.ndarray
    repeats: np.ndarray
    zero_point: np.ndarray
    grip_accel: np.ndarray
    omega_dot: np.ndarray
    steer: np.ndarray
    relaxed: np.ndarray
    z1: np.ndarray
    R1: np.ndarray
    z2: np.ndarray
    valid2: np.ndarray
    R2: np.ndarray
    Q: np.ndarray
    unseen_slide: np.ndarray


class StepResult(NamedTuple):
    """What the filters of a block of cars give, one row per car (leading axis L): the state
    filter's x (L, 6), P (L, 6, 6), sharing coefficients (L, 2), innovation NLL (L,) and its
    sub-filters' innovations and their covariances (nu1 (L, 7), S1 (L, 7, 7), nu2 (L, 3), S2 (L,
    3, 3)); whether the friction filter runs (L,), its inputs (the random walk and the prior
    covariance it starts from (L, 4, 4), the noise R1_mu (L, 3, 3), R2_mu (L, 2, 2)) and its
    fused mu (L, 4), P_mu (L, 4, 4), sharing coefficients (L, 2) and innovations (nu1_mu (L, 3),
    S1_mu (L, 3, 3), nu2_mu (L, 2), S2_mu (L, 2, 2))."""

    x: np.ndarray
    P: np.ndarray
    beta: np.ndarray
    nll: np.ndarray
    nu1: np.ndarray
    S1: np.ndarray
    nu2: np.ndarray
    S2: np.ndarray
    friction: np.ndarray
    walk: np.ndarray
    P_mu_in: np.ndarray
    R1_mu: np.ndarray
    R2_mu: np.ndarray
    mu: np.ndarray
    P_mu: np.ndarray
    beta_mu: np.ndarray
    nu1_mu: np.ndarray
    S1_mu: np.ndarray
    nu2_mu: np.ndarray
    S2_mu: np.ndarray


@numba.njit(inline="always", **JIT)
def _step_work(lanes) -> StepWork:
    """A :class:`StepWork` of ``lanes`` rows on the caller's stack."""
    return StepWork(
        scratch((lanes,)), scratch((lanes,)), scratch((lanes, N_CHANNELS)), scratch((lanes, N_CHANNELS), np.bool_),
        scratch((lanes, N_HELD)), scratch((lanes, 5)), scratch((lanes,)), scratch((lanes, 4)),
        scratch((lanes, 4, 4)), scratch((lanes, 4)), scratch((lanes, 7)), scratch((lanes, 7, 7)),
        scratch((lanes, 3)), scratch((lanes, 3), np.bool_), scratch((lanes, 3, 3)),
        scratch((lanes, N_STATE, N_STATE)), scratch((lanes,), np.bool_),
    )  # fmt: skip


@numba.njit(inline="always", **JIT)
def _step_result(lanes) -> StepResult:
    """A :class:`StepResult` of ``lanes`` rows on the caller's stack."""
    return StepResult(
        scratch((lanes, N_STATE)), scratch((lanes, N_STATE, N_STATE)), scratch((lanes, 2)), scratch((lanes,)),
        scratch((lanes, 7)), scratch((lanes, 7, 7)), scratch((lanes, 3)), scratch((lanes, 3, 3)),
        scratch((lanes,), np.bool_), scratch((lanes, 4, 4)), scratch((lanes, 4, 4)), scratch((lanes, 3, 3)),
        scratch((lanes, 2, 2)), scratch((lanes, 4)), scratch((lanes, 4, 4)), scratch((lanes, 2)),
        scratch((lanes, 3)), scratch((lanes, 3, 3)), scratch((lanes, 2)), scratch((lanes, 2, 2)),
    )  # fmt: skip


@numba.njit(**JIT)
def _open_step(f: FilterKernel, i: int, reading, valid_in, t: float, w: StepWork, lane: int) -> int:
    """The opening of vehicle i's step on its raw ``reading`` and ``valid_in`` (N_CHANNELS,) at
    time ``t`` [s] (NaN: unknown, a step of the nominal dt), into row ``lane`` of ``w``: the step's
    time, the input and held-sample checks, the zero point and slide rate, the grip floor's
    acceleration, the model's inputs and the filters' measurements and noise. Returns OK,
    BAD_TIME or BAD_MEASUREMENT (then the row is not to be used). Reads the state, writes none."""
    settings, pk = f.settings, f.model
    q = i if f.noise.process_var.shape[0] > 1 else 0
    process_var, sensor_var = f.noise.process_var[q], f.noise.sensor_var[q]
    state = f.state
    x, mu = state.x[i], state.mu[i]
    omega_prev, omega_dot, inertial_prev = state.omega_prev[i], state.omega_dot[i], state.inertial_prev[i]
    # the step: the time since the previous reading (the nominal dt where a clock's rounding is all
    # that differs); the noise given per nominal step scales with it
    dt = settings.dt
    if math.isfinite(t) and math.isfinite(state.t_prev[i]):
        elapsed = t - state.t_prev[i]
        if elapsed < 0.0:
            return BAD_TIME
        if elapsed > 0.0 and abs(elapsed - dt) > CLOCK_TOLERANCE * dt:  # (0: a caller without a clock)
            dt = elapsed
    w.dt[lane], w.elapsed_steps[lane] = dt, dt / settings.dt  # (1.0 exactly on a fixed-rate clock)
    for c in range(reading.shape[0]):  # the inputs drive the model, valid or not
        if (valid_in[c] or _is_input(c)) and not math.isfinite(reading[c]):
            return BAD_MEASUREMENT
    valid, repeats = w.valid[lane], w.repeats[lane]
    valid[:], repeats[:] = valid_in, state.inertial_repeats[i]
    for m in range(N_HELD):  # held samples and stuck sensors (StateEstimator.stuck_samples)
        c = HELD_CHANNELS[m]
        repeats[m] = repeats[m] + 1.0 if valid_in[c] and reading[c] == inertial_prev[m] else 0.0
        if repeats[m] >= settings.stuck_samples:
            valid[c] = False
    zero_point_new = w.zero_point[lane]
    zero_point_new[:] = state.zero_point[i]
    _learn_zero_point(zero_point_new, reading, valid, x[I_U], dt, settings.zero_point_time_constant)
    values = w.values[lane]
    values[:] = reading
    values[CH_AY] -= zero_point_new[ZP_OFFSET]
    grip_accel = state.grip_accel[i]
    if valid[CH_AX] and valid[CH_AY]:  # (GRIP_FLOOR_TIME_CONSTANT)
        grip_accel = _low_pass(
            grip_accel, math.hypot(values[CH_AX], values[CH_AY]), dt, settings.grip_floor_time_constant
        )
    w.grip_accel[lane] = grip_accel
    # inputs; wheel angular acceleration for eq. 7: differentiated wheel speed, low-passed
    omega, od = values[CH_OMEGA : CH_OMEGA + 4], w.omega_dot[lane]
    for k in range(4):
        od[k] = _low_pass(omega_dot[k], (omega[k] - omega_prev[k]) / dt, dt, OMEGA_DOT_TIME_CONSTANT)
    steer = w.steer[lane]
    fill_steer_trig(
        (values[CH_DELTA], values[CH_DELTA + 1], values[CH_DELTA + 2], values[CH_DELTA + 3]), steer
    )  # fmt: skip
    _relax_slip(x, steer, state.slip_relaxed[i], pk, dt, w.relaxed[lane])
    ax_var, ay_var, gyro_var, wheel_var = sensor_var[0], sensor_var[1], sensor_var[2], sensor_var[3]
    # sub-filter 1: [ax, ay, r, the wheel-centre speeds R omega] (channels 0-6), sub-filter 2: [ay, r]
    z1, R1 = w.z1[lane], w.R1[lane]
    z1[:3] = values[:3]
    for k in range(4):
        z1[3 + k] = values[CH_OMEGA + k] * pk.wheel_radius
    _fill_diagonal((ax_var, ay_var, gyro_var, wheel_var, wheel_var, wheel_var, wheel_var), R1)
    if settings.adaptive:  # (covariance matching of the wheel speeds: ADAPTIVE_TIME_CONSTANT)
        for k in range(4):
            R1[3 + k, 3 + k] *= max(state.wheel_nis[i, k], 1.0)
    # the state's sub-filter 2: [ay, r], and with the yaw balance Gamma = 0, measured in steady
    # driving (a third channel, invalid otherwise)
    z2, valid2, R2 = w.z2[lane], w.valid2[lane], w.R2[lane]
    z2[0], z2[1], z2[2] = values[CH_AY], values[CH_YAW_RATE], 0.0
    valid2[0], valid2[1], valid2[2] = valid[CH_AY], valid[CH_YAW_RATE], False
    _fill_diagonal((ay_var, gyro_var, 1.0), R2)
    if settings.yaw_balance:
        R2[2, 2] = settings.yaw_balance_std**2
        valid2[2] = _settled(zero_point_new, x[I_U])
    Q = w.Q[lane]
    _fill_diagonal(process_var, Q)
    for k in range(N_STATE):  # (the process noise is per nominal step)
        Q[k, k] *= w.elapsed_steps[lane]
    unseen_slide = False  # (SLIDE_*: sliding in a steady turn while the friction gate is shut)
    outward = -zero_point_new[ZP_SLIDE] * math.copysign(1.0, zero_point_new[ZP_YAW])
    if settings.slide_detection and outward > settings.slide_rate and zero_point_new[ZP_STEADY] > SLIDE_TAU:
        lam_before = scratch((4,))
        dugoff_lambdas(x[I_U], x[I_V], x[I_R], x[I_AX], x[I_AY], mu, steer, omega, pk, lam_before)
        unseen_slide = lam_before.min() >= EXCITATION_LAMBDA
    if unseen_slide:
        accel_floor = SLIDE_ACCEL_STD**2 * dt / NOISE_STEP
        Q[I_AX, I_AX], Q[I_AY, I_AY] = max(Q[I_AX, I_AX], accel_floor), max(Q[I_AY, I_AY], accel_floor)
    w.unseen_slide[lane] = unseen_slide
    return OK


@numba.njit(inline="always", **JIT)
def _model_args(f: FilterKernel, i: int, w: StepWork, lane: int, x_friction) -> ModelArgs:
    """The models' inputs of vehicle i's step (row ``lane`` of ``w``), the friction measurements
    at the state estimate ``x_friction`` (6,)."""
    values, od, steer, pk, dt = w.values[lane], w.omega_dot[lane], w.steer[lane], f.model, w.dt[lane]
    omega, torque = values[CH_OMEGA : CH_OMEGA + 4], values[CH_TORQUE : CH_TORQUE + 4]
    return ModelArgs(
        ModelInputs(f.state.mu[i], steer, omega, torque, od, pk, dt),
        MeasurementInputs(steer, pk),
        FrictionInputs(x_friction, steer, omega, torque, od, pk, dt),
    )


@numba.njit(**JIT)
def _state_filter(f: FilterKernel, i: int, w: StepWork, lane: int, res: StepResult) -> int:
    """Vehicle i's state filter (its kind's: federated, EKF or CKF) on row ``lane`` of ``w``,
    car by car, into row ``lane`` of ``res``; OK or FILTER_FAILED."""
    settings = f.settings
    state = f.state  # (on its own: numba loses writes through a NamedTuple unpacked from a tuple)
    x, P, beta = state.x[i], state.P[i], state.beta[i]
    x_new, P_new, beta_new = res.x[lane], res.P[lane], res.beta[lane]
    beta_new[:] = beta
    # (the friction measurements at the previous estimate: the state filter does not evaluate them)
    args = _model_args(f, i, w, lane, x)
    valid1 = w.valid[lane, :7]
    nu1, S1 = res.nu1[lane], res.S1[lane]
    if settings.federated:
        m2 = 3 if settings.yaw_balance else 2
        z2, valid2, R2 = scratch((m2,)), scratch((m2,), np.bool_), scratch((m2, m2))
        nu2, S2 = scratch((m2,)), scratch((m2, m2))
        z2[:], valid2[:], R2[:, :] = w.z2[lane, :m2], w.valid2[lane, :m2], w.R2[lane, :m2, :m2]
        huber_c = settings.huber_c if settings.robust else NO_HUBER
        nll = _federated(
            x, P, w.Q[lane], beta, TRANSITION, w.z1[lane], valid1, w.R1[lane], STATE_1, z2, valid2, R2, STATE_2,
            huber_c, args, x_new, P_new, beta_new, nu1, S1, nu2, S2,
        )  # fmt: skip
        res.nu2[lane, :m2], res.S2[lane, :m2, :m2] = nu2, S2
    elif settings.extended:
        nll = _ekf_step(x, P, w.Q[lane], w.z1[lane], valid1, w.R1[lane], args, x_new, P_new, nu1, S1)
    else:
        x_pred, P_pred = scratch((6,)), scratch((6, 6))
        if not _ckf_predict(x, P, w.Q[lane], TRANSITION, args, x_pred, P_pred):
            return FILTER_FAILED
        nll = _ckf_update(
            x_pred, P_pred, w.z1[lane], valid1, w.R1[lane], NO_HUBER, STATE_1, args, x_new, P_new, nu1, S1
        )
    res.nll[lane] = nll
    return OK if math.isfinite(nll) else FILTER_FAILED


@numba.njit(inline="always", **JIT)
def _friction_alarm(f: FilterKernel, i: int) -> bool:
    """Whether vehicle i's low-passed friction NIS per degree of freedom says its mu is refuted
    (FRICTION_ALARM_*)."""
    return f.state.friction_nis[i] > f.settings.friction_alarm


@numba.njit(**JIT)
def _after_state(f: FilterKernel, i: int, w: StepWork, lane: int, res: StepResult) -> int:
    """After vehicle i's state filter (row ``lane`` of ``res``): the measured forward speed's update,
    whether its friction filter runs, and that filter's noise and starting covariance; OK or
    FILTER_FAILED."""
    settings, mu_var = f.settings, f.noise.mu_var
    x_new, P_new = res.x[lane], res.P[lane]
    q = i if f.noise.sensor_var.shape[0] > 1 else 0
    sensor_var = f.noise.sensor_var[q]
    values, valid = w.values[lane], w.valid[lane]
    if valid[settings.speed_channel]:  # a measured forward speed
        huber_c = settings.huber_c if settings.robust else NO_HUBER
        res.nll[lane] += _speed_update(x_new, P_new, values[settings.speed_channel], sensor_var[4], huber_c)
        if not math.isfinite(res.nll[lane]):
            return FILTER_FAILED
    res.friction[lane] = settings.friction and x_new[I_U] > MU_MIN_SPEED
    if res.friction[lane]:
        gyro_var = sensor_var[2]
        _fill_correlated(mu_var[0] * w.elapsed_steps[lane], res.walk[lane])
        _fill_diagonal((mu_var[1], mu_var[1], gyro_var), res.R1_mu[lane])
        _fill_diagonal((mu_var[1], gyro_var), res.R2_mu[lane])
        # restart from the prior covariance (mu_max_std) on a slide or the friction alarm
        if w.unseen_slide[lane] or _friction_alarm(f, i):
            _fill_correlated(mu_var[2], res.P_mu_in[lane])
        else:
            res.P_mu_in[lane] = f.state.P_mu[i]
    return OK


@numba.njit(**JIT)
def _friction_filter(f: FilterKernel, i: int, w: StepWork, lane: int, res: StepResult) -> int:
    """Vehicle i's friction filter, car by car, into row ``lane`` of ``res``; OK or FILTER_FAILED."""
    settings = f.settings
    state = f.state  # (on its own: numba loses writes through a NamedTuple unpacked from a tuple)
    values, valid = w.values[lane], w.valid[lane]
    args = _model_args(f, i, w, lane, res.x[lane])
    nll_mu = _federated(
        state.mu[i], res.P_mu_in[lane], res.walk[lane], state.beta_mu[i], RANDOM_WALK, values[: CH_YAW_RATE + 1],
        valid[: CH_YAW_RATE + 1], res.R1_mu[lane], MU_1, values[CH_AY : CH_YAW_RATE + 1],
        valid[CH_AY : CH_YAW_RATE + 1], res.R2_mu[lane], MU_2, settings.huber_c, args, res.mu[lane], res.P_mu[lane],
        res.beta_mu[lane], res.nu1_mu[lane], res.S1_mu[lane], res.nu2_mu[lane], res.S2_mu[lane],
        settings.centred_friction,
    )  # fmt: skip
    return OK if math.isfinite(nll_mu) else FILTER_FAILED


@numba.njit(**JIT)
def _close_step(f: FilterKernel, i: int, reading, valid_in, t: float, w: StepWork, lane: int, res: StepResult) -> None:
    """The close of vehicle i's step after its filters (rows ``lane`` of ``w`` and ``res``): the
    innovations and their NIS, the friction gate, bounds, grip floor and the cap of its random walk,
    and the commit of its state rows (then :func:`_estimate_row`)."""
    settings, pk, mu_var = f.settings, f.model, f.noise.mu_var
    state = f.state  # (on its own: numba loses writes through a NamedTuple unpacked from a tuple)
    x, P, mu, P_mu = state.x[i], state.P[i], state.mu[i], state.P_mu[i]
    values, valid, dt = w.values[lane], w.valid[lane], w.dt[lane]
    zero_point_new, steer, od = w.zero_point[lane], w.steer[lane], w.omega_dot[lane]
    omega = values[CH_OMEGA : CH_OMEGA + 4]
    x_new, unseen_slide = res.x[lane], w.unseen_slide[lane]
    # the innovations and their NIS (INNOVATIONS, UPDATES), NaN where an update did not run
    innov, innov_std, nis, dof = scratch((N_INNOVATIONS,)), scratch((N_INNOVATIONS,)), scratch((4,)), scratch((4,))
    innov[:], innov_std[:], nis[:], dof[:] = math.nan, math.nan, math.nan, 0.0
    _record_innovation(res.nu1[lane], res.S1[lane], valid[:7], 0, 0, innov, innov_std, nis, dof)
    if settings.federated:
        m2 = 3 if settings.yaw_balance else 2
        _record_innovation(
            res.nu2[lane, :m2], res.S2[lane, :m2, :m2], w.valid2[lane, :m2], 1, 7, innov, innov_std, nis, dof
        )
    mu_new, P_mu_new, beta_mu_new = scratch((4,)), scratch((4, 4)), scratch((2,))
    mu_new[:], P_mu_new[:, :], beta_mu_new[:] = mu, P_mu, state.beta_mu[i]
    if res.friction[lane]:
        valid2 = valid[CH_AY : CH_YAW_RATE + 1]
        _record_innovation(res.nu1_mu[lane], res.S1_mu[lane], valid[: CH_YAW_RATE + 1], 2, 10, innov, innov_std,
                           nis, dof)  # fmt: skip
        _record_innovation(res.nu2_mu[lane], res.S2_mu[lane], valid2, 3, 13, innov, innov_std, nis, dof)
        ran = dof[2] + dof[3]
        if ran > 0:  # (FRICTION_ALARM_*)
            ratio = ((nis[2] if dof[2] > 0 else 0.0) + (nis[3] if dof[3] > 0 else 0.0)) / ran
            state.friction_nis[i] = _low_pass(state.friction_nis[i], ratio, dt, FRICTION_ALARM_TIME_CONSTANT)
        alarm = _friction_alarm(f, i)
        mu_fused, P_fused, P_mu_in, walk = res.mu[lane], res.P_mu[lane], res.P_mu_in[lane], res.walk[lane]
        beta_mu_new[:] = res.beta_mu[lane]
        # hold mu where the lateral demand is far from saturation (lambda >= EXCITATION_LAMBDA);
        # the covariance keeps the update (see the module docstring)
        lam = scratch((4,))
        dugoff_lambdas(x_new[I_U], x_new[I_V], x_new[I_R], x_new[I_AX], x_new[I_AY], mu, steer, omega, pk, lam)
        excited, falls_only = lam.min() < EXCITATION_LAMBDA, False
        if not excited and settings.gate_sigmas > 0.0:  # (judged a sigma lower, mu may only fall: GATE_SIGMAS)
            mu_gate = scratch((4,))
            for k in range(4):
                mu_gate[k] = max(mu[k] - settings.gate_sigmas * math.sqrt(P_mu[k, k]), MU_BOUNDS[0])
            dugoff_lambdas(x_new[I_U], x_new[I_V], x_new[I_R], x_new[I_AX], x_new[I_AY], mu_gate, steer, omega, pk, lam)
            excited = falls_only = lam.min() < EXCITATION_LAMBDA
        steady_hold = settings.steady_hold and _settled(zero_point_new, x_new[I_U]) and not alarm
        if (excited and not steady_hold) or unseen_slide or alarm or not settings.friction_gate:
            for k in range(4):
                mu_new[k] = min(max(mu_fused[k], MU_BOUNDS[0]), MU_BOUNDS[1])
                # (a slide, or a saturation only a lower friction explains, tells only that the
                # road is slipperier than mu_hat)
                if unseen_slide or (falls_only and not alarm):
                    mu_new[k] = min(mu_new[k], mu[k])
        elif settings.held_covariance:  # (HELD_COVARIANCE)
            for a_ in range(4):
                for b_ in range(4):
                    P_fused[a_, b_] = P_mu_in[a_, b_] + (0.0 if steady_hold else walk[a_, b_])
        if settings.grip_floor:  # (GRIP_FLOOR_TIME_CONSTANT)
            for k in range(4):
                floor = w.grip_accel[lane] / (GRAVITY * axle_tyre(pk, k).mu_scale)
                mu_new[k] = max(mu_new[k], min(floor, MU_BOUNDS[1]))
        # cap the random walk's growth where mu is unobservable
        scale = scratch((4,))
        for k in range(4):
            scale[k] = math.sqrt(min(P_fused[k, k], mu_var[2]) / max(P_fused[k, k], 1e-300))
        for a in range(4):
            for b in range(4):
                P_mu_new[a, b] = P_fused[a, b] * scale[a] * scale[b]
    # commit
    x[:], P[:, :], state.beta[i] = x_new, res.P[lane], res.beta[lane]
    mu[:], P_mu[:, :], state.beta_mu[i] = mu_new, P_mu_new, beta_mu_new
    state.omega_prev[i], state.omega_dot[i] = omega, od
    state.inertial_repeats[i] = w.repeats[lane]
    state.zero_point[i] = zero_point_new
    state.slip_relaxed[i] = w.relaxed[lane]
    for m in range(N_HELD):
        if valid_in[HELD_CHANNELS[m]]:
            state.inertial_prev[i, m] = reading[HELD_CHANNELS[m]]
    if math.isfinite(t):
        state.t_prev[i] = t
    state.grip_accel[i] = w.grip_accel[lane]
    state.innovation[i], state.innovation_std[i], state.nis[i], state.nis_dof[i] = innov, innov_std, nis, dof
    if settings.adaptive:
        for k in range(4):
            if math.isfinite(innov[3 + k]):  # (its squared standardised innovation, of the unscaled noise)
                ratio = (innov[3 + k] / innov_std[3 + k]) ** 2 * max(state.wheel_nis[i, k], 1.0)
                state.wheel_nis[i, k] = _low_pass(state.wheel_nis[i, k], ratio, dt, settings.adaptive_time_constant)


@numba.njit(**JIT)
def _estimate_row(f: FilterKernel, i: int, consider_var: float, out: Estimate, j: int) -> None:
    """Vehicle i's estimate from its committed state into row j of ``out``, its sideslip sigma with
    the consider term's variance ``consider_var`` [m^2/s^2] of v (:func:`_considered_v_var`; kept
    in the state, unused where the kind has none)."""
    settings = f.settings
    state = f.state  # (on its own: numba loses writes through a NamedTuple unpacked from a tuple)
    x, P, mu, P_mu = state.x[i], state.P[i], state.mu[i], state.P_mu[i]
    u, v = x[I_U], x[I_V]
    out.u[j], out.v[j], out.r[j], out.ax[j], out.ay[j] = u, v, x[I_R], x[I_AX], x[I_AY]
    speed = max(abs(u), MIN_SPEED)  # sideslip of a car at rest: lateral speed over a floored speed
    out.beta[j] = math.atan2(v, speed)
    denom = speed * speed + v * v
    grad_u = 0.0 if abs(u) < MIN_SPEED else (-v if u >= 0.0 else v) / denom
    grad_v = speed / denom
    beta_var = grad_u**2 * P[I_U, I_U] + 2 * grad_u * grad_v * P[I_U, I_V] + grad_v**2 * P[I_V, I_V]
    if settings.consider_std > 0.0:  # (CONSIDER_*)
        state.consider_var[i] = consider_var
        beta_var += grad_v**2 * consider_var
    out.beta_std[j] = math.sqrt(max(beta_var, 0.0))
    wheel_loads(x[I_AX], x[I_AY], f.model, out.fz[j])
    for k in range(4):
        out.mu[j, k] = mu[k]
        out.mu_std[j, k] = math.sqrt(P_mu[k, k]) if settings.friction else 0.0


@numba.njit(**JIT)
def _step_vehicle(f: FilterKernel, i: int, reading, valid_in, t: float, out: Estimate, j: int) -> tuple[int, float]:
    """One step of vehicle i's filters (:class:`FilterKernel` ``f``) on its raw sensor ``reading``
    and ``valid_in`` (N_CHANNELS,) taken at time ``t`` [s] (NaN: unknown, a step of the nominal
    dt); its state rows are updated in place only on success. Returns (status, innovation NLL)
    and writes the estimate into row j of ``out``. The block step (:func:`_step_block`) runs the
    same opening and close around its filters in lanes."""
    w, res = _step_work(1), _step_result(1)
    status = _open_step(f, i, reading, valid_in, t, w, 0)
    if status == OK:
        status = _state_filter(f, i, w, 0, res)
    if status == OK:
        status = _after_state(f, i, w, 0, res)
    if status == OK and res.friction[0]:
        status = _friction_filter(f, i, w, 0, res)
    if status != OK:
        return status, math.nan
    _close_step(f, i, reading, valid_in, t, w, 0, res)
    consider_var = 0.0
    if f.settings.consider_std > 0.0:
        state = f.state
        values = w.values[0]
        consider_var = _considered_v_var(
            state.x[i], state.mu[i], state.P_mu[i], w.steer[0], values[CH_OMEGA : CH_OMEGA + 4],
            values[CH_TORQUE : CH_TORQUE + 4], w.omega_dot[0], f.model, f.settings.consider_std,
        )  # fmt: skip
    _estimate_row(f, i, consider_var, out, j)
    return OK, res.nll[0]


@numba.njit(**JIT)
def step_vehicle(f: FilterKernel, i: int, reading: SensorReading, out: Estimate, j: int) -> int:
    """Vehicle i's filter step on row i of ``reading`` (values and valid (B, N_CHANNELS), times
    (B,), or none: an empty t steps by the nominal dt), its estimate into row j of ``out``;
    returns the status (OK, BAD_MEASUREMENT, FILTER_FAILED, BAD_TIME). Its ``last_nll`` turns
    NaN on a failure (the state rows stay as they were)."""
    t = reading.t[i] if reading.t.shape[0] > 0 else math.nan
    status, nll = _step_vehicle(f, i, reading.values[i], reading.valid[i], t, out, j)
    f.state.last_nll[i] = nll if status == OK else math.nan
    return status


# ---- the step of a block of cars in SIMD lanes -------------------------------------------------
#: cars per block of the lane step (its SIMD lanes: at 64 LLVM packs the lane loops into vectors,
#: at 16 or 32 it unrolls them into scalar code; docs/decisions/0046-lane-estimator.md)
LANES = 64
#: a block of fewer cars than this steps car by car (:func:`_step_vehicle`): the lanes' fixed cost
#: (all LANES lanes run) outweighs their speed below it (docs/decisions/0046-lane-estimator.md)
MIN_LANE_CARS = 8
N_POINTS = 2 * N_STATE  #: the state filter's cubature points
N_MU = 4  #: the friction filter's states (one mu per wheel)
N_MU_POINTS = 2 * N_MU  #: the friction filter's cubature points


class LaneArgs(NamedTuple):
    """What the models of a block of cars need besides their points (lane axis last): each car's
    friction mu (4, lanes) (the state filter's), wheel table steer (4, 4, lanes), wheel speeds,
    torques and wheel accelerations (4, lanes), the model, the step dt (lanes,) [s] and the state
    estimate x (6, lanes) the friction filter's measurements are evaluated at."""

    mu: np.ndarray
    steer: np.ndarray
    omega: np.ndarray
    torque: np.ndarray
    omega_dot: np.ndarray
    model: ModelKernel
    dt: np.ndarray
    x: np.ndarray


@numba.njit(**JIT)
def _evaluate_lanes(model, points, out, args: LaneArgs, K, lanes) -> None:
    """:func:`_evaluate` in lanes: model ``model`` at the K points (K, n, lanes) of each car into
    out (K, k, lanes), each point the same operations as the single car's (K and lanes
    compile-time constants: the work arrays stay on the stack)."""
    pk = args.model
    if model == TRANSITION:
        transition_lanes(
            points, out, args.mu, args.steer, args.omega, args.torque, args.omega_dot, pk, args.dt, K, lanes
        )
    elif model == STATE_1:
        steer = args.steer
        for k in range(K):
            for lane in range(lanes):
                u, v, r = points[k, I_U, lane], points[k, I_V, lane], points[k, I_R, lane]
                out[k, 0, lane], out[k, 1, lane], out[k, 2, lane] = points[k, I_AX, lane], points[k, I_AY, lane], r
                for w in range(4):
                    trig = (steer[0, w, lane], steer[1, w, lane], steer[2, w, lane], steer[3, w, lane])
                    out[k, 3 + w, lane] = wheel_kinematics(u, v, r, trig, pk, w)[1]
    elif model == STATE_2:
        for k in range(K):
            for lane in range(lanes):
                out[k, 0, lane], out[k, 1, lane] = points[k, I_AY, lane], points[k, I_R, lane]
            if out.shape[1] > 2:
                for lane in range(lanes):
                    out[k, 2, lane] = points[k, I_GAMMA, lane]
    elif model == RANDOM_WALK:
        for k in range(K):
            for i in range(points.shape[1]):
                for lane in range(lanes):
                    out[k, i, lane] = points[k, i, lane]
    else:  # the mu sub-filters' measurements (_mu_predictions): [ax, ay, r] (MU_1) or [ay, r] (MU_2)
        x, dt = args.x, args.dt
        state, mu, predicted = scratch((5, 1, lanes)), scratch((4, K, lanes)), scratch((3, K, lanes))
        for lane in range(lanes):  # (one state for the K points: their operating points taken once)
            state[0, 0, lane], state[1, 0, lane], state[2, 0, lane] = x[I_U, lane], x[I_V, lane], x[I_R, lane]
            state[3, 0, lane], state[4, 0, lane] = x[I_AX, lane], x[I_AY, lane]
        for k in range(K):
            for w in range(4):
                for lane in range(lanes):
                    mu[w, k, lane] = points[k, w, lane]
        shared_state_forces_lanes(state, mu, args.steer, args.omega, args.torque, args.omega_dot, pk, predicted, lanes)
        first = 0 if model == MU_1 else 1
        for k in range(K):
            for lane in range(lanes):
                r_prev = x[I_R, lane] - dt[lane] * x[I_GAMMA, lane] / pk.yaw_inertia
                predicted[2, k, lane] = r_prev + dt[lane] * predicted[2, k, lane] / pk.yaw_inertia
            for i in range(first, 3):
                for lane in range(lanes):
                    out[k, i - first, lane] = predicted[i, k, lane]


@numba.njit(**JIT)
def _ckf_predict_lanes(x, P, Q, model, args, x_out, P_out, ok, n, K, lanes) -> None:
    """:func:`_ckf_predict` of each lane (K = 2n points); ok (lanes,) False where P has no factor."""
    points, moved = scratch((K, n, lanes)), scratch((K, n, lanes))
    cubature_points_lanes(x, P, points, ok, n, lanes)
    _evaluate_lanes(model, points, moved, args, K, lanes)
    predicted_moments_lanes(moved, Q, x_out, P_out, n, lanes)


@numba.njit(**JIT)
def _ckf_update_lanes(x, P, z, valid, R, huber_c, model, args, x_out, P_out, nu, S, nll, ok, centred, n, m, K,
                      lanes) -> None:  # fmt: skip
    """:func:`_ckf_update` of each lane (K = 2n points): its innovation nu (m, lanes), covariance S
    (m, m, lanes) and NLL (lanes,), NaN and ok False where it fails; ``centred``: the innovation
    against the model at x (its value there is one evaluation more, the same as the single car's
    extra point)."""
    points, Z, ok_points = scratch((K, n, lanes)), scratch((K, m, lanes)), scratch((lanes,), np.bool_)
    cubature_points_lanes(x, P, points, ok_points, n, lanes)
    _evaluate_lanes(model, points, Z, args, K, lanes)
    if centred:
        centre, Z_centre = scratch((1, n, lanes)), scratch((1, m, lanes))
        for i in range(n):
            for lane in range(lanes):
                centre[0, i, lane] = x[i, lane]
        _evaluate_lanes(model, centre, Z_centre, args, 1, lanes)
        measurement_update_lanes(x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nll, ok, n, m, lanes, nu, S,
                                 Z_centre[0])  # fmt: skip
    else:
        measurement_update_lanes(x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nll, ok, n, m, lanes, nu, S)
    for lane in range(lanes):
        ok[lane] = ok[lane] and ok_points[lane]
        nll[lane] = nll[lane] if ok_points[lane] else math.nan


@numba.njit(**JIT)
def _federated_lanes(
    x, P, Q, beta, f_model, z1, valid1, R1, h1_model, z2, valid2, R2, h2_model, huber_c, args, x_out, P_out,
    beta_out, nu1, S1, nu2, S2, nll, ok, centred, n, m1, m2, K, lanes,
) -> None:  # fmt: skip
    """:func:`_federated` of each lane (estimation/lanes.py's arithmetic): the summed innovation NLL
    into nll (lanes,), NaN and ok (lanes,) False where the cycle fails."""
    xs, Ps = scratch((2, n, lanes)), scratch((2, n, n, lanes))
    x_pred, P_pred = scratch((n, lanes)), scratch((n, n, lanes))
    P_shared, Q_shared = scratch((n, n, lanes)), scratch((n, n, lanes))
    total, each, each_ok = scratch((lanes,)), scratch((lanes,)), scratch((lanes,), np.bool_)
    for lane in range(lanes):
        total[lane], ok[lane] = 0.0, True
    for s in range(2):
        for i in range(n):
            for j in range(n):
                for lane in range(lanes):
                    P_shared[i, j, lane] = P[i, j, lane] / beta[s, lane]
                    Q_shared[i, j, lane] = Q[i, j, lane] / beta[s, lane]
        _ckf_predict_lanes(x, P_shared, Q_shared, f_model, args, x_pred, P_pred, each_ok, n, K, lanes)
        for lane in range(lanes):
            ok[lane] = ok[lane] and each_ok[lane]
        if s == 0:
            _ckf_update_lanes(x_pred, P_pred, z1, valid1, R1, huber_c, h1_model, args, xs[0], Ps[0], nu1, S1, each,
                              each_ok, centred, n, m1, K, lanes)  # fmt: skip
        else:
            _ckf_update_lanes(x_pred, P_pred, z2, valid2, R2, huber_c, h2_model, args, xs[1], Ps[1], nu2, S2, each,
                              each_ok, centred, n, m2, K, lanes)  # fmt: skip
        for lane in range(lanes):
            ok[lane] = ok[lane] and each_ok[lane]
            total[lane] += each[lane]
    confidence = scratch((2, lanes))
    fuse_lanes(xs, Ps, x_out, P_out, confidence, each_ok, n, lanes)
    sharing_coefficients_lanes(confidence, beta_out, lanes)
    for lane in range(lanes):
        ok[lane] = ok[lane] and each_ok[lane]
        nll[lane] = total[lane] if ok[lane] else math.nan


@numba.njit(inline="always", **JIT)
def _to_lane(z_row, valid_row, R_row, z, valid, R, lane: int, m: int) -> None:
    """A car's measurement z_row, valid_row (m,) and noise R_row (m, m) into lane ``lane`` of z,
    valid (m, lanes) and R (m, m, lanes)."""
    for a in range(m):
        z[a, lane], valid[a, lane] = z_row[a], valid_row[a]
        for b in range(m):
            R[a, b, lane] = R_row[a, b]


@numba.njit(inline="always", **JIT)
def _inputs_to_lane(w: StepWork, g: int, steer, omega, torque, od, dt, lane: int) -> None:
    """Row g of ``w``'s model inputs (wheel table, wheel speeds, torques and accelerations, dt)
    into lane ``lane`` of steer (4, 4, lanes), omega, torque, od (4, lanes) and dt (lanes,)."""
    for k in range(4):
        od[k, lane] = w.omega_dot[g, k]
        omega[k, lane], torque[k, lane] = w.values[g, CH_OMEGA + k], w.values[g, CH_TORQUE + k]
        for a in range(4):
            steer[a, k, lane] = w.steer[g, a, k]
    dt[lane] = w.dt[g]


@numba.njit(**JIT)
def _state_filters_lanes(f: FilterKernel, car, source, w: StepWork, res: StepResult, ok, lanes) -> None:
    """The federated state filter of the vehicles car (lanes,) in lanes, lane ``lane`` on row
    ``source[lane]`` of ``w`` (a lane whose opening failed takes another's, its results unused),
    into the rows of ``res``; ok (lanes,) False where it fails."""
    settings, pk = f.settings, f.model
    state = f.state
    x, P, Q, beta = (
        scratch((N_STATE, lanes)),
        scratch((N_STATE, N_STATE, lanes)),
        scratch((N_STATE, N_STATE, lanes)),
        scratch((2, lanes)),
    )
    z1, valid1, R1 = scratch((7, lanes)), scratch((7, lanes), np.bool_), scratch((7, 7, lanes))
    z2, valid2, R2 = scratch((3, lanes)), scratch((3, lanes), np.bool_), scratch((3, 3, lanes))
    mu, steer, omega, torque = scratch((4, lanes)), scratch((4, 4, lanes)), scratch((4, lanes)), scratch((4, lanes))
    od, dt = scratch((4, lanes)), scratch((lanes,))
    for lane in range(lanes):
        g = source[lane]
        i = car[g]
        for a in range(N_STATE):
            x[a, lane] = state.x[i, a]
            for b in range(N_STATE):
                P[a, b, lane], Q[a, b, lane] = state.P[i, a, b], w.Q[g, a, b]
        beta[0, lane], beta[1, lane] = state.beta[i, 0], state.beta[i, 1]
        _to_lane(w.z1[g], w.valid[g], w.R1[g], z1, valid1, R1, lane, 7)
        _to_lane(w.z2[g], w.valid2[g], w.R2[g], z2, valid2, R2, lane, 3)
        for k in range(4):
            mu[k, lane] = state.mu[i, k]
        _inputs_to_lane(w, g, steer, omega, torque, od, dt, lane)
    args = LaneArgs(mu, steer, omega, torque, od, pk, dt, x)
    x_new, P_new, beta_new = scratch((N_STATE, lanes)), scratch((N_STATE, N_STATE, lanes)), scratch((2, lanes))
    nu1, S1, nll = scratch((7, lanes)), scratch((7, 7, lanes)), scratch((lanes,))
    huber_c = settings.huber_c if settings.robust else NO_HUBER
    m2 = 3 if settings.yaw_balance else 2
    nu2, S2 = scratch((3, lanes)), scratch((3, 3, lanes))
    if settings.yaw_balance:
        _federated_lanes(
            x, P, Q, beta, TRANSITION, z1, valid1, R1, STATE_1, z2, valid2, R2, STATE_2, huber_c, args, x_new, P_new,
            beta_new, nu1, S1, nu2, S2, nll, ok, False, N_STATE, 7, 3, N_POINTS, lanes,
        )  # fmt: skip
    else:
        z2b, valid2b, R2b, nu2b, S2b = (
            scratch((2, lanes)), scratch((2, lanes), np.bool_), scratch((2, 2, lanes)), scratch((2, lanes)),
            scratch((2, 2, lanes)),
        )  # fmt: skip
        for a in range(2):
            for lane in range(lanes):
                z2b[a, lane], valid2b[a, lane] = z2[a, lane], valid2[a, lane]
            for b in range(2):
                for lane in range(lanes):
                    R2b[a, b, lane] = R2[a, b, lane]
        _federated_lanes(
            x, P, Q, beta, TRANSITION, z1, valid1, R1, STATE_1, z2b, valid2b, R2b, STATE_2, huber_c, args, x_new,
            P_new, beta_new, nu1, S1, nu2b, S2b, nll, ok, False, N_STATE, 7, 2, N_POINTS, lanes,
        )  # fmt: skip
        for a in range(2):
            for lane in range(lanes):
                nu2[a, lane] = nu2b[a, lane]
            for b in range(2):
                for lane in range(lanes):
                    S2[a, b, lane] = S2b[a, b, lane]
    for lane in range(lanes):
        for a in range(N_STATE):
            res.x[lane, a] = x_new[a, lane]
            for b in range(N_STATE):
                res.P[lane, a, b] = P_new[a, b, lane]
        res.beta[lane, 0], res.beta[lane, 1], res.nll[lane] = beta_new[0, lane], beta_new[1, lane], nll[lane]
        for a in range(7):
            res.nu1[lane, a] = nu1[a, lane]
            for b in range(7):
                res.S1[lane, a, b] = S1[a, b, lane]
        for a in range(m2):
            res.nu2[lane, a] = nu2[a, lane]
            for b in range(m2):
                res.S2[lane, a, b] = S2[a, b, lane]


@numba.njit(**JIT)
def _friction_filters_lanes(f: FilterKernel, car, source, w: StepWork, res: StepResult, ok, lanes) -> None:
    """The friction filter of the vehicles car (lanes,) in lanes, lane ``lane`` on row
    ``source[lane]`` of ``w`` and ``res`` (one whose friction filter runs), into the rows of
    ``res``; ok (lanes,) False where it fails."""
    settings, pk = f.settings, f.model
    state = f.state
    mu, P_mu, walk, beta = (
        scratch((N_MU, lanes)),
        scratch((N_MU, N_MU, lanes)),
        scratch((N_MU, N_MU, lanes)),
        scratch((2, lanes)),
    )
    z1, valid1, R1 = scratch((3, lanes)), scratch((3, lanes), np.bool_), scratch((3, 3, lanes))
    z2, valid2, R2 = scratch((2, lanes)), scratch((2, lanes), np.bool_), scratch((2, 2, lanes))
    x, steer, omega, torque = (
        scratch((N_STATE, lanes)),
        scratch((4, 4, lanes)),
        scratch((4, lanes)),
        scratch((4, lanes)),
    )
    od, dt = scratch((4, lanes)), scratch((lanes,))
    for lane in range(lanes):
        g = source[lane]
        i = car[g]
        for a in range(N_MU):
            mu[a, lane] = state.mu[i, a]
            for b in range(N_MU):
                P_mu[a, b, lane], walk[a, b, lane] = res.P_mu_in[g, a, b], res.walk[g, a, b]
        beta[0, lane], beta[1, lane] = state.beta_mu[i, 0], state.beta_mu[i, 1]
        _to_lane(w.values[g], w.valid[g], res.R1_mu[g], z1, valid1, R1, lane, 3)
        _to_lane(w.values[g, CH_AY:], w.valid[g, CH_AY:], res.R2_mu[g], z2, valid2, R2, lane, 2)
        for a in range(N_STATE):
            x[a, lane] = res.x[g, a]
        _inputs_to_lane(w, g, steer, omega, torque, od, dt, lane)
    args = LaneArgs(mu, steer, omega, torque, od, pk, dt, x)
    mu_new, P_new, beta_new = scratch((N_MU, lanes)), scratch((N_MU, N_MU, lanes)), scratch((2, lanes))
    nu1, S1, nu2, S2, nll = (
        scratch((3, lanes)),
        scratch((3, 3, lanes)),
        scratch((2, lanes)),
        scratch((2, 2, lanes)),
        scratch((lanes,)),
    )
    _federated_lanes(
        mu, P_mu, walk, beta, RANDOM_WALK, z1, valid1, R1, MU_1, z2, valid2, R2, MU_2, settings.huber_c, args, mu_new,
        P_new, beta_new, nu1, S1, nu2, S2, nll, ok, settings.centred_friction, N_MU, 3, 2, N_MU_POINTS, lanes,
    )  # fmt: skip
    for lane in range(lanes):
        for a in range(N_MU):
            res.mu[lane, a] = mu_new[a, lane]
            for b in range(N_MU):
                res.P_mu[lane, a, b] = P_new[a, b, lane]
        res.beta_mu[lane, 0], res.beta_mu[lane, 1] = beta_new[0, lane], beta_new[1, lane]
        for a in range(3):
            res.nu1_mu[lane, a] = nu1[a, lane]
            for b in range(3):
                res.S1_mu[lane, a, b] = S1[a, b, lane]
        for a in range(2):
            res.nu2_mu[lane, a] = nu2[a, lane]
            for b in range(2):
                res.S2_mu[lane, a, b] = S2[a, b, lane]


@numba.njit(**JIT)
def _considered_v_var_lanes(f: FilterKernel, car, source, w: StepWork, out, lanes) -> None:
    """:func:`_considered_v_var` of the vehicles car (lanes,) at their committed state, lane
    ``lane`` on row ``source[lane]`` of ``w``, into out (lanes,): the model's five evaluations in
    lanes, each the single car's operations."""
    pk = f.model
    state = f.state
    points, mus, forces = scratch((5, 5, lanes)), scratch((4, 5, lanes)), scratch((3, 5, lanes))
    steer, omega, torque, od, dt, h = (
        scratch((4, 4, lanes)), scratch((4, lanes)), scratch((4, lanes)), scratch((4, lanes)), scratch((lanes,)),
        scratch((lanes,)),
    )  # fmt: skip
    one, one_mu = scratch((5, 5)), scratch((4, 5))
    for lane in range(lanes):
        g = source[lane]
        i = car[g]
        h[lane] = _consider_points(state.x[i], state.mu[i], state.P_mu[i], one, one_mu)
        for k in range(5):
            for a in range(5):
                points[a, k, lane] = one[a, k]
            for a in range(4):
                mus[a, k, lane] = one_mu[a, k]
        _inputs_to_lane(w, g, steer, omega, torque, od, dt, lane)
    body_forces_lanes(points, mus, steer, omega, torque, od, pk, forces, lanes)
    for lane in range(lanes):
        ay = forces[1, :, lane]
        out[lane] = _consider_variance(
            ay[0], ay[1], ay[2], ay[3], ay[4], h[lane], state.x[car[source[lane]], I_U], f.settings.consider_std
        )


@numba.njit(**JIT)
def _step_block(f: FilterKernel, rows, count: int, reading: SensorReading, out: Estimate, out_rows, status, nll,
                lanes) -> None:  # fmt: skip
    """One step of the vehicles rows[:count] (count <= lanes; a federated kind) with their
    filters in SIMD lanes: each vehicle's reading from its row of ``reading``, its estimate into
    row out_rows[j] of ``out``, its status into status[j] and its innovation NLL into nll[j] (NaN
    on a failure, whose state rows stay as they were). The same opening and close as
    :func:`_step_vehicle`'s, car by car, around the same filter arithmetic in lanes: each
    vehicle's results equal its single-car step's. Lanes beyond count repeat a vehicle, their
    results unused."""
    w, res = _step_work(lanes), _step_result(lanes)
    car, source, ok = scratch((lanes,), np.int64), scratch((lanes,), np.int64), scratch((lanes,), np.bool_)
    codes = scratch((lanes,), np.int64)
    first = -1
    for lane in range(lanes):
        i = rows[min(lane, count - 1)]
        car[lane] = i
        t = reading.t[i] if reading.t.shape[0] > 0 else math.nan
        codes[lane] = _open_step(f, i, reading.values[i], reading.valid[i], t, w, lane)
        if codes[lane] == OK and first < 0:
            first = lane
    if first >= 0:
        for lane in range(lanes):
            source[lane] = lane if codes[lane] == OK else first
        _state_filters_lanes(f, car, source, w, res, ok, lanes)
        first = -1
        for lane in range(count):
            if codes[lane] == OK:
                codes[lane] = _after_state(f, car[lane], w, lane, res) if ok[lane] else FILTER_FAILED
            if codes[lane] == OK and res.friction[lane] and first < 0:
                first = lane
        if first >= 0:
            for lane in range(lanes):
                source[lane] = lane if lane < count and codes[lane] == OK and res.friction[lane] else first
            _friction_filters_lanes(f, car, source, w, res, ok, lanes)
            for lane in range(count):
                if codes[lane] == OK and res.friction[lane] and not ok[lane]:
                    codes[lane] = FILTER_FAILED
    first = -1
    for lane in range(count):
        i = car[lane]
        status[lane], nll[lane] = codes[lane], math.nan
        if codes[lane] == OK:
            t = reading.t[i] if reading.t.shape[0] > 0 else math.nan
            _close_step(f, i, reading.values[i], reading.valid[i], t, w, lane, res)
            nll[lane] = res.nll[lane]
            first = lane if first < 0 else first
    if first < 0:
        return
    consider_var = scratch((lanes,))
    if f.settings.consider_std > 0.0:
        for lane in range(lanes):
            source[lane] = lane if lane < count and codes[lane] == OK else first
        _considered_v_var_lanes(f, car, source, w, consider_var, lanes)
    for lane in range(count):
        if codes[lane] == OK:
            _estimate_row(f, car[lane], consider_var[lane], out, out_rows[lane])


@numba.njit(**JIT)
def step_vehicles(f: FilterKernel, rows, count: int, reading: SensorReading, out: Estimate, out_rows, status) -> None:
    """:func:`step_vehicle` of the vehicles rows[:count], vehicle rows[j]'s estimate into row
    out_rows[j] of ``out`` and its status into status[j]: a federated kind in blocks of LANES cars
    in SIMD lanes (:func:`_step_block`), a block of fewer than MIN_LANE_CARS and the other kinds
    car by car; the same results either way."""
    block_rows, block_out, block_status, nll = (
        scratch((LANES,), np.int64), scratch((LANES,), np.int64), scratch((LANES,), np.int64), scratch((LANES,)),
    )  # fmt: skip
    for lo in range(0, count, LANES):
        n = min(LANES, count - lo)
        if not f.settings.federated or n < MIN_LANE_CARS:
            for j in range(lo, lo + n):
                status[j] = step_vehicle(f, rows[j], reading, out, out_rows[j])
            continue
        for j in range(n):
            block_rows[j], block_out[j] = rows[lo + j], out_rows[lo + j]
        _step_block(f, block_rows, n, reading, out, block_out, block_status, nll, LANES)
        for j in range(n):
            status[lo + j] = block_status[j]
            f.state.last_nll[block_rows[j]] = nll[j]


@numba.njit(nogil=True, **JIT)
def _step_blocks(blocks, rows, f: FilterKernel, reading: SensorReading, out: Estimate, status) -> None:
    """:func:`step_vehicles` of the vehicles rows[j] into row j of ``out`` and ``status``, for the
    j of each block b of ``blocks`` (j from b LANES, LANES of them: one block of lanes each;
    every bundle :func:`fourwis.core.kernels.borrowed` for the call)."""
    f, reading, out = borrowed((f, reading, out))
    positions = scratch((LANES,), np.int64)
    for b in blocks:
        lo = b * LANES
        n = min(LANES, rows.shape[0] - lo)
        for j in range(n):
            positions[j] = lo + j
        step_vehicles(f, rows[lo : lo + n], n, reading, out, positions, status[lo : lo + n])


@numba.njit(nogil=True, **JIT)
def _step_rows(positions, rows, f: FilterKernel, reading: SensorReading, out: Estimate, status) -> None:
    """:func:`step_vehicles` of the vehicles rows[j] into row j of ``out`` and ``status``, for j in
    ``positions`` (consecutive; every bundle :func:`fourwis.core.kernels.borrowed` for the call)."""
    f, reading, out = borrowed((f, reading, out))
    n = positions.shape[0]
    lo = positions[0] if n else 0
    step_vehicles(f, rows[lo : lo + n], n, reading, out, positions, status[lo : lo + n])


class Diagnostics(NamedTuple):
    """What a replay (:meth:`StateEstimator.replay` with ``diagnostics``) keeps of every step
    besides the estimate, for NEES and NIS: the covariance of (u, v, r) (T, B, 3, 3) [SI] (the
    filter's, with the consider term on v: what its beta_std reports, CONSIDER_*) and of
    the four mu (T, B, 4, 4), the innovations and their standard deviations (T, B,
    N_INNOVATIONS: :data:`INNOVATIONS`, NaN where a channel had no valid reading or an update did
    not run) and each update's NIS and valid channel count (T, B, 4: :data:`UPDATES`)."""

    P_state: np.ndarray
    P_mu: np.ndarray
    innovation: np.ndarray
    innovation_std: np.ndarray
    nis: np.ndarray
    nis_dof: np.ndarray


#: the rows and columns of the state covariance a Diagnostics keeps: u, v, r
STATE_NEES = (I_U, I_V, I_R)


@numba.njit(inline="always", **JIT)
def _keep_diagnostics(state: FilterState, b: int, k: int, diagnostics: Diagnostics) -> None:
    """Row (k, b) of ``diagnostics`` from vehicle b's filter state after a step."""
    for i in range(3):
        for j in range(3):
            diagnostics.P_state[k, b, i, j] = state.P[b, STATE_NEES[i], STATE_NEES[j]]
    diagnostics.P_state[k, b, 1, 1] += state.consider_var[b]  # (the sigma the estimate reports)
    diagnostics.P_mu[k, b] = state.P_mu[b]
    diagnostics.innovation[k, b] = state.innovation[b]
    diagnostics.innovation_std[k, b] = state.innovation_std[b]
    diagnostics.nis[k, b] = state.nis[b]
    diagnostics.nis_dof[k, b] = state.nis_dof[b]


@numba.njit(nogil=True, **JIT)
def _replay_members(
    members, f: FilterKernel, values, valid, t, out: Estimate, record: bool, nll, status, at, diagnostics: Diagnostics
) -> None:
    """Each vehicle b of ``members`` through every sample k of a log (values, valid (T,
    N_CHANNELS), t (T,)), from its state as it stands: the estimate of step k into row k B + b of
    ``out`` if ``record`` (else row b), and into ``diagnostics`` where its arrays have T rows (else
    none), the summed innovation NLL into nll[b]; a failure stops b at its step at[b] with its
    status[b]. Every bundle is :func:`fourwis.core.kernels.borrowed` for the call."""
    f, out, diagnostics = borrowed((f, out, diagnostics))
    B = f.state.x.shape[0]
    keep = diagnostics.nis.shape[0] == values.shape[0]
    for b in members:
        for k in range(values.shape[0]):
            code, step_nll = _step_vehicle(f, b, values[k], valid[k], t[k], out, k * B + b if record else b)
            f.state.last_nll[b] = step_nll if code == OK else math.nan
            if code != OK:
                status[b], at[b] = code, k
                break
            nll[b] += step_nll
            if keep:
                _keep_diagnostics(f.state, b, k, diagnostics)


class Replay(NamedTuple):
    """A log replayed through a batch of B filters (:meth:`StateEstimator.replay`): the estimate
    of every step (fields (T, B), per wheel (T, B, 4); None unless recorded), each member's summed
    innovation NLL (B,), where a member's filter failed: its status (B,) (OK: it did not) and
    the step (B,) (-1: none), and the :class:`Diagnostics` of every step (None unless asked)."""

    estimate: Estimate | None
    nll: np.ndarray
    status: np.ndarray
    failed_at: np.ndarray
    diagnostics: Diagnostics | None = None


def empty_diagnostics(steps: int, batch: int) -> Diagnostics:
    """A :class:`Diagnostics` of ``steps`` x ``batch`` rows (NaN-filled: a failed member's rows stay NaN)."""
    return Diagnostics(
        np.full((steps, batch, 3, 3), np.nan),
        np.full((steps, batch, 4, 4), np.nan),
        np.full((steps, batch, N_INNOVATIONS), np.nan),
        np.full((steps, batch, N_INNOVATIONS), np.nan),
        np.full((steps, batch, len(UPDATES)), np.nan),
        np.zeros((steps, batch, len(UPDATES))),
    )


def empty_estimate(batch: int) -> Estimate:
    """An :class:`Estimate` of ``batch`` rows of uninitialised float64 arrays, to write into: the
    rows of two blocks, (7, B) and (3, B, 4), each C-contiguous (two allocations instead of ten:
    a single car's step pays for each)."""
    u, v, beta, r, ax, ay, beta_std = np.empty((7, batch))
    mu, fz, mu_std = np.empty((3, batch, 4))
    return Estimate(u, v, beta, r, ax, ay, mu, fz, beta_std, mu_std)


@dataclass
class StateEstimator:
    """Batched estimator of ``kind`` (see module doc) for model ``params`` at step ``dt`` [s].

    One compiled step (numba) per call: every vehicle's filters run in compiled code, on every
    thread of numba's thread count for batches of PARALLEL_MIN_BATCH or more. The state is
    :attr:`state` (a :class:`FilterState`, leading axis B, updated in place), which callers may
    snapshot and restore (with arrays of the same kind)."""

    params: ModelParams
    kind: str = "joint"
    dt: float = 0.002
    noise: NoiseParams = field(default_factory=NoiseParams)
    nominal_mu: float = 0.8
    huber_c: float = HUBER_C
    #: low-pass time constant [s] of the accelerometer zero-point learning (ZERO_POINT_*);
    #: math.inf switches the learning off (the paper's filters take the sensors as they are)
    zero_point_time_constant: float = ZERO_POINT_TIME_CONSTANT
    #: identical inertial readings in a row taken for a frozen sensor (STUCK_SAMPLES); math.inf
    #: switches the check off, for noise-free or coarsely quantised readings, which repeat a
    #: value without being frozen
    stuck_samples: float = STUCK_SAMPLES
    #: the joint estimator's slide detection threshold [rad/s] (SLIDE_*); math.inf switches it
    #: off (the paper's joint estimator, whose friction gate can stay shut after a drop)
    slide_rate: float = SLIDE_RATE
    #: the joint estimator's yaw-balance pseudo-measurement in steady driving, its standard
    #: deviation [N m] (YAW_BALANCE_STD); math.inf switches it off (the paper's sub-filter 2)
    yaw_balance_std: float = YAW_BALANCE_STD
    #: the joint estimator's friction gate: mu is updated only while a wheel's lateral Dugoff
    #: lambda is below EXCITATION_LAMBDA (the module docstring); False updates it every step, as
    #: the paper's joint estimator does, so that mu follows model error where it is unobservable
    friction_gate: bool = True
    #: the joint estimator's grip floor: the time constant [s] of the measured acceleration that
    #: bounds mu from below (GRIP_FLOOR_TIME_CONSTANT); math.inf switches it off (as joint-paper)
    grip_floor_time_constant: float = GRIP_FLOOR_TIME_CONSTANT
    #: the joint estimator's steady hold: mu is held (mean and covariance) while the steering and
    #: yaw rate are steady (ZERO_POINT_*), where the friction is unobservable; False updates it
    #: there too, where it drifted along with the sideslip (as joint-paper)
    steady_hold: bool = True
    #: the relative error [-] of each axle's modelled lateral force in the sideslip sigma's consider
    #: term (CONSIDER_FORCE_STD, the kinds CONSIDER_KINDS); 0 switches it off
    consider_std: float = CONSIDER_FORCE_STD
    #: the time constant [s] of the wheel speeds' covariance matching (ADAPTIVE_TIME_CONSTANT,
    #: the kinds ADAPTIVE_KINDS); math.inf switches it off
    adaptive_time_constant: float = ADAPTIVE_TIME_CONSTANT
    #: the joint estimator's friction alarm: the low-passed NIS per degree of freedom of the
    #: friction filter (FRICTION_ALARM_*) above which mu is updated whatever the gate and the
    #: steady hold say; math.inf switches it off
    friction_alarm: float = FRICTION_ALARM
    #: the joint estimator's gate is judged at mu_hat minus this many of mu's sigmas
    #: (GATE_SIGMAS); 0 judges it at mu_hat
    gate_sigmas: float = GATE_SIGMAS
    needs_truth: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown estimator kind {self.kind!r}; known: {list(KINDS)}")
        if not (is_number(self.nominal_mu) and MU_BOUNDS[0] <= self.nominal_mu <= MU_BOUNDS[1]):
            raise ValueError(f"nominal_mu must lie in {MU_BOUNDS}, got {self.nominal_mu!r}")
        check_step(self.dt)
        if not (is_number(self.huber_c) and self.huber_c > 0):
            raise ValueError(f"huber_c must be > 0, got {self.huber_c!r}")
        if self.huber_c != HUBER_C and self.kind not in ROBUST_KINDS:
            raise ValueError(
                f"huber_c applies to the robust estimators {list(ROBUST_KINDS)}; {self.kind!r} updates "
                f"without Huber weighting, got huber_c={self.huber_c!r}"
            )
        if not (is_number(self.stuck_samples) and self.stuck_samples >= 1):
            raise ValueError(f"stuck_samples must be >= 1 (math.inf: off), got {self.stuck_samples!r}")
        if not (is_number(self.slide_rate) and self.slide_rate > 0):
            raise ValueError(f"slide_rate must be > 0 [rad/s] (math.inf: off), got {self.slide_rate!r}")
        if not (is_number(self.yaw_balance_std) and self.yaw_balance_std > 0):
            raise ValueError(f"yaw_balance_std must be > 0 [N m] (math.inf: off), got {self.yaw_balance_std!r}")
        if self.yaw_balance_std != YAW_BALANCE_STD and self.kind not in FRICTION_KINDS:
            raise ValueError(
                f"yaw_balance_std applies to the joint estimator; {self.kind!r} has no friction "
                f"filter to balance, got yaw_balance_std={self.yaw_balance_std!r}"
            )
        if not isinstance(self.friction_gate, bool):
            raise ValueError(f"friction_gate must be True or False, got {self.friction_gate!r}")
        if not self.friction_gate and self.kind not in FRICTION_KINDS:
            raise ValueError(f"friction_gate applies to the joint estimator; {self.kind!r} holds a nominal mu")
        if not (is_number(self.zero_point_time_constant) and self.zero_point_time_constant > 0):
            raise ValueError(f"zero_point_time_constant must be > 0 [s], got {self.zero_point_time_constant!r}")
        if not (is_number(self.grip_floor_time_constant) and self.grip_floor_time_constant > 0):
            raise ValueError(
                f"grip_floor_time_constant must be > 0 [s] (math.inf: off), got {self.grip_floor_time_constant!r}"
            )
        if self.grip_floor_time_constant != GRIP_FLOOR_TIME_CONSTANT and self.kind != "joint":
            raise ValueError(
                f"grip_floor_time_constant applies to the joint estimator; {self.kind!r} has none, "
                f"got grip_floor_time_constant={self.grip_floor_time_constant!r}"
            )
        if not isinstance(self.steady_hold, bool):
            raise ValueError(f"steady_hold must be True or False, got {self.steady_hold!r}")
        if not self.steady_hold and self.kind != "joint":
            raise ValueError(f"steady_hold applies to the joint estimator; {self.kind!r} has none")
        if not (is_number(self.consider_std) and 0.0 <= self.consider_std < math.inf):
            raise ValueError(f"consider_std must be finite and >= 0 (0: off), got {self.consider_std!r}")
        if self.consider_std != CONSIDER_FORCE_STD and self.kind not in CONSIDER_KINDS:
            raise ValueError(
                f"consider_std applies to {list(CONSIDER_KINDS)}; {self.kind!r} reports its filter's sigma "
                f"as the paper's, got consider_std={self.consider_std!r}"
            )
        if not (is_number(self.adaptive_time_constant) and self.adaptive_time_constant > 0):
            raise ValueError(
                f"adaptive_time_constant must be > 0 [s] (math.inf: off), got {self.adaptive_time_constant!r}"
            )
        if self.adaptive_time_constant != ADAPTIVE_TIME_CONSTANT and self.kind not in ADAPTIVE_KINDS:
            raise ValueError(
                f"adaptive_time_constant applies to {list(ADAPTIVE_KINDS)}; {self.kind!r} has none, "
                f"got adaptive_time_constant={self.adaptive_time_constant!r}"
            )
        if not (is_number(self.friction_alarm) and self.friction_alarm > 0):
            raise ValueError(f"friction_alarm must be > 0 (math.inf: off), got {self.friction_alarm!r}")
        if not (is_number(self.gate_sigmas) and 0 <= self.gate_sigmas < math.inf):
            raise ValueError(f"gate_sigmas must be finite and >= 0, got {self.gate_sigmas!r}")
        if (self.friction_alarm, self.gate_sigmas) != (FRICTION_ALARM, GATE_SIGMAS) and self.kind != "joint":
            raise ValueError(
                f"friction_alarm and gate_sigmas apply to the joint estimator; {self.kind!r} has neither, got "
                f"friction_alarm={self.friction_alarm!r}, gate_sigmas={self.gate_sigmas!r}"
            )
        friction = self.kind in FRICTION_KINDS
        self.settings = FilterSettings(
            extended=self.kind == "ekf",
            federated=self.kind in ("fkf", "alo-fkf", *FRICTION_KINDS),
            robust=self.kind in ROBUST_KINDS,
            friction=friction,
            yaw_balance=friction and self.yaw_balance_std < math.inf,
            slide_detection=friction and self.slide_rate < math.inf,
            friction_gate=bool(self.friction_gate),
            grip_floor=self.kind == "joint" and self.grip_floor_time_constant < math.inf,
            centred_friction=self.kind == "joint",
            steady_hold=self.kind == "joint" and self.steady_hold,
            held_covariance=self.kind == "joint",
            consider_std=float(self.consider_std) if self.kind in CONSIDER_KINDS else 0.0,
            adaptive=self.kind in ADAPTIVE_KINDS and self.adaptive_time_constant < math.inf,
            adaptive_time_constant=float(self.adaptive_time_constant),
            dt=float(self.dt),
            huber_c=float(self.huber_c),
            zero_point_time_constant=float(self.zero_point_time_constant),
            stuck_samples=float(self.stuck_samples),
            slide_rate=float(self.slide_rate),
            yaw_balance_std=float(self.yaw_balance_std),
            grip_floor_time_constant=float(self.grip_floor_time_constant),
            speed_channel=CH_SPEED,
            friction_alarm=float(self.friction_alarm) if self.kind == "joint" else math.inf,
            gate_sigmas=float(self.gate_sigmas) if self.kind == "joint" else 0.0,
        )
        self.state: FilterState | None = None
        self.set_noise(self.noise)

    def set_noise(self, noise: NoiseParams) -> None:
        """Use ``noise`` from the next step on (shared, or per member: see NoiseParams.scaled).
        The rescaling to the filter's rate (docs/decisions/0033-recorded-logs.md):
        the process noise and mu random walk are per NOISE_STEP (2 ms), so at another ``dt``
        their variances scale by dt / NOISE_STEP, and each step by its own elapsed time (noise
        of a process that runs continuously); the measurement noise is per sample and stays
        (it is mostly the model's error, which changes slowly: per sample the same at any rate;
        a recorded log's own sensor noise is added per channel by the replay)."""
        self.noise = noise
        per_step = self.dt / NOISE_STEP
        process_var = np.atleast_2d(np.square(np.asarray(noise.process_std, float)) * per_step)
        sensor_std = np.broadcast_arrays(
            *(np.atleast_1d(np.asarray(getattr(noise, name), dtype=float)) for name in SENSOR_NOISE)
        )
        sensor_var = np.square(np.stack(sensor_std, axis=1))
        members = max(len(process_var), len(sensor_var))  # the kernel reads both at one member's row
        mu_var = np.square(np.array([noise.mu_walk_std, noise.mu_accel_std, noise.mu_max_std], dtype=float))
        mu_var[0] *= per_step
        self.noise_variances = FilterNoise(  # (writable arrays: one kernel type)
            np.array(np.broadcast_to(process_var, (members, N_STATE))),
            np.array(np.broadcast_to(sensor_var, (members, len(SENSOR_NOISE)))),
            mu_var,
        )

    def kernel(self) -> FilterKernel:
        """This estimator as the compiled step (and the compiled closed loop) takes it: the
        settings, model, noise and state (the state's arrays themselves, updated in place)."""
        if self.state is None:
            raise RuntimeError("call reset(first_reading, initial_speed) before the first step")
        return FilterKernel(self.settings, self.params.kernel, self.noise_variances, self.state)

    # ---- set-up -------------------------------------------------------------------------
    def reset(self, reading, initial_speed: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Start (or, with ``mask`` (B,) bool, restart those rows of) the batch from a first
        ``reading`` (values and valid (B, N_CHANNELS)) and the forward speed [m/s] (scalar or
        (B,)): nominal mu, the inertial states from the reading (0 where a channel is invalid).
        The reading's time is ignored: the first :meth:`step` after a reset takes the nominal
        dt, each later one the time since the previous reading (the module docstring's rule)."""
        values = np.asarray(reading.values, dtype=float)
        if values.ndim != 2 or values.shape[1] != N_CHANNELS:
            raise ValueError(f"sensor reading must have shape (B, {N_CHANNELS}), got {values.shape}")
        valid = np.broadcast_to(np.asarray(getattr(reading, "valid", True), dtype=bool), values.shape)
        B = values.shape[0]
        started = self.state is not None
        if mask is not None and started and self.state.x.shape[0] != B:
            raise ValueError(f"a masked reset keeps the batch of {self.state.x.shape[0]}; the reading has {B} rows")
        if mask is not None:
            mask = np.asarray(mask)
            if mask.dtype != np.bool_ or mask.shape != (B,):
                raise ValueError(f"mask must be a bool array of shape ({B},), got {mask!r}")
        try:
            initial_speed = np.broadcast_to(np.asarray(initial_speed, dtype=float), (B,))
        except ValueError:
            raise ValueError(
                f"initial_speed must be a speed [m/s] or one per vehicle ({B},), got {initial_speed!r}"
            ) from None
        # (a first reset starts every row, so all of them are checked)
        rows = slice(None) if mask is None or not started else mask
        if not np.all(np.isfinite(initial_speed[rows])):
            raise ValueError(f"initial_speed must be finite [m/s], got {initial_speed!r}")
        inputs = [c for c in range(N_CHANNELS) if c not in MEASUREMENT_CHANNELS]
        needed = np.zeros(values.shape, dtype=bool)
        needed[:, inputs] = True
        bad = (needed | valid) & ~np.isfinite(values)
        if np.any(bad[rows]):
            b, c = np.argwhere(bad[rows])[0]
            raise ValueError(
                f"the first reading's channel {CHANNELS[c]!r} of vehicle {b} is {values[rows][b, c]!r}: the first "
                "reading must be finite in every input channel (wheel speeds, steering, torques: they start the "
                "model) and in every valid measurement"
            )
        measured = np.where(valid & np.isfinite(values), values, 0.0)
        x0 = np.zeros((B, N_STATE))
        x0[:, I_U] = initial_speed
        x0[:, I_AX], x0[:, I_AY], x0[:, I_R] = measured[:, CH_AX], measured[:, CH_AY], measured[:, CH_YAW_RATE]
        zero_point0 = np.zeros((B, 5))
        zero_point0[:, ZP_STEER] = 0.5 * (values[:, CH_DELTA] + values[:, CH_DELTA + 1])
        zero_point0[:, ZP_YAW] = measured[:, CH_YAW_RATE]
        fresh = FilterState(
            x=x0,
            P=np.broadcast_to(np.diag([0.5, 0.3, 1.0, 1.0, 0.02, 500.0]) ** 2, (B, N_STATE, N_STATE)).copy(),
            mu=np.full((B, 4), self.nominal_mu),
            P_mu=np.broadcast_to(_correlated(self.noise_variances.mu_var[2]), (B, 4, 4)).copy(),  # mu_max_std
            beta=np.full((B, 2), 0.5),
            beta_mu=np.full((B, 2), 0.5),
            omega_prev=values[:, CH_OMEGA : CH_OMEGA + 4].copy(),
            omega_dot=np.zeros((B, 4)),
            inertial_prev=np.full((B, N_HELD), np.nan),
            inertial_repeats=np.zeros((B, N_HELD)),
            zero_point=zero_point0,
            last_nll=np.zeros(B),
            slip_relaxed=np.full((B, 4), np.nan),  # (NaN: the first step starts it without lag)
            t_prev=np.full(B, np.nan),  # (NaN: the first step is one of the nominal dt)
            grip_accel=np.hypot(measured[:, CH_AX], measured[:, CH_AY]),
            innovation=np.full((B, N_INNOVATIONS), np.nan),
            innovation_std=np.full((B, N_INNOVATIONS), np.nan),
            nis=np.full((B, len(UPDATES)), np.nan),
            nis_dof=np.zeros((B, len(UPDATES))),
            wheel_nis=np.ones((B, 4)),
            consider_var=np.zeros(B),
            friction_nis=np.ones(B),
        )
        if mask is None or not started:
            self.state = fresh
            return
        for old, new in zip(self.state, fresh):
            old[mask] = new[mask]

    def replay(self, values, valid, t, initial_speed, record: bool = True, diagnostics: bool = False) -> Replay:
        """Run a whole log through the batch in one compiled loop: readings ``values`` and
        ``valid`` (T, N_CHANNELS), times ``t`` (T,) [s], every member reading the same samples
        (the batch: one member, or one per member of a per-member noise); reset from the first
        reading and ``initial_speed`` [m/s]. The same steps as :meth:`step` sample by sample,
        at a fraction of the cost. ``record``: keep every step's estimate (else only the NLL,
        for a tuning population). ``diagnostics``: also keep each step's covariances,
        innovations and NIS (:class:`Diagnostics`: for NEES and NIS). A member whose filter fails
        stops there (:class:`Replay`); :meth:`replay_error` gives its error."""
        values = np.ascontiguousarray(values, dtype=np.float64)
        valid = np.ascontiguousarray(valid, dtype=np.bool_)
        t = np.ascontiguousarray(t, dtype=np.float64)
        if (
            values.ndim != 2
            or values.shape[1] != N_CHANNELS
            or valid.shape != values.shape
            or t.shape != values.shape[:1]
        ):
            raise ValueError(
                f"a log replay takes values and valid (T, {N_CHANNELS}) and t (T,), got {values.shape}, "
                f"{valid.shape} and {t.shape}"
            )
        if len(t) == 0:
            raise ValueError("the log has no samples")
        B = self.noise_variances.process_var.shape[0]
        first = SensorReading(np.repeat(values[:1], B, 0), np.repeat(valid[:1], B, 0), np.repeat(t[:1], B))
        self.reset(first, np.broadcast_to(np.asarray(initial_speed, dtype=float), (B,)))
        T = len(t)
        out = empty_estimate(T * B if record else B)
        nll, status, at = np.zeros(B), np.zeros(B, dtype=np.int64), np.full(B, -1, dtype=np.int64)
        kept = empty_diagnostics(T if diagnostics else 0, B)
        run_parallel(
            _replay_members, np.arange(B), self.kernel(), values, valid, t, out, bool(record), nll, status, at, kept,
            min_items=PARALLEL_MIN_BATCH,
        )  # fmt: skip
        estimate = None
        if record:
            estimate = Estimate(*(field.reshape((T, B) + field.shape[1:]) for field in out))
        return Replay(estimate, nll, status, at, kept if diagnostics else None)

    def replay_error(self, result: Replay, values, t, member: int = 0) -> ValueError:
        """The error of ``member``'s failed replay (``result``) of the log ``values`` (T,
        N_CHANNELS), ``t`` (T,), naming the sample."""
        k = int(result.failed_at[member])
        error = self.step_error(member, int(result.status[member]), np.asarray(values)[k], float(np.asarray(t)[k]))
        return ValueError(f"at sample {k} (t = {float(np.asarray(t)[k])!r} s): {error}")

    # ---- one step -----------------------------------------------------------------------
    def step_error(self, i: int, status: int, values: np.ndarray, t: float = math.nan) -> ValueError:
        """The error of vehicle i's failed step (compiled status ``status``) on the reading
        ``values`` (N_CHANNELS,) at time ``t`` [s]."""
        if status == FILTER_FAILED:
            return ValueError(
                f"the {self.kind} filter of vehicle {i} failed: a covariance is not finite or not positive definite"
            )
        if status == BAD_TIME:
            return ValueError(
                f"the time of vehicle {i}'s reading, {t!r} s, is before its previous one, "
                f"{float(self.state.t_prev[i])!r} s: readings must come in time order"
            )
        bad_inputs = [
            CHANNELS[c] for c in range(N_CHANNELS) if c not in MEASUREMENT_CHANNELS and not np.isfinite(values[c])
        ]
        if bad_inputs:  # the model needs its inputs every step, valid or not
            return ValueError(
                f"inputs {bad_inputs} of vehicle {i} are NaN or inf: wheel speeds, steer angles and "
                "torques drive the model every step; hold the last value while a sensor is out (as "
                "envs.sensors does) and flag it invalid"
            )
        return ValueError(f"a valid measurement of vehicle {i} is NaN or inf: {values!r}")

    def step(self, reading, truth: Estimate | None = None, members: np.ndarray | None = None) -> Estimate:
        """One filter step on ``reading`` (values and valid (B, N_CHANNELS), times t (B,); a
        reading without times, or with an empty t, steps by the nominal dt); with ``members``
        (M,) indices only those rows step (the others keep their state) and the estimate has M
        rows. A ValueError (a bad reading, a failed filter) names the first failing vehicle; every
        failing row's state stays as it was but for ``last_nll``, which turns NaN; the other rows
        have stepped (snapshot :attr:`state` to retry a batch)."""
        f = self.kernel()
        B = f.state.x.shape[0]
        values = np.ascontiguousarray(reading.values, dtype=np.float64)
        valid = np.ascontiguousarray(reading.valid, dtype=np.bool_)
        if values.shape != (B, N_CHANNELS) or valid.shape != (B, N_CHANNELS):
            raise ValueError(f"sensor reading must have shape {(B, N_CHANNELS)}, got {values.shape} / {valid.shape}")
        if f.noise.process_var.shape[0] not in (1, B):
            raise ValueError(f"per-member noise for {f.noise.process_var.shape[0]} members, the batch has {B}")
        rows = member_rows(members, B)
        out, status = empty_estimate(len(rows)), np.zeros(len(rows), dtype=np.int64)
        t = np.ascontiguousarray(getattr(reading, "t", None) if getattr(reading, "t", None) is not None else [], float)
        if t.size and t.shape != (B,):
            raise ValueError(f"reading times must have shape ({B},) (or be empty), got {t.shape}")
        if self.settings.federated and len(rows) >= MIN_LANE_CARS:  # (whole blocks of lanes to each thread)
            blocks = np.arange(-(-len(rows) // LANES))
            run_parallel(_step_blocks, blocks, rows, f, SensorReading(values, valid, t), out, status)
        else:
            run_parallel(
                _step_rows, np.arange(len(rows)), rows, f, SensorReading(values, valid, t), out, status,
                min_items=PARALLEL_MIN_BATCH,
            )  # fmt: skip
        if np.count_nonzero(status):
            j = int(np.flatnonzero(status)[0])
            raise self.step_error(
                int(rows[j]), int(status[j]), values[rows[j]], float(t[rows[j]]) if t.size else math.nan
            )
        return out

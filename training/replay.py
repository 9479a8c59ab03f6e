"""Replaying estimators on a recorded log: the log's channels turned into the estimators'
inputs (the channel layout of :data:`fourwis.core.types.CHANNELS`) for a given car, and any
estimator or baseline run through them at the log's own rate and times.

What the inputs are made of, by what the log has (each choice is listed in the report):

* steering: the front wheels' own angles; or one road-wheel angle (or the handwheel angle over
  the steering ratio) split by the Ackermann geometry, tan(delta_in,out) = L tan(delta) /
  (L -/+ (t/2) tan(delta)) for full Ackermann, the vehicle's ``ackermann`` fraction of the way
  from parallel; rear: the rear wheels' angles, one rear angle, or none (0);
* wheel speeds: the log's, as angular speeds at the model's radius (a wheel's angular speed
  times its axle's radius over the model's: the wheel-centre speed is what the model reads);
  without them, the kinematic wheel-centre speeds of the measured forward speed and yaw rate at
  zero sideslip and zero longitudinal slip, flagged invalid (inputs only: they set the slip
  ratios near zero, the filters measure the ``speed`` channel instead);
* net wheel torques (:func:`fourwis.core.types.net_wheel_torque`): drive torques per wheel, or
  engine torque x gear ratio x driveline efficiency split by the drive layout (half each to
  the driven axle's wheels; ``front_share`` to the front axle of an all-wheel drive), less
  brake pressure x gain (a log with one of the two takes the other as none: a car with
  friction brakes logs their pressure); a log with neither gets the documented fallback from
  the measured ax: the force m ax, positive to the driven wheels, negative to all four by the
  brake balance (each axle's share split evenly). The wheels' spin inertia J omega_dot / R is
  left out of the fallback (it is ~1% of m ax on a car);
* missing samples (NaN): a measurement is skipped (invalid), an input holds its last value;
* time: the log's own; the estimators' nominal step is the median step rounded to 1 us, and
  every step takes its own elapsed time (gaps are reported and coasted through).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from fourwis.core.types import (
    CH_AX,
    CH_AY,
    CH_DELTA,
    CH_OMEGA,
    CH_SPEED,
    CH_TORQUE,
    CH_YAW_RATE,
    N_CHANNELS,
    Estimate,
    SensorReading,
    net_wheel_torque,
)
from fourwis.estimation import BASELINES, NoiseParams, make_estimator, parse_estimator_name, tuned_noise
from fourwis.estimation.joint import TUNED_KINDS, StateEstimator, empty_estimate
from fourwis.estimation.model import MIN_SPEED
from fourwis.training.logs import WHEELS, Log
from fourwis.training.vehicle_file import Vehicle

GAP_FACTOR = 1.5  #: a step longer than this many nominal steps is a gap (reported)
#: the sample rates [Hz] the estimators are meant for; a log outside them is replayed with a note
RATE_RANGE = (50.0, 1000.0)


class LogInputs(NamedTuple):
    """A log as the estimators read it: times t (T,) [s], readings values and valid (T,
    N_CHANNELS), the speed [m/s] they start from, the nominal step [s], the references (name ->
    (T,) SI, per wheel (T, 4)), and notes on what was made of what (for the report)."""

    t: np.ndarray
    values: np.ndarray
    valid: np.ndarray
    initial_speed: float
    nominal_dt: float
    references: dict
    notes: tuple[str, ...]


def nominal_step(t: np.ndarray) -> float:
    """The nominal step [s] of sample times ``t``: the median step, rounded to 1 us (a fixed-rate
    clock's rounding then does not move the step; see estimation.joint.CLOCK_TOLERANCE)."""
    step = float(np.median(np.diff(t)))
    rounded = round(step, 6)
    return rounded if rounded > 0 else step


def gap_summary(t: np.ndarray, dt: float) -> tuple[int, float, float, float]:
    """(count, longest [s], total missing time [s], time of the longest [s]) of the steps of ``t``
    longer than GAP_FACTOR x ``dt``."""
    steps = np.diff(t)
    gaps = np.flatnonzero(steps > GAP_FACTOR * dt)
    if not gaps.size:
        return 0, 0.0, 0.0, math.nan
    longest = gaps[np.argmax(steps[gaps])]
    return len(gaps), float(steps[longest]), float(np.sum(steps[gaps] - dt)), float(t[longest])


def _held(x: np.ndarray) -> np.ndarray:
    """x (T,) with every NaN replaced by the last finite value before it (the first must be finite)."""
    good = np.isfinite(x)
    index = np.where(good, np.arange(len(x)), 0)
    np.maximum.accumulate(index, out=index)
    return x[index]


def ackermann_angles(delta: np.ndarray, wheelbase: float, track: float, fraction: float) -> tuple[np.ndarray, ...]:
    """Left and right road-wheel angles [rad] of one angle ``delta`` [rad] (that of a wheel at the
    axle's centre) with ``fraction`` (0: parallel, 1: full) of the Ackermann geometry of
    ``wheelbase`` and ``track`` [m]: tan(delta_left) = L tan(delta) / (L - (t/2) tan(delta)), the
    right wheel with +; the inner wheel steers more."""
    tan = np.tan(delta)
    left = np.arctan(wheelbase * tan / (wheelbase - 0.5 * track * tan))
    right = np.arctan(wheelbase * tan / (wheelbase + 0.5 * track * tan))
    return delta + fraction * (left - delta), delta + fraction * (right - delta)


def _drive_split(vehicle: Vehicle) -> np.ndarray:
    """Each wheel's share (4,) of the drive torque (the layout, half to each wheel of an axle)."""
    front = {"front": 1.0, "rear": 0.0, "all": vehicle.front_drive_share}[vehicle.drive_layout]
    return np.array([front, front, 1.0 - front, 1.0 - front]) / 2.0


def _brake_split(vehicle: Vehicle) -> np.ndarray:
    """Each wheel's share (4,) of the braking force (the brake balance, half to each wheel)."""
    front = vehicle.brake_balance
    return np.array([front, front, 1.0 - front, 1.0 - front]) / 2.0


def _where(log: Log, k: int) -> str:
    return f"row {k + 1} (t = {float(log.t[k])!r} s)"


def _drive_torques(log: Log, vehicle: Vehicle) -> tuple[np.ndarray | None, str]:
    """The drive torque at each wheel (T, 4) [N m] from what the log has (None: unknown), and how."""
    if "torque_fl" in log:
        return np.column_stack(
            [_held(log[f"torque_{w}"]) for w in WHEELS]
        ), "drive torques: the log's torque_* channels"
    if "engine_torque" not in log:
        return None, ""
    engine = _held(log["engine_torque"])
    if "gear_ratio" in log:
        ratio, how = _held(log["gear_ratio"]), "gear_ratio"
    else:
        gear = _held(log["gear"])
        ratios = np.concatenate([[0.0], vehicle.gear_ratios])  # gear 0: neutral
        bad = np.flatnonzero((gear != np.round(gear)) | (gear < 0) | (gear >= len(ratios)))
        if bad.size:
            raise ValueError(
                f"log {log.source}: channel 'gear' is {float(gear[bad[0]])!r} at {_where(log, int(bad[0]))}: "
                f"the vehicle file gives {len(vehicle.gear_ratios)} gear_ratios ([drive] gear_ratios; 0 is neutral)"
            )
        ratio, how = ratios[gear.astype(int)], "gear and the vehicle's gear_ratios"
    total = engine * ratio * vehicle.driveline_efficiency
    return total[:, None] * _drive_split(vehicle), (
        f"drive torques: engine_torque x {how} x efficiency {vehicle.driveline_efficiency:g}, split "
        f"{' / '.join(f'{s:g}' for s in _drive_split(vehicle))} (layout {vehicle.drive_layout})"
    )


def _brake_torques(log: Log, vehicle: Vehicle) -> tuple[np.ndarray | None, str]:
    """The brake torque at each wheel (T, 4) [N m] from brake pressures x gains (None: unknown), and how."""
    if "brake_pressure_fl" in log:
        pressure, how = np.column_stack([_held(log[f"brake_pressure_{w}"]) for w in WHEELS]), "brake_pressure_*"
    elif "brake_pressure" in log:
        pressure, how = np.repeat(_held(log["brake_pressure"])[:, None], 4, axis=1), "brake_pressure (all wheels)"
    else:
        return None, ""
    if vehicle.brake_gain is None:
        raise ValueError(
            f"log {log.source} has brake pressure; the vehicle file needs [drive] brake_gain = [front, rear] [N m/Pa]"
        )
    gain = np.repeat(np.asarray(vehicle.brake_gain), 2)
    return pressure * gain, f"brake torques: {how} x brake_gain {list(vehicle.brake_gain)} N m/Pa"


def log_inputs(log: Log, vehicle: Vehicle) -> LogInputs:
    """The estimators' inputs of ``log`` for the car ``vehicle`` (module docstring)."""
    T = len(log.t)
    values, valid = np.full((T, N_CHANNELS), np.nan), np.zeros((T, N_CHANNELS), dtype=bool)
    notes = []
    params = vehicle.params
    R = params.wheel_radius  # the model's
    radius = vehicle.axle_radius
    for channel, name in ((CH_AX, "ax"), (CH_AY, "ay"), (CH_YAW_RATE, "yaw_rate"), (CH_SPEED, "speed")):
        if name in log:
            values[:, channel], valid[:, channel] = log[name], np.isfinite(log[name])
    # steering
    if "steer_fl" in log:
        front = [log["steer_fl"], log["steer_fr"]]
        notes.append("front steer: the log's steer_fl, steer_fr")
    else:
        if "steer" in log:
            delta, how = log["steer"], "steer"
        else:
            delta, how = (
                log["handwheel"] / params.steering_ratio,
                f"handwheel / steering ratio {params.steering_ratio:g}",
            )
        front = list(ackermann_angles(_held(delta), params.wheelbase, params.track_front, vehicle.ackermann))
        front = [np.where(np.isfinite(delta), f, np.nan) for f in front]
        notes.append(f"front steer: {how}, split by {vehicle.ackermann:g} of the Ackermann geometry")
    if "steer_rl" in log:
        rear = [log["steer_rl"], log["steer_rr"]]
        notes.append("rear steer: the log's steer_rl, steer_rr")
    elif "steer_rear" in log:
        rear = [log["steer_rear"]] * 2
        notes.append("rear steer: the log's steer_rear on both wheels")
    else:
        rear = [np.zeros(T)] * 2
        notes.append("rear steer: none (0)")
    for w, angle in enumerate(front + rear):
        values[:, CH_DELTA + w], valid[:, CH_DELTA + w] = _held(angle), np.isfinite(angle)
    # wheel speeds, as angular speeds at the model's radius
    speed_u = _held(np.where(valid[:, CH_SPEED], values[:, CH_SPEED], np.nan)) if "speed" in log else None
    yaw = _held(np.where(valid[:, CH_YAW_RATE], values[:, CH_YAW_RATE], np.nan)) if valid[:, CH_YAW_RATE].any() else 0
    if "wheel_speed_fl" in log:
        linear = log.linear_wheel_speed()
        for w, wheel in enumerate(WHEELS):
            raw = log[f"wheel_speed_{wheel}"]
            factor = 1.0 / R if linear else radius[w] / R
            values[:, CH_OMEGA + w], valid[:, CH_OMEGA + w] = _held(raw) * factor, np.isfinite(raw)
        notes.append(
            "wheel speeds: the log's" + (" (linear, over the model's radius)" if linear else " (at each axle's radius)")
        )
    else:
        if not np.isfinite(speed_u[0]):
            raise ValueError(
                f"log {log.source}: 'speed' is missing at {_where(log, 0)}, and the log has no wheel speeds"
            )
        a, b = params.cg_to_front, params.cg_to_rear
        for w in range(4):
            x_w = a if w < 2 else -b
            y_w = (params.track_front if w < 2 else params.track_rear) / 2 * (1 if w % 2 == 0 else -1)
            delta = values[:, CH_DELTA + w]
            along = (speed_u - y_w * yaw) * np.cos(delta) + x_w * yaw * np.sin(delta)
            values[:, CH_OMEGA + w] = along / R
        notes.append(
            "wheel speeds: none in the log; the kinematic wheel-centre speeds of 'speed' and the yaw rate "
            "at zero sideslip and slip, as inputs only (not measured)"
        )
    # net wheel torques at the model's radius: the log's sources, or the fallback without any
    drive, drive_how = _drive_torques(log, vehicle)
    brake, brake_how = _brake_torques(log, vehicle)
    if drive is not None or brake is not None:
        net = net_wheel_torque(0.0 if drive is None else drive, 0.0 if brake is None else brake, 1.0)
        values[:, CH_TORQUE : CH_TORQUE + 4] = net * (R / radius)  # (the force at the wheel kept)
        notes += [how for how in (drive_how, brake_how) if how]
        notes.append("no " + ("brake" if brake is None else "drive") + " torque in the log: taken as none")
    else:
        ax = _held(np.where(valid[:, CH_AX], values[:, CH_AX], np.nan)) if valid[:, CH_AX].any() else np.zeros(T)
        force = params.mass * ax
        split = np.where(force[:, None] >= 0, _drive_split(vehicle), _brake_split(vehicle))
        values[:, CH_TORQUE : CH_TORQUE + 4] = force[:, None] * split * R
        notes.append(
            "wheel torques: none in the log; the fallback from the measured ax (a force m ax, driving to the "
            f"{vehicle.drive_layout}-drive wheels, braking by the balance {vehicle.brake_balance:.3g} front)"
        )
    valid[:, CH_TORQUE : CH_TORQUE + 4] = True
    # where the estimators start
    if "initial_speed" in log.metadata:
        try:
            initial_speed = float(log.metadata["initial_speed"].split()[0])
        except (ValueError, IndexError):
            raise ValueError(
                f"log {log.source}: metadata initial_speed must be a speed [m/s], got {log.metadata['initial_speed']!r}"
            ) from None
    elif speed_u is not None and np.isfinite(speed_u[0]):
        initial_speed = float(speed_u[0])
    else:
        initial_speed = float(np.mean(values[0, CH_OMEGA : CH_OMEGA + 4]) * R)
    dt = nominal_step(log.t)
    rate = 1.0 / dt
    if not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
        notes.append(
            f"sample rate {rate:.4g} Hz: outside the {RATE_RANGE[0]:g}-{RATE_RANGE[1]:g} Hz the estimators "
            "are meant for"
        )
    return LogInputs(log.t, values, valid, initial_speed, dt, references(log), tuple(notes))


def references(log: Log) -> dict:
    """The log's reference channels for scoring (SI): vx, vy, beta (from vy and vx where only they
    are given, and vy from vx and beta likewise), yaw_rate, mu ((T, 4); one ``ref_mu`` on all wheels)."""
    out = {}
    for name in ("vx", "vy", "beta", "yaw_rate"):
        if f"ref_{name}" in log:
            out[name] = log[f"ref_{name}"]
    if "beta" not in out and {"vx", "vy"} <= set(out):
        out["beta"] = np.arctan2(out["vy"], np.maximum(np.abs(out["vx"]), MIN_SPEED))
    if "vy" not in out and {"vx", "beta"} <= set(out):
        out["vy"] = np.abs(out["vx"]) * np.tan(out["beta"])
    if "ref_mu_fl" in log:
        out["mu"] = np.column_stack([log[f"ref_mu_{w}"] for w in WHEELS])
    elif "ref_mu" in log:
        out["mu"] = np.repeat(log["ref_mu"][:, None], 4, axis=1)
    return out


def log_noise(name: str, vehicle: Vehicle, noise: NoiseParams | None = None) -> NoiseParams | None:
    """The noise estimator ``name`` runs with on a log of ``vehicle``: ``noise``, else what
    make_estimator gives it (the shipped tuning for alo-fkf and joint, the hand-set noise for
    the others), with the log's declared sensor noise (the vehicle file's [sensors]) added in
    quadrature per channel; None for the baselines without noise."""
    base = parse_estimator_name(name)[0]
    if base in ("baseline-steady", "baseline-zero") or ":" in base:
        return noise
    if noise is None:
        noise = (tuned_noise() if base in TUNED_KINDS else None) or NoiseParams()
    declared = vehicle.sensor_noise
    if not declared:
        return noise
    fields = {
        "ax": "ax_std",
        "ay": "ay_std",
        "yaw_rate": "gyro_std",
        "speed": "speed_std",
        "wheel_speed": "wheel_speed_std",
    }
    changes = {f: np.hypot(getattr(noise, f), declared[k]) for k, f in fields.items() if k in declared}
    return replace(noise, **changes)


class ReplayResult(NamedTuple):
    """One estimator's run on a log: its estimate (fields (T,), per wheel (T, 4); None if it
    failed at once), the error that stopped it (None: it ran to the end; a failure after step k
    leaves the estimate NaN from there), and its run time [s]."""

    estimate: Estimate | None
    error: str | None
    seconds: float


def _nan_after(estimate: Estimate, k: int) -> Estimate:
    out = Estimate(*(np.array(f, dtype=float) for f in estimate))
    for f in out:
        f[k:] = np.nan
    return out


def replay_estimator(name: str, vehicle: Vehicle, inputs: LogInputs, noise: NoiseParams | None = None) -> ReplayResult:
    """Run the estimator ``name`` (a fourwis estimator or baseline, or ``module:factory``) on the
    log ``inputs`` of ``vehicle``, from a reset on the first sample at the log's initial speed."""
    base = parse_estimator_name(name)[0]
    if base == "oracle" or "+true-" in name:
        raise ValueError(f"estimator {name!r} needs the simulator's truth; a log has none")
    options = vehicle.estimator_options() if ":" not in base else {}
    noise = log_noise(name, vehicle, noise)
    start = time.perf_counter()
    estimator = make_estimator(name, vehicle.params, inputs.nominal_dt, noise, **options)
    args = (inputs.values, inputs.valid, inputs.t, inputs.initial_speed)
    if type(estimator) is StateEstimator:
        result = estimator.replay(*args)
        estimate = Estimate(*(f[:, 0] for f in result.estimate))
        error = None
        if result.status[0]:
            error = str(estimator.replay_error(result, inputs.values, inputs.t))
            estimate = _nan_after(estimate, int(result.failed_at[0]))
        return ReplayResult(estimate, error, time.perf_counter() - start)
    if base in BASELINES:
        try:
            estimate = Estimate(*(f[:, 0] for f in estimator.replay(*args)))
        except ValueError as err:
            return ReplayResult(None, str(err), time.perf_counter() - start)
        return ReplayResult(estimate, None, time.perf_counter() - start)
    return _step_through(estimator, inputs, start)


def _step_through(estimator, inputs: LogInputs, start: float) -> ReplayResult:
    """A user's estimator stepped sample by sample (the step interface)."""
    T = len(inputs.t)
    out = empty_estimate(T)
    for k in range(T):
        reading = SensorReading(inputs.values[k : k + 1].copy(), inputs.valid[k : k + 1].copy(), inputs.t[k : k + 1])
        try:
            if k == 0:
                estimator.reset(reading, np.full(1, inputs.initial_speed))
            step = estimator.step(reading)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as err:
            return ReplayResult(_nan_after(out, k), f"at sample {k}: {err}", time.perf_counter() - start)
        for target, value in zip(out, step):
            target[k] = np.asarray(value)[0]
    return ReplayResult(out, None, time.perf_counter() - start)


__all__ = [
    "LogInputs",
    "ReplayResult",
    "ackermann_angles",
    "gap_summary",
    "log_inputs",
    "log_noise",
    "nominal_step",
    "references",
    "replay_estimator",
]

"""FMVSS 126 / UN R13-H electronic stability test procedure: characterisation and the
sine-with-dwell amplitude series, on any road and with any controller/estimator.

1. Slowly increasing steer (S7.6) at 80 km/h, 13.5 deg/s, to the left and to the right on a
   dry road (mu 1.0): A = the steering-wheel angle at 0.3 g, the mean of both directions. The
   regulation runs three tests per direction and rounds A to 0.1 deg; a deterministic
   simulation needs one run per direction, and A is kept unrounded (16.554 deg for the
   shipped car: rounding would move every amplitude by 0.3%).
2. Sine with dwell (S7.9) from 80 km/h, coasting, at 1.5A, 2A, 2.5A, ... up to the larger of
   6.5A and 270 deg, no run above 300 deg; each amplitude steered left-first and right-first.
   On low-mu roads we keep the dry-road A (the regulation only defines the dry test; the same
   steering inputs on a slippery road make the controller's job harder, which is the point).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from fourwis.envs.layout import A_AY, S_R
from fourwis.envs.metrics import (
    SineWithDwellResult,
    peak_abs,
    sine_with_dwell_metrics,
    steering_angle_at_lateral_acceleration,
)
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.envs.vehicle import VehicleParams

MAX_AMPLITUDE = math.radians(300.0)  #: no sine-with-dwell run above this [rad]
MIN_LAST_AMPLITUDE = math.radians(270.0)  #: the series reaches at least this unless 6.5A is larger [rad]
MAX_A_DEG = 200.0  #: largest A [deg] with a series: its first run, 1.5A, at most 300 deg


def characterise(params: VehicleParams = VehicleParams(), mu: float = 1.0, seed: int = 0) -> float:
    """A [rad]: steering-wheel angle at 0.3 g from slowly increasing steer, left and right averaged,
    of the car ``params`` describes (its 4WS feed-forward included: eq. 20 lowers the yaw gain, so
    that car's A is larger). Cached: the same car is characterised once per process."""
    return _characterise(params, mu, seed)  # (positional: one cache entry however it is called)


@functools.lru_cache(maxsize=16)
def _characterise(params: VehicleParams, mu: float, seed: int) -> float:
    angles = []
    for direction in (1, -1):
        traj = simulate(make_scenario("slowly_increasing_steer", mu=mu, direction=direction, params=params), seed=seed)
        angles.append(steering_angle_at_lateral_acceleration(traj.t, traj.steering_wheel, traj.aux[:, A_AY]))
    return float(np.mean(angles))


def amplitudes(A: float) -> np.ndarray:
    """The series' steering-wheel amplitudes [rad]: 1.5A in steps of 0.5A up to max(6.5A, 270 deg), <= 300 deg."""
    if not (math.isfinite(A) and 0 < A <= math.radians(MAX_A_DEG)):
        raise ValueError(
            f"A must be an angle in (0, {MAX_A_DEG:g} deg] (the series starts at 1.5A, at most 300 deg), got {A!r} rad"
        )
    last = max(6.5 * A, MIN_LAST_AMPLITUDE)
    series = np.arange(1.5, last / A + 1e-9, 0.5) * A
    series = series[series <= MAX_AMPLITUDE + 1e-9]
    if series[-1] < min(last, MAX_AMPLITUDE) - 1e-9:
        series = np.append(series, min(last, MAX_AMPLITUDE))
    return series


@dataclass(frozen=True)
class SeriesRun:
    """One sine-with-dwell run of a series."""

    mu: float
    amplitude: float  #: steering-wheel amplitude [rad]
    direction: int  #: +1 left first, -1 right first
    result: SineWithDwellResult
    peak_sideslip: float  #: largest |beta| [rad]


@dataclass(frozen=True)
class SeriesJob:
    """One run of a series to do (what :func:`run_series` hands to ``map_runs``)."""

    A: float  #: characterisation angle [rad]
    mu: float
    amplitude: float  #: steering-wheel amplitude [rad]
    direction: int  #: +1 left first, -1 right first
    controller_factory: Callable | None
    estimator: object
    params: VehicleParams
    seed: int


def run_series_job(job: SeriesJob) -> SeriesRun:
    """Simulate one sine-with-dwell run of a series and score it."""
    scenario = make_scenario(
        "sine_with_dwell",
        mu=job.mu,
        amplitude_deg=math.degrees(job.amplitude),
        direction=job.direction,
        params=job.params,
    )
    controller = job.controller_factory() if job.controller_factory is not None else None
    traj = simulate(scenario, controller=controller, estimator=job.estimator, seed=job.seed)
    beta = traj.truth.beta
    result = sine_with_dwell_metrics(
        traj.t, traj.steering_wheel, traj.state[:, S_R], traj.aux[:, A_AY], sideslip=beta, A=job.A
    )
    return SeriesRun(job.mu, float(job.amplitude), job.direction, result, peak_abs(beta))


def run_series(
    A: float,
    mu: float = 1.0,
    controller_factory: Callable | None = None,
    estimator=None,
    params: VehicleParams = VehicleParams(),
    seed: int = 0,
    progress: bool = False,
    amplitude_list: np.ndarray | None = None,
    map_runs: Callable | None = None,
) -> list[SeriesRun]:
    """The sine-with-dwell series at friction ``mu`` (both directions). ``controller_factory()``
    builds a fresh controller per run (None: uncontrolled); ``estimator`` as for simulate.
    ``map_runs(run_series_job, jobs, desc)`` runs the :class:`SeriesJob` list and returns the
    SeriesRuns in its order (default: here, one after the other; ``fourwis swd`` hands in
    training.pool's process pool or Ray, which need a picklable factory and estimator)."""
    todo = [(a, d) for a in (amplitudes(A) if amplitude_list is None else amplitude_list) for d in (1, -1)]
    jobs = [SeriesJob(A, mu, float(a), d, controller_factory, estimator, params, seed) for a, d in todo]
    desc = f"sine with dwell, mu {mu}"
    if map_runs is not None:
        return list(map_runs(run_series_job, jobs, desc))
    return [run_series_job(job) for job in tqdm(jobs, disable=not progress, desc=desc, unit="run")]


MEASURED_A = "0.3 g at 80 km/h, dry road"  #: where :func:`characterise` finds A (a table's header)


def format_table(runs: list[SeriesRun], A: float, A_source: str = MEASURED_A) -> str:
    """Markdown table of a series in the regulation's terms; ``A_source`` says where A came from.
    The left-first and right-first runs of an amplitude that read alike in every column (a
    symmetric car without sensor noise in the loop steers mirror images) share one row, dir
    ``L, R``, instead of a row repeated."""
    lines = [
        f"A = {math.degrees(A):.1f} deg ({A_source})",
        "",
        "| mu | amplitude | dir | yaw ratio @COS+1.00 s (<=35%) | @COS+1.75 s (<=20%) "
        "| displacement @BOS+1.07 s | peak beta | yaw | resp. | spin |",
        "|---:|---:|:-:|---:|---:|---:|---:|:-:|:-:|:-:|",
    ]
    rows: list[tuple[str, list[str], str]] = []  # (mu and amplitude, directions, the other cells)
    for run in runs:
        r = run.result
        resp = "n/a" if r.passed_responsiveness is None else ("pass" if r.passed_responsiveness else "FAIL")
        where = f"{run.mu:.2f} | {math.degrees(run.amplitude):.0f} deg ({run.amplitude / A:.1f}A)"
        cells = (
            f"{100 * r.yaw_rate_ratio_1000:.1f}% | {100 * r.yaw_rate_ratio_1750:.1f}% "
            f"| {r.lateral_displacement:.2f} m | {math.degrees(run.peak_sideslip):.1f} deg "
            f"| {'pass' if r.passed_yaw else 'FAIL'} | {resp} | {'SPIN' if r.spun_out else ''}"
        )
        direction = "L" if run.direction > 0 else "R"
        if rows and rows[-1][0] == where and rows[-1][2] == cells:
            rows[-1][1].append(direction)
        else:
            rows.append((where, [direction], cells))
    lines += [f"| {where} | {', '.join(directions)} | {cells} |" for where, directions, cells in rows]
    return "\n".join(lines)

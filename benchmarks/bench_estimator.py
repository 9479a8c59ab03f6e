"""Estimator cost side by side (issue 4): the `joint` estimator per step for one vehicle and per
vehicle in a batch of 1024, and one `ckf` step (predict + update, one vehicle) against one
filterpy UnscentedKalmanFilter step with cubature weights on the same compiled 6-state
estimation model and the same 7 measurements (sub-filter 1: ax, ay, r, four wheel speeds).

Also the joint estimator per vehicle-step at batches 1, 64, 256 and 1024 (``--batches``), by the
wall clock and by the process's CPU time (every thread's: batches step on all cores), the
measure that a shared, loaded host disturbs least. ``--no-peer`` leaves filterpy out.

Run: ``.venv/bin/python benchmarks/bench_estimator.py`` (or ``fourwis bench --only estimator``).
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np

from fourwis.core.types import CH_DELTA, CH_TORQUE
from fourwis.envs.layout import NU
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.sensors import SensorModel, SensorParams
from fourwis.envs.simulation import DT, truth_of
from fourwis.envs.vehicle import VehicleParams, derivatives
from fourwis.estimation import make_estimator
from fourwis.estimation.joint import MeasurementInputs, measure_state_1
from fourwis.estimation.model import ModelInputs, steer_trig, transition


def _timed(fn: Callable[[], None], seconds: float = 3.0) -> tuple[float, float]:
    """Mean wall and CPU time (``time.process_time``: all threads) [s] of ``fn()`` over
    ~``seconds`` after a warm-up."""
    fn()
    count, start, cpu = 0, time.perf_counter(), time.process_time()
    while time.perf_counter() - start < seconds:
        fn()
        count += 1
    return (time.perf_counter() - start) / count, (time.process_time() - cpu) / count


def _per_call(fn: Callable[[], None], seconds: float = 3.0) -> float:
    """Mean wall time [s] of ``fn()`` over ~``seconds`` after a warm-up."""
    return _timed(fn, seconds)[0]


def _started(name: str, batch: int, **options):
    """Estimator ``name`` for ``batch`` vehicles reset on one noisy reading of paper_sine's
    initial state (40 km/h, straight); returns (estimator, reading). The benchmark repeats that
    reading without its time (each step then takes the nominal dt), so the frozen-sensor check is
    off (``stuck_samples`` inf): otherwise ax, ay and r count as held samples from the second
    step on and every timed step would run with them invalid.
    ``options``: more keyword arguments for make_estimator."""
    params = VehicleParams()
    scenario = make_scenario("paper_sine")
    state = scenario.initial_state(batch)
    aux = derivatives(state, np.zeros((batch, NU)), np.full((batch, 4), 0.8), params)[1]
    reading = SensorModel(SensorParams(), (), batch, np.random.default_rng(0)).measure(truth_of(state, aux)[0], 0.0)
    reading = reading._replace(t=np.zeros(0))  # (a repeated time would be refused: readings come in time order)
    estimator = make_estimator(name, params, DT, stuck_samples=math.inf, **options)
    estimator.reset(reading, np.full(batch, scenario.speed))
    return estimator, reading


def joint_step_time(batch: int, tyre_relaxation: bool = False) -> float:
    """Seconds per ``joint`` step for ``batch`` vehicles (see :func:`_started`), optionally with
    the tyre relaxation in its model."""
    estimator, reading = _started("joint", batch, tyre_relaxation=tyre_relaxation)
    return _per_call(lambda: estimator.step(reading))


def joint_step_times(batch: int) -> tuple[float, float]:
    """Wall and CPU seconds per ``joint`` step for ``batch`` vehicles (see :func:`_started`)."""
    estimator, reading = _started("joint", batch)
    return _timed(lambda: estimator.step(reading))


def ckf_versus_filterpy() -> tuple[float, float]:
    """Seconds per predict + update: our ``ckf`` estimator (one vehicle, compiled step incl. its
    Python entry) and filterpy's UKF (alpha 1, beta 0, kappa 0: the cubature rule) on the same
    compiled 6-state model and 7 measurements, with the same Q and R."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    estimator, reading = _started("ckf", 1)
    p = estimator.params
    values = reading.values[0]
    delta = values[CH_DELTA : CH_DELTA + 4].copy()
    trig = steer_trig(delta)
    h_args = MeasurementInputs(trig, p.kernel)
    # the compiled transition with its arguments built once, as hx has them (not the checked
    # convenience wrapper estimation.model.state_transition, whose argument checks and
    # conversions cost ~5 us per sigma point: filterpy would be timed with our Python overhead)
    f_args = ModelInputs(
        np.full(4, 0.8),
        trig,
        values[3:7].copy(),
        values[CH_TORQUE : CH_TORQUE + 4].copy(),
        np.zeros(4),
        p.kernel,
        float(DT),
    )

    def fx(x: np.ndarray, dt: float) -> np.ndarray:
        out = np.empty((1, 6))
        transition(x.reshape(1, 6), out, f_args)
        return out[0]

    def hx(x: np.ndarray) -> np.ndarray:
        out = np.empty((1, 7))
        measure_state_1(x.reshape(1, 6), 0, out, h_args)
        return out[0]

    noise = estimator.noise
    # (2n + 1 = 13 sigma points, the centre one with weight 0: one model call more than the CKF's 12)
    ukf = UnscentedKalmanFilter(6, 7, DT, hx, fx, MerweScaledSigmaPoints(6, alpha=1.0, beta=0.0, kappa=0.0))
    ukf.x, ukf.P = estimator.state.x[0].copy(), estimator.state.P[0].copy()
    ukf.Q = np.diag(np.square(noise.process_std))
    ukf.R = np.diag([noise.ax_std**2, noise.ay_std**2, noise.gyro_std**2] + [noise.wheel_speed_std**2] * 4)
    z = np.concatenate([values[:3], values[3:7] * p.wheel_radius])

    def filterpy_step() -> None:
        ukf.predict()
        ukf.update(z)

    return _per_call(lambda: estimator.step(reading)), _per_call(filterpy_step)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", nargs="*", type=int, default=[1, 64, 256, 1024], help="batch sizes")
    parser.add_argument("--no-peer", action="store_true", help="leave out the filterpy comparison")
    args = parser.parse_args(argv)
    if not args.no_peer:
        try:  # the peer, from the bench extra: named before the timed runs, not after them
            import filterpy  # noqa: F401
        except ModuleNotFoundError as err:
            raise ModuleNotFoundError(
                "the estimator benchmark's peer needs filterpy: pip install 'fourwis[bench]'"
            ) from err
    times = {batch: joint_step_times(batch) for batch in args.batches}
    print("| measurement | time | target | ratio to target |")
    print("|---|---:|---:|---:|")
    for batch, (wall, cpu) in times.items():
        print(f"| joint estimator, batch {batch}, wall per vehicle-step | {wall / batch * 1e6:,.2f} us | | |")
        print(f"| joint estimator, batch {batch}, CPU per vehicle-step | {cpu / batch * 1e6:,.2f} us | | |")
    if args.no_peer:
        return
    single = times[1][0] if 1 in times else joint_step_time(1)
    batch = times[1024][0] if 1024 in times else joint_step_time(1024)
    relaxed = joint_step_time(1024, tyre_relaxation=True)
    ours, theirs = ckf_versus_filterpy()
    print(f"| joint estimator, one vehicle, per step | {single * 1e6:,.0f} us | <= 100 us | {100e-6 / single:.2f}x |")
    print(
        f"| joint estimator, batch 1024, per vehicle-step | {batch / 1024 * 1e6:,.1f} us | <= 20 us "
        f"| {20e-6 / (batch / 1024):.2f}x |"
    )
    print(
        f"| ... with the tyre-relaxation option | {relaxed / 1024 * 1e6:,.1f} us | <= 20 us "
        f"| {20e-6 / (relaxed / 1024):.2f}x |"
    )
    print(f"| ckf estimator step, one vehicle (6 states, 7 measurements) | {ours * 1e6:,.1f} us | | |")
    print(f"| filterpy UKF predict + update, same model | {theirs * 1e6:,.0f} us | | |")
    print(f"| CKF speed-up over filterpy | {theirs / ours:.1f}x | >= 3x | {theirs / ours / 3:.2f}x |")


if __name__ == "__main__":
    main()

"""Estimator cost side by side (issue 4): the `joint` estimator per step for one vehicle and per
vehicle in a batch of 1024, and one plain CKF step (predict + update) against one filterpy
UnscentedKalmanFilter step with cubature weights on the same 6-state estimation model and the
same 7 measurements (sub-filter 1: ax, ay, r, four wheel speeds).

Run: ``.venv/bin/python benchmarks/bench_estimator.py`` (or ``fourwis bench --only estimator``).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from envs.sensors import SensorModel, SensorParams
from envs.simulation import sensor_truth
from envs.scenarios import make_scenario
from envs.vehicle import NU, VehicleParams, derivatives
from estimation import make_estimator
from estimation.ckf import ckf_predict, ckf_update
from estimation.model import Inputs, ModelParams, state_transition, wheel_kinematics

DT = 0.002


def _per_call(fn: Callable[[], None], seconds: float = 3.0) -> float:
    """Mean wall time [s] of ``fn()`` over ~``seconds`` after a warm-up."""
    fn()
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        fn()
        count += 1
    return (time.perf_counter() - start) / count


def joint_step_time(batch: int) -> float:
    """Seconds per ``joint`` step for ``batch`` vehicles driving straight at 20 m/s."""
    params = VehicleParams()
    scenario = make_scenario("paper_sine")
    state = scenario.initial_state(batch)
    aux = derivatives(state, np.zeros((batch, NU)), np.full((batch, 4), 0.8), params)[1]
    sensors = SensorModel(SensorParams(), (), batch, np.random.default_rng(0))
    reading = sensors.measure(sensor_truth(state, aux), 0.0)
    estimator = make_estimator("joint", params, DT)
    estimator.reset(reading, np.full(batch, scenario.speed))
    return _per_call(lambda: estimator.step(reading))


def ckf_versus_filterpy() -> tuple[float, float]:
    """Seconds per predict + update: our batched CKF (B = 1) and filterpy's UKF (alpha 1,
    beta 0, kappa 0: the cubature rule) on the estimator's 6-state model."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    p = ModelParams.from_vehicle(VehicleParams())
    u0 = 20.0
    inputs = Inputs(np.full((1, 1, 4), 0.02), np.full((1, 1, 4), u0 / 0.278), np.full((1, 1, 4), 20.0),
                    np.zeros((1, 1, 4)))
    mu = np.full((1, 1, 4), 0.8)

    def f(points: np.ndarray) -> np.ndarray:  # (B, K, 6)
        return state_transition(points, mu, inputs, p, DT)

    def h(points: np.ndarray) -> np.ndarray:  # (B, K, 7)
        _, along = wheel_kinematics(points[..., 0], points[..., 1], points[..., 4], inputs.delta, p)
        return np.concatenate([points[..., [2, 3, 4]], along], axis=-1)

    x0 = np.array([u0, 0.0, 0.0, 0.0, 0.0, 0.0])
    P0 = np.diag([0.5, 0.3, 1.0, 1.0, 0.02, 500.0]) ** 2
    Q = np.diag([0.01, 0.001, 0.3, 0.3, 0.002, 80.0]) ** 2
    R = np.diag([0.02**2, 0.02**2, 0.004**2] + [0.014**2] * 4)
    z = h(x0[None, None])[0]
    state = {"x": x0[None].copy(), "P": P0[None].copy()}

    def ours() -> None:
        x, P = ckf_predict(state["x"], state["P"], f, Q)
        upd = ckf_update(x, P, z, h, R)
        state["x"], state["P"] = upd.x, upd.P

    ukf = UnscentedKalmanFilter(6, 7, DT, lambda s: h(s[None, None])[0, 0], lambda s, dt: f(s[None, None])[0, 0],
                                MerweScaledSigmaPoints(6, alpha=1.0, beta=0.0, kappa=0.0))
    ukf.x, ukf.P, ukf.Q, ukf.R = x0.copy(), P0.copy(), Q, R

    def filterpy_step() -> None:
        ukf.predict()
        ukf.update(z[0])

    return _per_call(ours), _per_call(filterpy_step)


def main() -> None:
    single = joint_step_time(1)
    batch = joint_step_time(1024)
    ours, theirs = ckf_versus_filterpy()
    print("| measurement | time | target | ratio to target |")
    print("|---|---:|---:|---:|")
    print(f"| joint estimator, one vehicle, per step | {single * 1e6:,.0f} us | <= 100 us | {100e-6 / single:.2f}x |")
    print(f"| joint estimator, batch 1024, per vehicle-step | {batch / 1024 * 1e6:,.1f} us | <= 20 us "
          f"| {20e-6 / (batch / 1024):.2f}x |")
    print(f"| plain CKF predict + update (6 states, 7 measurements) | {ours * 1e6:,.0f} us | | |")
    print(f"| filterpy UKF predict + update, same model | {theirs * 1e6:,.0f} us | | |")
    print(f"| CKF speed-up over filterpy | {theirs / ours:.1f}x | >= 3x | {theirs / ours / 3:.2f}x |")


if __name__ == "__main__":
    main()

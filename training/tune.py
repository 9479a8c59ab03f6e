"""Offline tuning of the filter noise (paper eq. 30-31, section 3.3): an optimizer (the paper's
antlion by default, or CMA-ES / random search: estimation.optimizers) searches log10 scale
factors of (process noise, accelerometer, gyro, wheel-speed noise) that minimise the
estimation error of the robust federated CKF (``alo-fkf``) on a calibration run against its
truth; each population is scored in one batched replay (a filter with per-member noise).
The calibration run is a randomised scenario (not one of the paper's five, so the paper
conditions stay unseen). Writes estimation/data/tuned_noise.json, which ``alo-fkf`` uses.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from envs.scenarios import make_scenario
from envs.sensors import SensorReading
from envs.simulation import Trajectory, simulate
from estimation import NoiseParams, make_estimator
from estimation.optimizers import minimize
from training.io import atomic_write_text

OUTPUT = Path(__file__).resolve().parent.parent / "estimation" / "data" / "tuned_noise.json"
BOUNDS = [(-1.5, 1.5)] * 4  #: log10 factors on (process, accelerometer, gyro, wheel-speed) noise
CALIBRATION_SEED = 1000  #: the randomised calibration scenario's seed


def calibration_run(seed: int = CALIBRATION_SEED, duration: float = 6.0) -> Trajectory:
    """An open-loop run of the randomised scenario (truth + sensor readings)."""
    return simulate(make_scenario("random", seed=seed, duration=duration), seed=seed)


def replay_cost(log10_factors: np.ndarray, traj: Trajectory, kind: str = "alo-fkf") -> np.ndarray:
    """Estimation error of ``kind`` with scaled noise replayed on ``traj``, for a population of
    candidates ``log10_factors`` (N, 4) in ONE batched filter (each member its own noise):
    beta RMSE / 0.1 deg + yaw-rate RMSE / 0.01 rad/s + speed RMSE / 0.05 m/s (each term 1 at a
    good estimator); (N,) costs, inf for members whose replay failed."""
    factors = np.atleast_2d(np.asarray(log10_factors, dtype=float))
    n = len(factors)
    est = make_estimator(kind, traj.scenario.vehicle_params, noise=NoiseParams().scaled(factors))
    T = len(traj.t)
    beta, r, u = np.empty((T, n)), np.empty((T, n)), np.empty((T, n))
    try:
        for k in range(T):
            reading = SensorReading(np.repeat(traj.sensors[k][None], n, 0), np.repeat(traj.sensor_valid[k][None], n, 0),
                                    np.full(n, traj.t[k]))
            if k == 0:
                est.reset(reading, np.full(n, traj.scenario.speed))
            e = est.step(reading)
            beta[k], r[k], u[k] = e.beta, e.r, e.u
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        if n == 1:
            return np.array([math.inf])
        return np.concatenate([replay_cost(f[None], traj, kind) for f in factors])  # isolate the failure

    def error(est_series: np.ndarray, truth: np.ndarray) -> np.ndarray:
        return np.sqrt(np.mean((est_series - truth[:, None]) ** 2, axis=0))

    cost = error(beta, traj.truth.beta) / math.radians(0.1) + error(r, traj.truth.r) / 0.01 + error(u, traj.truth.u) / 0.05
    return np.where(np.isfinite(cost), cost, math.inf)


def tune(n_agents: int = 8, iterations: int = 8, seed: int = 0, out: Path = OUTPUT, optimizer: str = "alo",
         duration: float = 6.0, progress: bool = True) -> dict:
    """Tune alo-fkf's noise with ``optimizer`` (see estimation.optimizers) on a ``duration`` [s]
    calibration run; returns (and writes atomically) the result."""
    traj = calibration_run(duration=duration)

    def objective(X: np.ndarray) -> np.ndarray:
        return replay_cost(X, traj)

    default = float(objective(np.zeros((1, 4)))[0])
    result = minimize(objective, BOUNDS, optimizer, n_agents=n_agents, iterations=iterations, seed=seed,
                      progress=progress)
    data = {"log10_factors": [float(v) for v in result.x], "cost": result.fun, "default_cost": default,
            "optimizer": optimizer, "history": [float(v) for v in result.history],
            "evaluations": result.n_evaluations,
            "calibration": f"random scenario seed {CALIBRATION_SEED}, {duration:g} s, sensor seed {CALIBRATION_SEED}",
            "objective": "beta RMSE/0.1 deg + r RMSE/0.01 rad/s + u RMSE/0.05 m/s of alo-fkf"}
    atomic_write_text(out, json.dumps(data, indent=2) + "\n")
    return data

"""Offline ALO tuning of the filter noise (paper eq. 30-31, section 3.3): the antlion optimizer
searches log10 scale factors of (process noise, accelerometer, gyro, wheel-speed noise) that
minimise the estimation error of the robust federated CKF (``alo-fkf``) on a calibration run
against its truth. The calibration run is a randomised scenario (not one of the paper's
five, so the paper conditions stay unseen). Writes estimation/data/tuned_noise.json, which
``alo-fkf`` and ``joint`` then use.
"""

from __future__ import annotations

import json
import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from envs.metrics import rmse
from envs.scenarios import make_scenario
from envs.sensors import SensorReading
from envs.simulation import Trajectory, simulate
from estimation import NoiseParams, make_estimator
from estimation.antlion import antlion
from training.io import atomic_write_text

OUTPUT = Path(__file__).resolve().parent.parent / "estimation" / "data" / "tuned_noise.json"
BOUNDS = [(-1.5, 1.5)] * 4  #: log10 factors on (process, accelerometer, gyro, wheel-speed) noise
CALIBRATION_SEED = 1000  #: the randomised calibration scenario's seed


def calibration_run(seed: int = CALIBRATION_SEED, duration: float = 6.0) -> Trajectory:
    """An open-loop run of the randomised scenario (truth + sensor readings)."""
    return simulate(make_scenario("random", seed=seed, duration=duration), seed=seed)


def replay_cost(log10_factors: np.ndarray, traj: Trajectory, kind: str = "alo-fkf") -> float:
    """Estimation error of ``kind`` with scaled noise replayed on ``traj``: beta RMSE / 0.1 deg +
    yaw-rate RMSE / 0.01 rad/s + speed RMSE / 0.05 m/s (each term 1 at a good estimator)."""
    params = traj.scenario.vehicle_params
    est = make_estimator(kind, params, noise=NoiseParams().scaled(log10_factors))
    betas, rs, us = [], [], []
    try:
        for k in range(len(traj.t)):
            reading = SensorReading(traj.sensors[k][None], traj.sensor_valid[k][None], float(traj.t[k]))
            if k == 0:
                est.reset(reading, np.array([traj.scenario.speed]))
            e = est.step(reading)
            betas.append(e.beta[0])
            rs.append(e.r[0])
            us.append(e.u[0])
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        return math.inf
    cost = (rmse(np.array(betas), traj.truth.beta) / math.radians(0.1) + rmse(np.array(rs), traj.truth.r) / 0.01
            + rmse(np.array(us), traj.truth.u) / 0.05)
    return float(cost) if math.isfinite(cost) else math.inf


def _cost(args) -> float:
    return replay_cost(*args)


def tune(n_agents: int = 8, iterations: int = 8, seed: int = 0, jobs: int = 2, out: Path = OUTPUT) -> dict:
    """Run the ALO tuning; returns (and writes atomically) the result."""
    traj = calibration_run()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        def objective(X: np.ndarray) -> np.ndarray:
            return np.array(list(pool.map(_cost, [(x, traj) for x in X])))

        default = float(objective(np.zeros((1, 4)))[0])
        result = antlion(objective, BOUNDS, n_agents=n_agents, iterations=iterations, rng=seed, progress=True)
    data = {"log10_factors": [float(v) for v in result.x], "cost": result.fun, "default_cost": default,
            "history": [float(v) for v in result.history], "evaluations": result.n_evaluations,
            "calibration": f"random scenario seed {CALIBRATION_SEED}, 6 s, sensor seed {CALIBRATION_SEED}",
            "objective": "beta RMSE/0.1 deg + r RMSE/0.01 rad/s + u RMSE/0.05 m/s of alo-fkf"}
    atomic_write_text(out, json.dumps(data, indent=2) + "\n")
    return data

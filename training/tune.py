"""Offline tuning of the filter noise (paper eq. 30-31, section 3.3): an optimizer (the paper's
antlion by default, or CMA-ES / random search: estimation.optimizers) searches log10 scale
factors of (process noise, accelerometer, gyro, wheel-speed noise) for the robust federated
CKF (``alo-fkf``) on a calibration run; each population is scored in one batched replay (a
filter with per-member noise). The calibration run is a randomised scenario (not one of the
paper's five, so the paper conditions stay unseen). Writes results/tune/tuned_noise.json
(:data:`DEFAULT_OUT`); only on request (``replace_shipped``, ``fourwis tune --replace-shipped``)
does it replace the shipped estimation/data/tuned_noise.json (:data:`SHIPPED`), which ``alo-fkf``
and ``joint`` use: a smoke run must not change every later run's estimators.

Criterion (``criterion``):

* ``nll`` (default): the mean innovation negative log-likelihood
  0.5 (nu^T S^-1 nu + log det S + m log 2 pi) of both sub-filters per step, i.e. maximum-
  likelihood noise identification (Mehra 1970). It needs no truth, so it is what a car can
  run on its own data (the online tuner uses it too). The paper's eq. 31/62, a fixed-weight
  sum of squared measurement residuals, cannot set the noise's level: Q and R scaled together
  leave the gain, hence the residuals, unchanged, so the filter's confidence is free; the
  log det S term is what pins it.
* ``truth``: the estimation error against the simulator's truth (beta, yaw rate, speed), a
  simulation-only criterion kept for comparison.

Deviation from the project's design notes and its tuning issue (not part of this repository), on
purpose: they describe the offline tuning as "against truth"; the truth-error optimum is a badly
calibrated filter and does not transfer to ``joint``, so the likelihood is the default
(docs/decisions/0022-noise-tuning-likelihood.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fourwis.core.checks import is_integer
from fourwis.core.types import SensorReading
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import Trajectory, simulate
from fourwis.estimation import NoiseParams, make_estimator, tuned_noise
from fourwis.estimation.optimizers import minimize
from fourwis.training.io import atomic_write_json, check_writable
from fourwis.training.pool import Backend, as_backend, open_pool, parallel_map, shared
from fourwis.training.provenance import provenance

#: the shipped tuning, which alo-fkf and joint use (estimation.tuned_noise)
SHIPPED = Path(__file__).resolve().parent.parent / "estimation" / "data" / "tuned_noise.json"
DEFAULT_OUT = Path("results") / "tune" / "tuned_noise.json"  #: where a tuning goes unless told (cwd-relative)
BOUNDS = [(-1.5, 1.5)] * 4  #: log10 factors on (process, accelerometer, gyro, wheel-speed) noise
CALIBRATION_SEED = 1000  #: the randomised calibration scenario's seed


def calibration_run(seed: int = CALIBRATION_SEED, duration: float = 10.0) -> Trajectory:
    """An open-loop run of the randomised scenario (truth + sensor readings)."""
    return simulate(make_scenario("random", seed=seed, duration=duration), seed=seed)


CRITERIA = ("nll", "truth")


class Replay(NamedTuple):
    """A population's replay: estimated beta [rad], yaw rate [rad/s], speed [m/s] (T, N) and the
    mean innovation NLL per step (N,)."""

    beta: np.ndarray
    r: np.ndarray
    u: np.ndarray
    mean_nll: np.ndarray


def replay(log10_factors: np.ndarray, traj: Trajectory, kind: str = "alo-fkf") -> Replay:
    """Replay ``traj``'s readings through ``kind`` with noise scaled by each candidate of
    ``log10_factors`` (N, 4), all in ONE batched filter (each member its own noise). Raises
    ValueError (or FloatingPointError) if a member's filter fails."""
    factors = np.atleast_2d(np.asarray(log10_factors, dtype=float))
    n = len(factors)
    est = make_estimator(kind, traj.scenario.vehicle_params, noise=NoiseParams().scaled(factors))
    T = len(traj.t)
    beta, r, u, nll = np.empty((T, n)), np.empty((T, n)), np.empty((T, n)), np.zeros(n)
    for k in range(T):
        reading = SensorReading(
            np.repeat(traj.sensors[k][None], n, 0), np.repeat(traj.sensor_valid[k][None], n, 0), np.full(n, traj.t[k])
        )
        if k == 0:
            est.reset(reading, np.full(n, traj.scenario.speed))
        e = est.step(reading)
        beta[k], r[k], u[k] = e.beta, e.r, e.u
        nll += est.state.last_nll
    return Replay(beta, r, u, nll / T)


def replay_cost(
    log10_factors: np.ndarray, traj: Trajectory, kind: str = "alo-fkf", criterion: str = "nll"
) -> np.ndarray:
    """Cost of ``kind`` with scaled noise replayed on ``traj`` (:func:`replay`) for a population
    of candidates ``log10_factors`` (N, 4); (N,) costs, inf for members whose replay failed.
    ``nll``: mean innovation NLL per step; ``truth``: beta RMSE / 0.1 deg + yaw-rate RMSE /
    0.01 rad/s + speed RMSE / 0.05 m/s (each term 1 at a good estimator)."""
    if criterion not in CRITERIA:
        raise ValueError(f"unknown tuning criterion {criterion!r}; known: {list(CRITERIA)}")
    factors = np.atleast_2d(np.asarray(log10_factors, dtype=float))
    try:
        run = replay(factors, traj, kind)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        if len(factors) == 1:
            return np.array([math.inf])
        return np.concatenate([replay_cost(f[None], traj, kind, criterion) for f in factors])  # isolate the failure
    if criterion == "nll":
        return np.where(np.isfinite(run.mean_nll), run.mean_nll, math.inf)

    def error(est_series: np.ndarray, truth: np.ndarray) -> np.ndarray:
        return np.sqrt(np.mean((est_series - truth[:, None]) ** 2, axis=0))

    cost = (
        error(run.beta, traj.truth.beta) / math.radians(0.1)
        + error(run.r, traj.truth.r) / 0.01
        + error(run.u, traj.truth.u) / 0.05
    )
    return np.where(np.isfinite(cost), cost, math.inf)


MU_NOISE_SEEDS = tuple(range(2000, 2024))  #: random scenarios of the mu-noise scan (used by no report)
MU_NOISE_GRID = (0.15, 0.3, 0.45, 0.6, 0.9, 1.2)  #: candidate mu_accel_std [m/s^2]


def _population_cost(job: tuple) -> np.ndarray:
    """A task of :func:`tune`'s population: (N,) costs of a part (N, 4) of it, replayed on the
    calibration run (shared once with every worker: training.pool.shared)."""
    traj, factors, criterion = job
    return replay_cost(factors, shared(traj), criterion=criterion)


def _mu_error(job: tuple[int, float]) -> float:
    seed, mu_accel_std = job
    scenario = make_scenario("random", seed=seed, duration=10.0)
    noise = replace(tuned_noise() or NoiseParams(), mu_accel_std=mu_accel_std)
    traj = simulate(scenario, estimator=make_estimator("joint", scenario.vehicle_params, noise=noise), seed=seed)
    half = traj.t > traj.t[-1] / 2
    return float(np.mean(np.abs(traj.estimate.mu[half] - traj.truth.mu[half])))


def mu_noise_scan(
    grid: Sequence[float] = MU_NOISE_GRID,
    seeds: Sequence[int] = MU_NOISE_SEEDS,
    jobs: int | None = None,
    progress: bool = True,
    backend: Backend | str | None = None,
) -> dict[float, float]:
    """The joint estimator's mean |mu_hat - mu| over the last half of open-loop random scenarios
    ``seeds`` (10 s, sensor noise seeded alike) for each mu_accel_std of ``grid`` (the rest of
    the noise as shipped): the scan behind NoiseParams.mu_accel_std."""
    if not grid or not all(math.isfinite(g) and g > 0 for g in grid):
        raise ValueError(f"mu_accel_std candidates must be finite and > 0, got {list(grid)!r}")
    if not seeds or not all(is_integer(s) and s >= 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct integers >= 0 (at least one), got {list(seeds)!r}")
    jobs_list = [(seed, float(g)) for g in grid for seed in seeds]
    errors = list(parallel_map(_mu_error, jobs_list, jobs, "mu-noise scan", progress, backend))
    return {float(g): float(np.mean(errors[i * len(seeds) : (i + 1) * len(seeds)])) for i, g in enumerate(grid)}


def tune(
    n_agents: int = 30,
    iterations: int = 100,
    seed: int = 0,
    out: str | Path = DEFAULT_OUT,
    optimizer: str = "alo",
    duration: float = 10.0,
    progress: bool = True,
    criterion: str = "nll",
    replace_shipped: bool = False,
    command: str | None = None,
    jobs: int | None = None,
    backend: Backend | str | None = None,
) -> dict:
    """Tune alo-fkf's noise with ``optimizer`` (see estimation.optimizers) by ``criterion`` on a
    ``duration`` [s] calibration run; returns (and writes atomically to the JSON file ``out``)
    the result, with who wrote it (``command``, default: this process's command line, the
    commit, date and host). ``replace_shipped``: also write it over :data:`SHIPPED`, the tuning
    alo-fkf and joint use. If the optimizer does not beat the hand-set noise the result keeps it
    (log10 factors 0, ``improved`` false; ``optimizer_best`` holds what the optimizer found). A
    negative ``seed`` or a file that cannot be written raises ValueError before any work.

    ``backend`` and ``jobs`` (training.pool): by default each population is replayed in one
    batched filter in this process; on Ray (or with ``jobs``, in that many local processes)
    it is split into that many parts (default on Ray: one per cluster CPU) replayed as tasks.
    Every member's filter is its own in the batch, so the costs, hence the result, are the
    same however the population is split."""
    if not (is_integer(seed) and seed >= 0):
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not isinstance(replace_shipped, bool):
        raise ValueError(f"replace_shipped must be True or False, got {replace_shipped!r}")
    seed = int(seed)  # (written to the result's JSON)
    out = check_writable(out, "file")
    if replace_shipped:
        check_writable(SHIPPED, "file", "the shipped tuning")
    header = provenance(command)
    backend = as_backend(backend)
    split = backend.name == "ray" or jobs is not None  # else the whole population in one replay here
    with open_pool(backend, jobs) as pool:
        traj = calibration_run(duration=duration)
        handle = pool.share(traj) if split else traj

        def objective(X: np.ndarray) -> np.ndarray:
            if not split:
                return replay_cost(X, traj, criterion=criterion)
            parts = [(handle, part, criterion) for part in np.array_split(X, min(len(X), pool.slots))]
            return np.concatenate(list(pool.map(_population_cost, parts, "population", progress=False)))

        default = float(objective(np.zeros((1, 4)))[0])
        result = minimize(
            objective, BOUNDS, optimizer, n_agents=n_agents, iterations=iterations, seed=seed, progress=progress
        )
    improved = bool(result.fun < default)  # else the hand-set noise (factors 0) is kept, not a worse tuning
    data = {
        "log10_factors": [float(v) for v in result.x] if improved else [0.0] * 4,
        "cost": float(result.fun) if improved else default,
        "default_cost": default,
        "improved": improved,
        "optimizer_best": {"log10_factors": [float(v) for v in result.x], "cost": float(result.fun)},
        "optimizer": optimizer,
        "history": [float(v) for v in result.history],
        "evaluations": result.n_evaluations,
        "seed": seed,
        "n_agents": int(n_agents),
        "iterations": int(iterations),
        "duration": float(duration),
        "calibration": f"random scenario seed {CALIBRATION_SEED}, {duration:g} s, sensor seed {CALIBRATION_SEED}",
        "criterion": criterion,
        "objective": (
            "mean innovation NLL per step of alo-fkf"
            if criterion == "nll"
            else "beta RMSE/0.1 deg + r RMSE/0.01 rad/s + u RMSE/0.05 m/s of alo-fkf"
        ),
        "written_by": header._asdict(),
    }
    atomic_write_json(out, data)
    if replace_shipped:
        atomic_write_json(SHIPPED, data)
    return data

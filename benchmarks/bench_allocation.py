"""Torque allocation cost: the compiled minimum-workload allocator against scipy's SLSQP
solving the same bounded QP, side by side on the same random demands (reported separately for
the feasible ones, the only ones SLSQP solves, and the infeasible ones, on which it fails).

Run: .venv/bin/python benchmarks/bench_allocation.py
The allocator runs every 2 ms step for every car, so its cost is per vehicle-step. SLSQP
solves each vehicle's QP in workload-normalised forces (well scaled) from a zero start.
"""

from __future__ import annotations

import time

import numpy as np
from _common import report
from scipy.optimize import minimize

from fourwis.control.allocation import allocate_torques, wheel_force_map
from fourwis.envs.vehicle import VehicleParams


def _demands(batch: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    fz = rng.uniform(500.0, 3500.0, (batch, 4))
    mu = rng.uniform(0.1, 1.0, (batch, 4))
    lateral = rng.uniform(-0.9, 0.9, (batch, 4)) * mu * fz
    return (
        rng.normal(0.0, 150.0, (batch, 4)),
        rng.normal(0.0, 1500.0, batch),
        fz,
        mu,
        lateral,
        rng.uniform(0.0, 35.0, batch),
    )


def _best_time(fn, repeats: int = 5) -> float:
    fn()  # compile / warm up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def _scipy_allocate(params, base, moment, fz, mu, lateral, speed) -> None:
    _, (lever,) = wheel_force_map(params, 0.0, 0.0)
    for b in range(len(base)):
        cap = mu[b] * fz[b]
        motor = min(params.motor_peak_torque, params.motor_peak_power * params.wheel_radius / max(speed[b], 1e-9))
        limit = np.minimum(motor / params.wheel_radius, np.sqrt(np.maximum(cap**2 - lateral[b] ** 2, 0.0)))
        drive = base[b].sum() / params.wheel_radius
        equalities = {"type": "eq", "fun": lambda y: [(cap @ y - drive) / 1e3, (lever * cap @ y - moment[b]) / 1e3]}
        minimize(
            lambda y: y @ y,
            np.zeros(4),
            jac=lambda y: 2 * y,
            method="SLSQP",
            bounds=list(zip(-limit / cap, limit / cap)),
            constraints=[equalities],
        )


def main() -> dict:
    params = VehicleParams()
    results = {}
    for batch in (1, 256):
        demands = _demands(batch)
        ours = (
            _best_time(
                lambda: allocate_torques(demands[0], demands[1], demands[2], demands[3], params, demands[4], demands[5])
            )
            / batch
        )
        results[f"compiled allocator, batch {batch} [us per vehicle-step]"] = ours * 1e6
    # the side by side on the same 200 demands, split by feasibility: SLSQP solves the feasible QPs;
    # on an infeasible demand its equality constraints cannot hold and it fails (iteration limit,
    # incompatible constraints) after ~30x the work, where the allocator degrades the demand
    demands = _demands(200)
    feasible = allocate_torques(*demands[:4], params, demands[4], demands[5]).feasible
    results["share of the 200 demands that are infeasible"] = float(np.mean(~feasible))
    for name, rows in (("feasible", feasible), ("infeasible", ~feasible), ("all", np.ones_like(feasible))):
        sub = tuple(a[rows] for a in demands)
        n = int(rows.sum())
        ours = _best_time(lambda: allocate_torques(*sub[:4], params, sub[4], sub[5])) / n
        theirs = _best_time(lambda: _scipy_allocate(params, *sub), repeats=2) / n
        results[f"compiled allocator, {name} demands, batch {n} [us per vehicle-step]"] = ours * 1e6
        results[f"scipy SLSQP, {name} demands [us per vehicle]"] = theirs * 1e6
        results[f"scipy / compiled, {name} demands"] = theirs / ours
    return report(results, decimals=2)


if __name__ == "__main__":
    main()

"""Noise tuning optimizers side by side (issue 5): ALO (the paper's) vs CMA-ES vs random search
on the same evaluation budget for the Q/R problem of ``fourwis tune`` (alo-fkf's cost on a
randomised calibration run), 5 seeds each; and the wall time of the issue's ALO run of
30 agents x 100 iterations on a 10 s calibration run.

Run: ``.venv/bin/python benchmarks/bench_tune.py`` (or ``fourwis bench --only tune``).
"""

from __future__ import annotations

import time

import numpy as np

from fourwis.estimation.optimizers import METHODS, minimize
from fourwis.training.tune import BOUNDS, calibration_run, replay_cost

DURATION = 2.5  #: calibration run [s] (shorter than fourwis tune's 10 s to keep the bench short)
AGENTS, ITERATIONS, SEEDS = 6, 6, 5


def main() -> None:
    traj = calibration_run(duration=DURATION)
    default = replay_cost(np.zeros((1, 4)), traj)[0]
    replay_cost(np.zeros((AGENTS, 4)), traj)  # warm-up: compile the batched (parallel) estimator step
    print(
        f"calibration: random scenario, {DURATION} s; budget {AGENTS} agents x ({ITERATIONS} + 1) populations "
        f"= {AGENTS * (ITERATIONS + 1)} evaluations; default-noise cost {default:.3f}"
    )
    print("| optimizer | best cost mean | std | min | max | wall per run [s] |")
    print("|---|---:|---:|---:|---:|---:|")
    for method in METHODS:
        best, walls = [], []
        for seed in range(SEEDS):
            start = time.perf_counter()
            result = minimize(lambda X: replay_cost(X, traj), BOUNDS, method, AGENTS, ITERATIONS, seed)
            walls.append(time.perf_counter() - start)
            best.append(result.fun)
        b = np.array(best)
        print(f"| {method} | {b.mean():.3f} | {b.std():.3f} | {b.min():.3f} | {b.max():.3f} | {np.mean(walls):.1f} |")
    long_run = calibration_run(duration=10.0)
    start = time.perf_counter()
    result = minimize(lambda X: replay_cost(X, long_run), BOUNDS, "alo", 30, 100, seed=0)
    wall = time.perf_counter() - start
    print(
        f"ALO, 30 agents x 100 iterations ({result.n_evaluations} evaluations) on a 10 s run: {wall:.0f} s "
        f"(target <= 120 s: {120 / wall:.2f}x); best cost {result.fun:.3f}, default noise "
        f"{replay_cost(np.zeros((1, 4)), long_run)[0]:.3f}"
    )


if __name__ == "__main__":
    main()

"""Plant throughput at the 2 ms step: one vehicle and a batch of 1024.

Run: .venv/bin/python benchmarks/bench_plant.py
Three single-vehicle figures, because they answer different questions: one Python call per
2 ms step (the slowest way to drive the plant), one call per 20 ms control step (how the
env drives it), and a long in-kernel rollout (the kernel's own cost).
"""

from __future__ import annotations

import time

import numpy as np
from _common import report

from fourwis.envs.layout import NU
from fourwis.envs.road import RoadTables, uniform
from fourwis.envs.vehicle import VehicleParams, initial_state, step


def _rate(fn, vehicle_steps: int, repeats: int = 3) -> float:
    fn()  # compile / warm up
    best = min(_timed(fn) for _ in range(repeats))
    return vehicle_steps / best


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def main() -> dict:
    params = VehicleParams()
    dt = 0.002
    single = initial_state(params, 20.0)
    controls = np.zeros((1, NU))
    controls[0, :4] = 50.0
    controls[0, 4] = 0.03
    road1 = RoadTables.from_roads(uniform(0.8), 1)

    def per_step_calls(n=20_000):
        x = single
        for _ in range(n):
            x = step(x, controls, params, road1, dt).state

    def per_control_step(n=4_000):
        x = single
        for _ in range(n):
            x = step(x, controls, params, road1, dt, 10).state

    def in_kernel(n=200_000):
        step(single, controls, params, road1, dt, n)

    batch = 1024
    xb = initial_state(params, np.linspace(5.0, 40.0, batch), batch)
    ub = np.repeat(controls, batch, axis=0)
    roadb = RoadTables.from_roads(uniform(0.8), batch)

    def batched(n=500):
        step(xb, ub, params, roadb, dt, n)

    results = {
        "single, one call per 2 ms step [steps/s]": _rate(per_step_calls, 20_000),
        "single, one call per 20 ms control step [steps/s]": _rate(per_control_step, 40_000),
        "single, in-kernel rollout [steps/s]": _rate(in_kernel, 200_000),
        "batch 1024 [vehicle-steps/s]": _rate(batched, 500 * batch),
    }
    return report(results)


if __name__ == "__main__":
    main()

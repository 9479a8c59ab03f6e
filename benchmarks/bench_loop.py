"""What a closed-loop step costs, and what a Python component adds to it: one car on
paper_sine (2 ms steps) with everything compiled, with the estimator or the controller a user's
Python object (each served from Python once per step, fourwis.envs.loop's PythonStage), and
with both. The user's objects here do the least a real one does: the estimator wraps the
compiled ``ckf`` (so its cost over the compiled ckf is the Python stage's), the controller
returns the driver's torques with a differential yaw moment from the estimated yaw rate.

Run: ``.venv/bin/python benchmarks/bench_loop.py`` (or ``fourwis bench --only loop``).
"""

from __future__ import annotations

import time

import numpy as np
from _common import report

from fourwis.core.types import Command
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import ClosedLoop
from fourwis.estimation import make_estimator

STEPS = 2000


class PythonEstimator:
    """A user's estimator: the compiled ckf behind a Python object (the loop cannot see inside)."""

    needs_truth = False

    def __init__(self, params, dt):
        self.inner, self.dt = make_estimator("ckf", params, dt), dt

    def reset(self, reading, initial_speed, mask=None):
        self.inner.reset(reading, initial_speed, mask)

    def step(self, reading, truth=None, members=None):
        return self.inner.step(reading, truth, members)


class PythonController:
    """A user's controller: Mz = -2000 r, as a differential torque on both axles."""

    def __init__(self, params):
        self.params = params

    def reset(self):
        pass

    def __call__(self, t, estimate, front_steer, base_torques):
        force = -2000.0 * estimate.r / self.params.track_front / 2
        torques = base_torques + np.outer(force * self.params.wheel_radius, [-1.0, 1.0, -1.0, 1.0])
        return Command(torques, np.zeros(len(torques)))


def per_step(controller, estimator) -> float:
    """Wall seconds per 2 ms step of one car (best of three runs of STEPS steps)."""
    times = []
    for _ in range(3):
        scenario = make_scenario("paper_sine", duration=20.0)
        params = scenario.vehicle_params
        loop = ClosedLoop(
            scenario,
            controller(params) if callable(controller) else controller,
            estimator(params, 0.002) if callable(estimator) else estimator,
            np.random.default_rng(0),
        )
        loop.advance_steps(100, records=False)  # (compiles and warms up)
        start = time.perf_counter()
        loop.advance_steps(STEPS, records=False)
        times.append((time.perf_counter() - start) / STEPS)
    return min(times)


def main() -> None:
    compiled = per_step(None, "ckf")
    results = {
        "compiled: ckf, no controller [us/step]": compiled * 1e6,
        "compiled: ckf, dyc-lqr [us/step]": per_step("dyc-lqr", "ckf") * 1e6,
        "python estimator (wrapping ckf), no controller [us/step]": per_step(None, PythonEstimator) * 1e6,
        "compiled ckf, python controller [us/step]": per_step(PythonController, "ckf") * 1e6,
        "python estimator and controller [us/step]": per_step(PythonController, PythonEstimator) * 1e6,
    }
    report(results, decimals=1)


if __name__ == "__main__":
    main()

"""Env throughput side by side with peers, in one run (issue 7).

fourwis: single env (gym.make) with the oracle, CKF and joint estimators in the loop, and the
native vector env of 64 and 256 cars; one env step = 20 ms of simulated time (ten 2 ms
substeps of plant, sensors and estimator); at 256 cars also on ``random``'s drawn lane
changes only (``course_share`` 1: the path-following driver steers and the path deviation is
measured every step). Peers (the ``bench`` extra): highway-env's ``highway-fast-v0`` (one
step = 1 simulated second), CommonRoad's multi-body vehicle model
(``vehiclemodels.vehicle_dynamics_mb``, RK4 at 1 ms; model only, no env around it) and
gymnasium's ``CartPoleVectorEnv`` (256 envs, 20 ms steps). Reports env-steps/s and
simulated seconds per wall-clock second.

Each fourwis rate is also given per CPU second (``time.process_time``: every thread of the
process, so a shared, loaded host slows it less than the wall clock), in the JSON object that
ends the output. ``--envs NAME ...`` measures only those rows (``single``, ``vector64``,
``vector256``, ``lanes256``, ``oracle256``, ``peers``).

Run: ``.venv/bin/python benchmarks/bench_env.py`` (or ``fourwis bench --only env``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable

import numpy as np

SECONDS = 4.0  #: wall time per measurement [s]
WARM_UP = 1.0  #: untimed wall time first [s]: compiles and cache loads of the paths one step does not reach (resets)


#: each fourwis row's env steps per CPU second (process time), by its label (:func:`_rate`'s)
CPU_RATES: dict[str, float] = {}


def _rate(step: Callable[[], int], seconds: float = SECONDS, label: str | None = None) -> float:
    """Env steps per wall second of repeated ``step()`` calls (each returns how many env steps it
    made); with a ``label``, the steps per CPU second of the process go into CPU_RATES."""
    start = time.perf_counter()
    while time.perf_counter() - start < WARM_UP:  # warm-up (JIT, caches, the first episode ends)
        step()
    count, start, cpu = 0, time.perf_counter(), time.process_time()
    while time.perf_counter() - start < seconds:
        count += step()
    if label is not None:
        CPU_RATES[label] = count / (time.process_time() - cpu)
    return count / (time.perf_counter() - start)


def fourwis_single(estimator: str) -> float:
    import gymnasium as gym

    env = gym.make("fourwis:FourWIS/YawStability-v0", estimator=estimator)
    env.reset(seed=0)
    action = np.zeros(2, dtype=np.float32)

    def step() -> int:
        *_, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
        return 1

    return _rate(step, label=f"fourwis single env, {estimator}")


def fourwis_vector(estimator: str, n: int, course_share: float = 0.0) -> float:
    from fourwis.envs.gym_env import YawStabilityVectorEnv

    env = YawStabilityVectorEnv(
        num_envs=n, estimator=estimator, scenario_kwargs={"course_share": course_share}, autoreset_mode="SameStep"
    )
    env.reset(seed=0)
    action = np.zeros((n, 2), dtype=np.float32)

    def step() -> int:
        env.step(action)
        return n

    lane_changes = ", lane changes" if course_share else ""
    return _rate(step, label=f"fourwis vector env x{n}, {estimator}{lane_changes}")


def highway_fast() -> float | None:
    try:
        import gymnasium as gym
        import highway_env  # noqa: F401  (registers highway-fast-v0)
    except ImportError:
        return None
    env = gym.make("highway-fast-v0")
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step() -> int:
        *_, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        if terminated or truncated:
            env.reset()
        return 1

    return _rate(step)


def commonroad_mb(dt: float = 0.001) -> float | None:
    try:
        from vehiclemodels.init_mb import init_mb
        from vehiclemodels.parameters_vehicle2 import parameters_vehicle2
        from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb
    except ImportError:
        return None
    p = parameters_vehicle2()
    x0 = np.array(init_mb([0, 0, 0, 20.0, 0, 0, 0], p), dtype=float)
    u = [0.05, 0.0]

    def f(x):
        return np.asarray(vehicle_dynamics_mb(x, u, p), dtype=float)

    state, steps = [x0], [0]
    restart = round(2.0 / dt)  # the steering ramp spins the car and the model's state turns NaN at ~2.6 s: restart

    def step() -> int:
        x = state[0]
        k1 = f(x)
        k2 = f(x + 0.5 * dt * k1)
        k3 = f(x + 0.5 * dt * k2)
        k4 = f(x + dt * k3)
        state[0] = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        steps[0] += 1
        if steps[0] % restart == 0:
            if not np.all(np.isfinite(state[0])):
                raise FloatingPointError("CommonRoad MB state became non-finite: the timing would be of NaN arithmetic")
            state[0] = x0
        return 1

    return _rate(step)


def cartpole_vector(n: int = 256) -> float:
    from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

    env = CartPoleVectorEnv(num_envs=n)
    env.reset(seed=0)
    actions = np.zeros(n, dtype=np.int64)

    def step() -> int:
        env.step(actions)
        return n

    return _rate(step)


GROUPS = ("single", "vector64", "vector256", "lanes256", "oracle256", "peers")  #: --envs choices


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="*", choices=GROUPS, default=list(GROUPS), help="rows to measure")
    chosen = set(parser.parse_args(argv).envs)
    rows: list[tuple[str, float | None, float]] = []  # name, env-steps/s, simulated s per env step
    if "single" in chosen:
        for estimator in ("oracle", "ckf", "joint"):
            rows.append((f"fourwis single env, {estimator}", fourwis_single(estimator), 0.02))
    for n in (64, 256):
        if f"vector{n}" in chosen:
            rows.append((f"fourwis vector env x{n}, joint", fourwis_vector("joint", n), 0.02))
    if "lanes256" in chosen:
        rows.append(
            ("fourwis vector env x256, joint, lane changes", fourwis_vector("joint", 256, course_share=1.0), 0.02)
        )
    if "oracle256" in chosen:
        rows.append(("fourwis vector env x256, oracle", fourwis_vector("oracle", 256), 0.02))
    if "peers" in chosen:
        rows.append(("highway-env highway-fast-v0", highway_fast(), 1.0))
        rows.append(("CommonRoad MB model (RK4, 1 ms)", commonroad_mb(), 0.001))
        rows.append(("gymnasium CartPoleVectorEnv x256", cartpole_vector(), 0.02))
    highway = next((rate for name, rate, _ in rows if name.startswith("highway-env")), None)
    import numba

    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, numba threads "
        f"{numba.get_num_threads()}; load average {os.getloadavg()[0]:.2f} at the end (benchmark an idle "
        f"machine); {time.strftime('%Y-%m-%d')}"
    )
    print("| env | env-steps/s | simulated s per wall s | sim-time ratio to highway-fast-v0 |")
    print("|---|---:|---:|---:|")
    for name, rate, sim_dt in rows:
        if rate is None:
            print(f"| {name} | not installed (pip install -e '.[bench]') | | |")
            continue
        ratio = f"{rate * sim_dt / highway:.2f}" if highway else "n/a"
        print(f"| {name} | {rate:,.0f} | {rate * sim_dt:,.1f} | {ratio} |")
    print(json.dumps({f"{name}, per CPU second [env-steps/s]": rate for name, rate in CPU_RATES.items()}, indent=1))


if __name__ == "__main__":
    main()

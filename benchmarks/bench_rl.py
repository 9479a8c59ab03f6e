"""RL training throughput on 2 cores (issue 8): PPO and SAC on the native vector env of 16
cars with the joint estimator in the loop (the default training setup), env steps per wall
second including the learner's updates.

Run: ``.venv/bin/python benchmarks/bench_rl.py`` (or ``fourwis bench --only rl``).
"""

from __future__ import annotations

import tempfile
import time

from fourwis.training.rl import train

STEPS = {"ppo": 16_384, "sac": 8_192}


def _train(algo: str, out: str, steps: int) -> None:
    train(
        algo,
        out,
        steps,
        env_kwargs={"estimator": "joint"},
        n_envs=16,
        eval_every=10**9,
        checkpoint_every=10**9,
        progress=False,
        algo_overrides={"learning_starts": 1024} if algo == "sac" else None,
    )


def main() -> None:
    with tempfile.TemporaryDirectory() as out:  # untimed: numba cache loads and first-call set-up, which
        _train("ppo", out, 1)  # would otherwise fall on the first row only (~1 s of PPO's ~5 s)
    # (the rate first: benchmarks/side_by_side.py reads a row's first number)
    print("| algorithm | env-steps/s | env steps | wall [s] |")
    print("|---|---:|---:|---:|")
    for algo, steps in STEPS.items():
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            _train(algo, out, steps)
            wall = time.perf_counter() - start
        print(f"| {algo.upper()} | {steps / wall:,.0f} | {steps:,} | {wall:.1f} |")


if __name__ == "__main__":
    main()

"""Scale-out on this machine (issue 39): the headline comparison on the local process pool and
on a local Ray instance, side by side in one run, and RLlib PPO against stable-baselines3 PPO
in env steps per wall second on the same env and estimator.

1. ``fourwis compare`` (the headline matrix, its defaults) as a user runs it, each in a fresh
   process: ``--backend local`` and ``--backend ray`` (which starts its Ray instance: counted),
   wall time of each and whether their runs.csv are byte-identical.
2. PPO on the native vector env, 16 cars, the joint estimator in the loop (bench_rl.py's
   setup), rollouts of 16 x 256 steps, 4 updates: SB3 in this process, RLlib with one EnvRunner
   of 16 cars and with two of 8, or none (sampling in this process), the Learner in this process
   (the Ray instance started first, untimed). Env steps per wall second of the whole ``train``
   call, updates included, and for RLlib also within its training loop (without building the
   Algorithm: the EnvRunner actors' start and their envs).

Run: ``.venv/bin/python benchmarks/bench_cluster.py`` (or ``fourwis bench --only cluster``);
needs the ray extra. Prints the machine, date, commit and the commands with the numbers.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FOURWIS = [sys.executable, "-m", "fourwis.training.cli"]
RL_STEPS = 16_384  #: 4 PPO updates of 16 cars x 256 steps
ROUNDS = 2  #: local / ray pairs of the headline comparison


def _header() -> None:
    commit = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain"], capture_output=True, text=True).stdout
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    machine = platform.processor() or platform.machine()
    print(f"machine: {machine}, {os.cpu_count()} cores, Python {platform.python_version()}")
    print(f"date: {datetime.datetime.now().isoformat(timespec='minutes')}, load average before: {load}")
    print(f"commit: {commit}{' (with uncommitted changes)' if dirty.strip() else ''}")
    import ray

    print(f"ray {ray.__version__}")


def compare_side_by_side(rounds: int = ROUNDS) -> None:
    print("\n| fourwis compare (headline) | " + " | ".join(f"round {k + 1} wall [s]" for k in range(rounds)) + " |")
    print("|---|" + "---:|" * rounds)
    walls: dict[str, list[float]] = {"local": [], "ray": []}
    csvs = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(rounds):  # alternating, so that a change in the machine's load falls on both
            for backend in walls:
                out = Path(tmp) / f"{backend}{k}"
                command = [*FOURWIS, "compare", "--backend", backend, "--out", str(out)]
                start = time.perf_counter()
                subprocess.run(command, check=True, capture_output=True)
                walls[backend].append(time.perf_counter() - start)
                csvs.append((out / "runs.csv").read_bytes())
    for backend, times in walls.items():
        print(f"| `fourwis compare --backend {backend}` | " + " | ".join(f"{w:.1f}" for w in times) + " |")
    rows = len(csvs[0].splitlines()) - 1
    same = all(c == csvs[0] for c in csvs)
    print(f"\nruns.csv: {rows} runs, byte-identical in all {len(csvs)} runs on both backends: {same}")


def _sb3(out: str, steps: int) -> None:
    from fourwis.training.rl import train

    train("ppo", out, steps, env_kwargs={"estimator": "joint"}, n_envs=16, eval_every=10**9, checkpoint_every=10**9,
          progress=False)  # fmt: skip


def _rllib(out: str, steps: int, env_runners: int, n_envs: int) -> None:
    from fourwis.training.rllib import train

    train(out, steps, env_kwargs={"estimator": "joint"}, n_envs=n_envs, env_runners=env_runners, eval_every=10**9,
          checkpoint_every=10**9, progress=False)  # fmt: skip


def ppo_throughput() -> None:
    import ray

    ray.init(include_dashboard=False, logging_level="ERROR")
    runs = [
        ("stable-baselines3 PPO, 16 cars in this process", lambda out, n: _sb3(out, n)),
        ("RLlib PPO, no EnvRunner actor: 16 cars sampled in this process", lambda out, n: _rllib(out, n, 0, 16)),
        ("RLlib PPO, 1 EnvRunner x 16 cars", lambda out, n: _rllib(out, n, 1, 16)),
        ("RLlib PPO, 2 EnvRunners x 8 cars", lambda out, n: _rllib(out, n, 2, 8)),
    ]
    with tempfile.TemporaryDirectory() as out:  # untimed: numba cache loads, first-call set-up
        _sb3(str(Path(out) / "warm"), 1)
    print("\n| PPO, joint estimator, 16 cars | env steps | wall [s] | env-steps/s | in the training loop |")
    print("|---|---:|---:|---:|---:|")
    for name, run in runs:
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            run(str(Path(out) / "run"), RL_STEPS)
            wall = time.perf_counter() - start
            steps = json.loads((Path(out) / "run" / "config.json").read_text())["timesteps"]  # (as trained)
            progress = Path(out) / "run" / "progress.csv"  # RLlib's: steps / time since the Algorithm was built
            loop = f"{float(progress.read_text().splitlines()[-1].split(',')[-1]):,.0f}" if progress.exists() else "-"
        print(f"| {name} | {steps:,} | {wall:.1f} | {steps / wall:,.0f} | {loop} |")
    ray.shutdown()


def main() -> None:
    import importlib.util

    if importlib.util.find_spec("ray") is None:  # (fourwis bench runs every benchmark)
        print("bench_cluster needs the ray extra: pip install 'fourwis[ray]'")
        return
    _header()
    print(f"command: {' '.join([Path(sys.executable).name, *sys.argv])}")
    compare_side_by_side()
    ppo_throughput()


if __name__ == "__main__":
    main()

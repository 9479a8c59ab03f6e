"""Run directories of trained policies (``fourwis train``, with stable-baselines3 or RLlib):
what their config.json records, which files they hold, and the checks before a run is resumed
or replaced. Shared by :mod:`fourwis.training.rl` and :mod:`fourwis.training.rllib`."""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from fourwis.envs.sensors import Fault

EVALUATIONS = "evaluations.npz"  #: the run's evaluation log (SB3's EvalCallback format)
SHIPPED_POLICIES = Path(__file__).resolve().parent / "policies"  #: the trained policies shipped as package data
TORCH_THREADS = 1  #: 128-unit MLPs gain nothing from more threads, which would compete with the env


@dataclass(frozen=True)
class RunConfig:
    """What a run directory's ``config.json`` records: enough to rebuild env and policy.
    ``timesteps``: env steps the model has trained (at the start of training: those of the run
    resumed, else 0); ``requested_timesteps``: the total asked for, which SB3 rounds up to whole
    rollouts."""

    algo: str
    env_kwargs: dict
    seed: int
    n_envs: int
    timesteps: int
    requested_timesteps: int


REPLAY_BUFFER = "replay_buffer.pkl"  #: an off-policy run's replay buffer, saved with its final model
RUN_FILES = (
    "model.zip",
    "vecnormalize.pkl",
    "config.json",
    REPLAY_BUFFER,
    EVALUATIONS,
    "learning_curve.png",
    "learning_curve.csv",
    "checkpoints",
    "tb",
    ".evaluating",
    "policy",
    "obs_filter.pkl",
    "progress.csv",
    "algorithm",
)  #: what ``train`` writes into a run directory (the last four: an RLlib run's, training.rllib)


def other_run(out: Path, resume: str | Path | None) -> bool:
    """True if ``out`` holds a run (config.json or model.zip) other than the one ``resume`` continues."""
    if not any((out / name).exists() for name in ("config.json", "model.zip")):
        return False
    return resume is None or run_files(resume)[2].parent.resolve() != out.resolve()


def delete_run(out: Path) -> None:
    """Delete the files of the run in ``out`` (:data:`RUN_FILES`); anything else there stays."""
    for name in RUN_FILES:
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)


def check_resumable(
    resume: str | Path, algo: str, env_kwargs: dict, seed: int | None, n_envs: int | None, framework: str = "sb3"
) -> tuple[int, int]:
    """A resumed run continues the same algorithm on the same env with the same seed and cars
    (an off-policy replay buffer holds rows of n_envs cars): ValueError naming what differs from
    the resumed run's config.json (checked before anything is written; ``env_kwargs`` as :func:`as_json`
    gives them). Returns its (seed, n_envs)."""
    config_path = run_files(resume)[2]
    if not config_path.exists():
        raise ValueError(f"cannot resume {resume}: {config_path} is missing (its algorithm and env are unknown)")
    saved = read_run_config(config_path)
    if saved.get("framework", "sb3") != framework:
        raise ValueError(
            f"cannot resume {resume}: it was trained with --framework {saved.get('framework', 'sb3')}, not {framework}"
        )
    if saved["algo"] != algo:
        raise ValueError(f"cannot resume {resume}: it was trained with --algo {saved['algo']}, not {algo}")
    if saved["env_kwargs"] != env_kwargs:
        raise ValueError(
            f"cannot resume {resume}: it was trained with env_kwargs {saved['env_kwargs']!r}, "
            f"not {env_kwargs!r} (pass the same --env-kwargs)"
        )
    for name, value in (("seed", seed), ("n_envs", n_envs)):
        if value is not None and value != saved[name]:
            raise ValueError(
                f"cannot resume {resume}: it was trained with {name} {saved[name]}, not {value} "
                f"(leave it out to continue with the run's)"
            )
    return saved["seed"], saved["n_envs"]


def as_json(env_kwargs: dict) -> dict:
    """``env_kwargs`` as config.json holds them (an envs.sensors.Fault as a dict of its fields,
    numpy scalars and arrays as numbers and lists), which EnvConfig takes back: a run is built,
    resumed and evaluated from the same values. Any other object (a FrictionMap, VehicleParams,
    a steering callable) would not come back as itself: ValueError naming it."""

    def plain(value):
        if isinstance(value, Fault):
            return asdict(value)
        if isinstance(value, (np.generic, np.ndarray)):
            return value.tolist()
        raise TypeError(
            f"env_kwargs value {value!r} cannot be recorded in config.json and read back "
            "(give numbers, lists, strings and envs.sensors.Fault)"
        )

    try:
        return json.loads(json.dumps(env_kwargs, default=plain))
    except TypeError as err:
        raise ValueError(f"bad env_kwargs {env_kwargs!r}: {err}") from None


def minibatch(largest: int, rollout: int) -> int:
    """PPO's minibatch: the largest divisor of the rollout (steps x cars) not above ``largest``,
    so that every epoch splits the rollout into equal minibatches (1024 of 16 x 256 steps)."""
    return max(d for d in range(1, min(largest, rollout) + 1) if rollout % d == 0)


def checkpoint_step(path: Path) -> int:
    """The env steps of a checkpoint ``checkpoints/step_<steps>.zip``."""
    return int(path.stem.removeprefix("step_"))


def run_files(path: str | Path) -> tuple[Path, Path, Path]:
    """(model .zip, normaliser .pkl, run config.json) of a run directory (or its model.zip) or of
    a checkpoint's .zip (checkpoints/ inside its run directory). ``training/policies/<name>``
    that is no path from here is the policy shipped in the installed package (README's
    examples, run anywhere)."""
    given = path = Path(path)
    if not path.exists() and path.parts[:2] == ("training", "policies"):
        path = SHIPPED_POLICIES.joinpath(*path.parts[2:])
    if not path.exists():
        raise FileNotFoundError(f"no trained policy at {given}: no such run directory or checkpoint")
    if path.is_file() and path.name == "model.zip":  # a run's final model: the run directory's files
        path = path.parent
    files = (
        (path / "model.zip", path / "vecnormalize.pkl", path / "config.json")
        if path.is_dir()
        else (path, path.with_suffix(".pkl"), path.parent.parent / "config.json")
    )
    if path.is_dir() and (path / "policy").is_dir():  # an RLlib run or checkpoint (training.rllib)
        config = path / "config.json" if (path / "config.json").exists() else path.parent.parent / "config.json"
        files = (path / "policy", path / "obs_filter.pkl", config)
    for p in files[:2]:  # the config is read only where a policy is rebuilt (PolicyController)
        if not p.exists():
            latest = (
                max((path / "checkpoints").glob("step_*.zip"), key=checkpoint_step, default=None)
                if path.is_dir()
                else None
            )
            hint = f" (an interrupted run? its latest checkpoint is {latest})" if latest else ""
            raise FileNotFoundError(f"no trained policy at {path}: {p} is missing{hint}")
    return files


#: what config.json must hold, by type, for a run to be rebuilt (RunConfig's fields that are read)
CONFIG_FIELDS = {"algo": str, "env_kwargs": dict, "seed": int, "n_envs": int, "timesteps": int}


def read_run_config(path: str | Path) -> dict:
    """A run directory's config.json (:class:`RunConfig`) as a dict; ValueError naming the file
    when it is not JSON or lacks a field (:data:`CONFIG_FIELDS`) of the right type, as a damaged
    or hand-edited file would (FileNotFoundError when it is missing)."""
    try:
        config = json.loads(Path(path).read_bytes())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path} is damaged: not the JSON run config fourwis train writes ({err})") from None
    if not isinstance(config, dict):
        raise ValueError(f"{path} is damaged: expected a JSON object (a run config), got {type(config).__name__}")
    wrong = [
        f"{name} ({kind.__name__})"
        for name, kind in CONFIG_FIELDS.items()
        if not isinstance(config.get(name), kind) or (kind is int and isinstance(config.get(name), bool))
    ]
    if wrong:
        raise ValueError(f"{path} is damaged: it lacks a valid {', '.join(wrong)}")
    return config

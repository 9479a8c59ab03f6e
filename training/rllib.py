"""Reinforcement learning with RLlib, on its current API stack (RLModule, Learner, EnvRunner).

:func:`train` registers the env with RLlib (:data:`ENV_NAME`, built by :func:`make_env`),
runs ``env_runners`` EnvRunner actors, each stepping ``n_envs`` cars of ONE native
:class:`envs.gym_env.YawStabilityVectorEnv` (gymnasium's VECTOR_ENTRY_POINT mode: no per-car
copies of the env), a local Learner, and RLlib's MeanStdFilter on the observations (the
counterpart of SB3's VecNormalize). PPO only, on the settings of SB3's PPO
(:data:`training.rl_config.ALGO_CONFIGS`, translated by :func:`ppo_config`).

A run directory holds ``config.json`` (as SB3's runs, plus ``framework: "rllib"`` and
``env_runners``), the exported policy ``policy/`` (the RLModule, ``RLModule.save_to_path``)
with ``obs_filter.pkl`` (the observation filter's state), ``algorithm/`` (the final Algorithm
checkpoint: learner, optimiser, filters, counters), ``progress.csv`` (per training iteration:
env steps, training and held-out evaluation returns, env steps/s) and ``checkpoints/step_N/``
(Algorithm checkpoints, each with its own ``policy/`` and ``obs_filter.pkl``, so
``rl:<run>/checkpoints/step_N`` runs too). ``resume`` continues a run or a checkpoint
(``Algorithm.restore_from_path``) with its env, seed and cars, its cars reseeded from (seed,
steps trained) as SB3's resumed runs are. ``fourwis evaluate`` and
``rl:<run>`` controllers load it as they load a stable-baselines3 run
(:class:`training.rl.PolicyController`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import pickle
import shutil
import time
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from fourwis.training.rl_config import ALGO_CONFIGS, EVAL_SCENARIO
from fourwis.training.runs import (
    TORCH_THREADS,
    RunConfig,
    as_json,
    check_resumable,
    checkpoint_step,
    delete_run,
    minibatch,
    other_run,
)  # fmt: skip

ENV_NAME = "fourwis-yaw-stability"  #: the env's name in RLlib's registry
POLICY = "policy"  #: the exported RLModule's folder in a run directory or checkpoint
OBS_FILTER = "obs_filter.pkl"  #: the observation filter's state beside it
PROGRESS = "progress.csv"
ALGORITHM = "algorithm"  #: the final Algorithm checkpoint in a run directory (what --resume of the run restores)
RLLIB_EXTRA_MISSING = "fourwis train --framework rllib needs RLlib: pip install 'fourwis[ray]'"


def _rllib():
    try:
        import ray.rllib  # noqa: F401
    except ModuleNotFoundError as err:  # an optional dependency (the ray extra)
        raise ModuleNotFoundError(RLLIB_EXTRA_MISSING) from err


def make_env(env_config: dict):
    """RLlib's env creator: the native vector env of ``num_envs`` cars (what an EnvRunner asks
    for in VECTOR_ENTRY_POINT mode) or, without ``num_envs``, the single env; ``env_config``
    holds the env keyword arguments. Its infos keep only the per-car arrays (the batched truth
    and estimate are NamedTuples, which RLlib's list-of-dicts infos cannot split). It also sets
    the EnvRunner's torch threads to training.runs.TORCH_THREADS: a remote EnvRunner came up with
    one per core, and its policy's forward passes then competed with the env for them."""
    import gymnasium as gym
    import torch

    torch.set_num_threads(TORCH_THREADS)

    from fourwis.envs.gym_env import YawStabilityEnv, YawStabilityVectorEnv

    kwargs = dict(env_config)
    num_envs = kwargs.pop("num_envs", None)
    if num_envs is None:
        return YawStabilityEnv(**kwargs)

    class ArrayInfos(gym.vector.VectorWrapper):
        def reset(self, **reset_kwargs):
            obs, info = self.env.reset(**reset_kwargs)
            return obs, _arrays(info)

        def step(self, actions):
            obs, reward, terminated, truncated, info = self.env.step(actions)
            return obs, reward, terminated, truncated, _arrays(info)

    return ArrayInfos(YawStabilityVectorEnv(num_envs=num_envs, **kwargs))


def _arrays(info: dict) -> dict:
    return {k: v for k, v in info.items() if isinstance(v, np.ndarray)}


def ppo_config(
    env_kwargs: dict,
    n_envs: int,
    env_runners: int,
    seed: int,
    eval_kwargs: dict | None = None,
    eval_episodes: int = 4,
    overrides: dict | None = None,
):
    """RLlib's PPOConfig for the env with ``env_kwargs``: ``env_runners`` EnvRunners (0: sample
    in this process) of ``n_envs`` cars each, SB3's PPO settings (rollouts of ``n_steps`` per
    car, minibatches of up to 1024 that split the batch evenly, 10 epochs, two 128-unit tanh
    layers, value-loss weight 0.5, gradient norm 0.5, no KL penalty, no value clipping),
    ``overrides`` (``n_steps``, ``batch_size``, ``n_epochs``) on top. ``eval_kwargs``: the
    held-out evaluation env's keyword arguments (``algo.evaluate()``, ``eval_episodes`` episodes)."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.connectors.env_to_module import MeanStdFilter
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.tune.registry import register_env

    register_env(ENV_NAME, make_env)
    settings = {**ALGO_CONFIGS["ppo"], **(overrides or {})}
    batch = settings["n_steps"] * n_envs * max(1, env_runners)
    config = (
        PPOConfig()
        .environment(ENV_NAME, env_config=env_kwargs)
        .env_runners(
            num_env_runners=env_runners,
            num_envs_per_env_runner=n_envs,
            gym_env_vectorize_mode="vector_entry_point",
            rollout_fragment_length=settings["n_steps"],
            env_to_module_connector=lambda env, spaces=None, device=None: MeanStdFilter(clip_by_value=10.0),
        )
        .training(
            train_batch_size_per_learner=batch,
            minibatch_size=minibatch(settings["batch_size"], batch),
            num_epochs=settings["n_epochs"],
            lr=settings["learning_rate"],
            gamma=settings["gamma"],
            lambda_=settings["gae_lambda"],
            clip_param=settings["clip_range"],
            entropy_coeff=settings["ent_coef"],
            vf_loss_coeff=0.5,
            grad_clip=0.5,
            grad_clip_by="global_norm",
            use_kl_loss=False,
            vf_clip_param=math.inf,
        )
        .rl_module(
            model_config=DefaultModelConfig(
                fcnet_hiddens=list(settings["policy_kwargs"]["net_arch"]), fcnet_activation="tanh"
            )
        )
        .learners(num_learners=0)
        .debugging(seed=seed)
    )
    if eval_kwargs is not None:
        config = config.evaluation(
            evaluation_interval=None,  # (run when due, by train)
            evaluation_num_env_runners=1,  # (the driver's own EnvRunner has no env once there are remote ones)
            evaluation_duration=eval_episodes,
            evaluation_duration_unit="episodes",
            # no CPU of its own: it is idle while the EnvRunners sample, and does not keep them waiting for one
            evaluation_config={
                "env_config": eval_kwargs,
                "num_envs_per_env_runner": min(eval_episodes, 4),
                "num_cpus_per_env_runner": 0,
            },
        )
    return config


def _init_ray(address: str | None) -> None:
    import ray

    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, logging_level="WARNING")


def train(
    out: str | Path,
    timesteps: int,
    seed: int | None = None,
    env_kwargs: dict | None = None,
    n_envs: int | None = None,
    env_runners: int = 1,
    eval_scenario: str = EVAL_SCENARIO,
    eval_every: int = 40_000,
    eval_episodes: int = 4,
    checkpoint_every: int = 50_000,
    progress: bool = True,
    algo_overrides: dict | None = None,
    overwrite: bool = False,
    address: str | None = None,
    resume: str | Path | None = None,
) -> Path:
    """Train RLlib PPO until ``timesteps`` env steps (rounded up to whole training batches of
    ``n_steps`` x ``n_envs`` x ``env_runners``; RLlib's sampler may take a few steps more, which
    config.json counts) on a Ray instance (``address`` as
    training.pool.Backend's: None starts a local one); writes the run directory ``out`` and
    returns its exported ``policy/``. Checkpoints every ``checkpoint_every`` env steps, a
    held-out evaluation on ``eval_scenario`` every ``eval_every``. ``seed`` and ``n_envs``
    default to 0 and 16 (or the resumed run's); an ``out`` holding another run than the one
    ``resume`` continues is refused unless ``overwrite``."""
    _rllib()
    from fourwis.core.checks import is_integer
    from fourwis.envs.gym_env import EnvConfig
    from fourwis.training.io import atomic_write_json, check_writable

    env_kwargs = as_json(dict(env_kwargs or {}))
    checkpoint, resumed_steps = None, 0
    if resume is not None:
        seed, n_envs = check_resumable(resume, "ppo", env_kwargs, seed, n_envs, framework="rllib")
        checkpoint, resumed_steps = _resumed(Path(resume))
        if resumed_steps >= timesteps:
            raise ValueError(
                f"cannot resume {resume}: it already has {resumed_steps} timesteps and --timesteps is the "
                f"total to reach, so give more than {resumed_steps}, not {timesteps}"
            )
    seed = 0 if seed is None else seed
    n_envs = 16 if n_envs is None else n_envs
    for name, value, low in (
        ("timesteps", timesteps, 1),
        ("seed", seed, 0),
        ("n_envs", n_envs, 1),
        ("env_runners", env_runners, 0),
        ("eval_every", eval_every, 1),
        ("checkpoint_every", checkpoint_every, 1),
        ("eval_episodes", eval_episodes, 1),
    ):
        if not (is_integer(value) and value >= low):
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    try:
        env_config = EnvConfig(**env_kwargs)
    except TypeError as err:
        raise ValueError(
            f"bad env_kwargs {env_kwargs!r}: {err}; known: {[f.name for f in fields(EnvConfig)]}"
        ) from None
    if env_config.privileged:
        raise ValueError("privileged (asymmetric actor-critic) training is stable-baselines3's: use --framework sb3")
    out = check_writable(out)
    replaces = other_run(out, resume)
    if replaces and not overwrite:
        raise ValueError(
            f"{out} already holds a run: continue it with --resume {out}, or give a new --out (--overwrite replaces it)"
        )
    if resume is not None:
        _check_no_abandoned_branch(checkpoint, resumed_steps, out)
    eval_kwargs = {**env_kwargs, "scenario": eval_scenario}
    for name in ("speed_kph", "mu", "scenario_kwargs", "max_episode_steps"):  # the held-out scenario, run whole
        eval_kwargs.pop(name, None)
    import torch

    torch.set_num_threads(TORCH_THREADS)
    _init_ray(address)
    import ray

    cpus = ray.cluster_resources().get("CPU", 0)
    if address is None and env_runners > cpus:  # (a cluster may scale up to them; this machine does not)
        raise ValueError(
            f"--env-runners {env_runners} needs as many CPUs, but the local Ray instance has {cpus:g}: "
            "give fewer, or --address of a cluster"
        )
    evaluated = (eval_every * (resumed_steps // eval_every + 1)) <= timesteps  # (else no evaluation EnvRunner)
    # a resumed run's cars carry on through the training distribution rather than replay its start
    car_seed = seed if resume is None else int(np.random.SeedSequence([seed, resumed_steps]).generate_state(1)[0])
    config = ppo_config(
        env_kwargs, n_envs, env_runners, car_seed, eval_kwargs if evaluated else None, eval_episodes, algo_overrides
    )
    rows = _earlier_progress(Path(resume), resumed_steps) if resume is not None else []
    if replaces:
        delete_run(out)
    out.mkdir(parents=True, exist_ok=True)
    algo = config.build_algo()
    if checkpoint is not None:
        algo.restore_from_path(str(checkpoint.resolve()))
    run_config = RunConfig("ppo", env_kwargs, int(seed), int(n_envs), resumed_steps, int(timesteps))
    record = {**asdict(run_config), "framework": "rllib", "env_runners": int(env_runners)}
    atomic_write_json(out / "config.json", record)
    steps = last_checkpoint = last_eval = resumed_steps
    from tqdm import tqdm

    bar = tqdm(total=timesteps, disable=not progress, desc="rllib ppo", unit="step")
    start = time.perf_counter()
    interrupted = False
    try:
        while steps < timesteps:
            result = algo.train()
            runners = result["env_runners"]
            now = int(runners["num_env_steps_sampled_lifetime"])
            bar.update(now - steps)
            steps = now
            row = {
                "iteration": int(result["training_iteration"]),
                "timesteps": steps,
                "episode_return_mean": runners.get("episode_return_mean", math.nan),
                "eval_return_mean": math.nan,
                "env_steps_per_s": (steps - resumed_steps) / (time.perf_counter() - start),
            }
            if steps // eval_every > last_eval // eval_every:
                last_eval = steps
                row["eval_return_mean"] = algo.evaluate()["env_runners"].get("episode_return_mean", math.nan)
            rows.append(row)
            _write_progress(out, rows)
            if steps // checkpoint_every > last_checkpoint // checkpoint_every:
                last_checkpoint = steps
                _checkpoint(algo, out / "checkpoints" / f"step_{steps:09d}")
    except KeyboardInterrupt:  # keep the policy as it stands, then stop
        interrupted = True
    finally:
        bar.close()
    atomic_write_json(out / "config.json", {**record, "timesteps": steps})
    _export(algo, out)
    _save_algorithm(algo, out / ALGORITHM)
    algo.stop()
    if interrupted:
        raise KeyboardInterrupt(f"interrupted after {steps:,} env steps; saved {out / POLICY}")
    return out / POLICY


def _write_progress(out: Path, rows: list[dict]) -> None:
    from fourwis.training.io import atomic_write_text

    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()} for row in rows)
    atomic_write_text(out / PROGRESS, text.getvalue())


def _checkpoint(algo, path: Path) -> None:
    """The Algorithm's checkpoint (resumable) with the exported policy inside (``rl:`` runs it)."""
    _save_algorithm(algo, path, export=True)


def _save_algorithm(algo, path: Path, export: bool = False) -> None:
    """``algo.save_to_path`` (and with ``export`` the policy, :func:`_export`) into a temporary
    folder beside ``path``, renamed into place: whole or absent."""
    tmp = path.with_name(f".{path.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    algo.save_to_path(str(tmp.resolve()))
    if export:
        _export(algo, tmp)
    shutil.rmtree(path, ignore_errors=True)
    os.replace(tmp, path)


def _resumed(resume: Path) -> tuple[Path, int]:
    """The Algorithm checkpoint that ``resume`` (a run directory or its checkpoints/step_N)
    continues, and its env steps; FileNotFoundError if it has none."""
    if (resume / "checkpoints").is_dir() or (resume / "config.json").exists():  # a run directory
        checkpoint = resume / ALGORITHM
        steps = json.loads((resume / "config.json").read_text())["timesteps"]
    else:
        checkpoint, steps = resume, checkpoint_step(resume)
    if not (checkpoint / "algorithm_state.pkl").exists() and not any(checkpoint.glob("*.json")):
        raise FileNotFoundError(f"cannot resume {resume}: no RLlib Algorithm checkpoint at {checkpoint}")
    return checkpoint, int(steps)


def _check_no_abandoned_branch(checkpoint: Path, steps: int, out: Path) -> None:
    """ValueError if resuming into the resumed run's own folder ``out`` would leave checkpoints
    beyond the resumed step beside the new branch's (as training.rl refuses for SB3 runs)."""
    run = checkpoint.parent if checkpoint.name == ALGORITHM else checkpoint.parent.parent
    if run.resolve() != out.resolve():
        return
    later = sorted(p.name for p in (out / "checkpoints").glob("step_*") if checkpoint_step(p) > steps)
    if later:
        raise ValueError(
            f"resuming {checkpoint} into its own run {out} would leave the run's later checkpoints {later} "
            "beside the new branch's: resume the latest checkpoint, or give a new --out"
        )


def _earlier_progress(resume: Path, steps: int) -> list[dict]:
    """The resumed run's progress.csv rows up to ``steps`` (the new rows follow them)."""
    run = resume if (resume / "config.json").exists() else resume.parent.parent
    path = run / PROGRESS
    if not path.exists():
        return []
    rows = list(csv.DictReader(io.StringIO(path.read_text())))
    return [{k: (int(v) if k in ("iteration", "timesteps") else float(v)) for k, v in r.items()} for r in rows
            if int(r["timesteps"]) <= steps]  # fmt: skip


def _export(algo, folder: Path) -> None:
    """The trained RLModule into ``folder/policy`` and the observation filter's state into
    ``folder/obs_filter.pkl`` (the policy's own input transform, merged over the EnvRunners)."""
    from fourwis.training.io import atomic_write

    policy = folder / POLICY
    tmp = folder / f".{POLICY}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    algo.get_module().save_to_path(str(tmp.resolve()))
    shutil.rmtree(policy, ignore_errors=True)
    os.replace(tmp, policy)
    state = _filter_state(algo)
    atomic_write(folder / OBS_FILTER, lambda p: p.write_bytes(pickle.dumps(state)))


def _filter_state(algo) -> dict:
    """The MeanStdFilter's state from the Algorithm's env-to-module connector (merged over the
    EnvRunners), or from its local EnvRunner's when it samples itself."""
    from ray.rllib.connectors.env_to_module import MeanStdFilter

    pipeline = getattr(algo, "env_to_module_connector", None)
    if pipeline is None:
        pipeline = algo.env_runner._env_to_module
    for piece in pipeline.connectors:
        if isinstance(piece, MeanStdFilter):
            return piece.get_state()
    raise RuntimeError("the run's env-to-module connector has no MeanStdFilter")


class RLlibPolicy:
    """An exported RLlib policy (``folder/policy`` and ``folder/obs_filter.pkl``): deterministic
    actions (the action distribution's mode) for observations (N, n_obs) float32, normalised by
    the run's frozen filter statistics (RLlib's own MeanStdFilter transform)."""

    def __init__(self, folder: str | Path):
        _rllib()
        import torch
        from ray.rllib.core.rl_module.rl_module import RLModule
        from ray.rllib.utils.filter import MeanStdFilter, RunningStat

        folder = Path(folder)
        self.module = RLModule.from_checkpoint(str((folder / POLICY).resolve()))
        self._dist = self.module.get_inference_action_dist_cls()
        state = next(iter(pickle.loads((folder / OBS_FILTER).read_bytes()).values()))
        self.filter = MeanStdFilter(
            state["shape"], demean=state["de_mean_to_zero"], destd=state["de_std_to_one"], clip=state["clip_by_value"]
        )
        self.filter.running_stats = RunningStat.from_state(state["running_stats"][0])
        self._torch = torch

    def normalise(self, obs: np.ndarray) -> np.ndarray:
        """The observation filter, its statistics frozen (no update)."""
        return np.asarray(self.filter(np.asarray(obs, dtype=np.float32), update=False), dtype=np.float32)

    def predict(self, obs: np.ndarray) -> np.ndarray:
        """Actions (N, n_act) for raw observations (N, n_obs)."""
        with self._torch.no_grad():
            out = self.module.forward_inference({"obs": self._torch.from_numpy(self.normalise(obs))})
            dist = self._dist.from_logits(out["action_dist_inputs"]).to_deterministic()
            return dist.sample().numpy()


def is_rllib_run(config_path: Path) -> bool:
    """True if the run whose config.json is ``config_path`` was trained with RLlib."""
    import json

    return config_path.exists() and json.loads(config_path.read_text()).get("framework") == "rllib"

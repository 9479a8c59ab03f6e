"""Reinforcement learning with stable-baselines3 on the native vector env.

``train`` runs PPO, SAC or TD3 on :class:`envs.gym_env.YawStabilityVectorEnv` through
:class:`SB3VecEnv` (SB3 2.x does not consume ``gymnasium.vector`` envs), with VecNormalize,
an EvalCallback on a held-out scenario, atomic checkpoints, TensorBoard logs, a progress bar
and resume. A run directory holds ``model.zip``, ``vecnormalize.pkl`` and ``config.json``
(+ ``checkpoints/``, ``evaluations.npz``, ``learning_curve.png``, ``tb/``, and for SAC / TD3
the replay buffer ``replay_buffer.pkl``); ``train`` refuses an ``--out`` that holds another
run unless told to overwrite it.

Resume: a run continues from its ``model.zip`` or a checkpoint, with the run's seed and number
of cars. An off-policy run's replay buffer (~26 MB) is saved with the final model and with the
latest checkpoint only; resumed from an earlier checkpoint, the run refills its buffer with
``learning_starts`` steps of random actions (SB3's warm-up) before it trains again. The
resumed part reseeds its cars from (seed, steps trained), so its episodes carry on through
the training distribution instead of replaying the run's first ones.

:class:`PolicyController` runs a trained policy as a stability controller inside
:func:`envs.simulation.simulate`, so ``fourwis evaluate`` and ``fourwis compare`` judge it
with the same metrics as the DYC (controller name ``rl:<run dir>``).

Hyperparameters (:data:`ALGO_CONFIGS`): SB3 defaults scaled down for a 2-core CPU; networks of
two 128-unit layers (the observation is 14 numbers); gamma 0.99, i.e. a ~2 s horizon at the
20 ms control step, longer than the yaw and sideslip transients the reward penalises.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
import shutil
import time
from dataclasses import asdict, fields, replace
from pathlib import Path

import numpy as np
from gymnasium.vector import AutoresetMode

from fourwis.training.rl_config import ALGO_CONFIGS, ALGOS, EVAL_SCENARIO, RL_EXTRA_MISSING

try:
    from stable_baselines3.common.vec_env import VecEnv
except ModuleNotFoundError as err:  # an optional dependency (the rl extra)
    raise ModuleNotFoundError(RL_EXTRA_MISSING) from err

from fourwis.core.checks import is_integer
from fourwis.envs.gym_env import N_OBS, AgentController, EnvConfig, YawStabilityVectorEnv, state_observation
from fourwis.training.asymmetric import POLICIES
from fourwis.training.io import atomic_write, atomic_write_json, atomic_write_text, check_writable, pyplot
from fourwis.training.runs import (
    EVALUATIONS,
    REPLAY_BUFFER,
    TORCH_THREADS,
    RunConfig,
    as_json,
    check_resumable,
    checkpoint_step,
    delete_run,
    minibatch,
    other_run,
    read_run_config,
    run_files,
)  # fmt: skip


def _algo_class(algo: str):
    if algo not in ALGOS:
        raise ValueError(f"unknown algo {algo!r}; known: {list(ALGOS)}")
    import stable_baselines3 as sb3

    return {"ppo": sb3.PPO, "sac": sb3.SAC, "td3": sb3.TD3}[algo]


def _check_train_extras(progress: bool) -> None:
    """ModuleNotFoundError naming the extra before a run writes anything: SB3's tensorboard log
    and progress bar (rich, tqdm) need the rl extra, the learning curve needs matplotlib (plots).
    (Found missing only by SB3 once training began, they had left a config.json without a model
    that blocked the next try.)"""
    needed = ("tensorboard", "rich", "tqdm") if progress else ("tensorboard",)
    missing = [name for name in needed if importlib.util.find_spec(name) is None]
    if missing:
        raise ModuleNotFoundError(f"fourwis train needs {missing}: pip install 'fourwis[rl]'")
    pyplot()


#: the per-step info keys SB3VecEnv gives each car (the single env's, less the truth and estimate)
PER_STEP_INFO = ("action_clipped", "beta", "yaw_rate_error", "path_deviation", "spin_out", "phase_plane_index")


class SB3VecEnv(VecEnv):
    """A :class:`YawStabilityVectorEnv` (same-step autoreset) as an SB3 ``VecEnv``:
    ``terminal_observation`` and ``TimeLimit.truncated`` in the infos, Monitor-style
    ``episode`` records (r, l, t), the env's ``episode_metrics`` and each car's per-step keys
    (:data:`PER_STEP_INFO`; the truth and estimate are left out). Rendered, it shows car 0
    (``get_images`` gives its one frame), so SB3's ``VecVideoRecorder`` records car 0. Its
    ``episode`` records are a Monitor's (``env_is_wrapped(Monitor)`` is True, so SB3's
    ``evaluate_policy`` reads them; a ``VecMonitor`` around it is not needed). The cars are one
    env object: ``set_attr`` and ``env_method`` act on all of them (other ``indices`` are
    refused), and ``set_options`` takes one options dict for every car."""

    def __init__(self, env: YawStabilityVectorEnv):
        if env.autoreset_mode != AutoresetMode.SAME_STEP:
            raise ValueError(
                f"SB3 needs a vector env that resets in the same step; got autoreset_mode "
                f"{env.autoreset_mode.value!r}: build it with autoreset_mode='SameStep'"
            )
        self.env = env
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self.metadata = {**self.metadata, "render_fps": env.metadata["render_fps"]}
        self._actions: np.ndarray | None = None
        self._start = time.time()

    def reset(self) -> np.ndarray:
        seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
        options = self._options[0]
        try:  # (the same dict for every car after set_options(dict); equal ones from a list)
            differ = any(o is not options and o != options for o in self._options)
        except ValueError:  # arrays inside, compared elementwise: take them as different
            differ = True
        if differ:
            raise ValueError(f"the vector env takes one reset options dict for every car, got {self._options!r}")
        obs, _ = self.env.reset(seed=seeds, options=options or None)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, reward, terminated, truncated, info = self.env.step(self._actions)
        done = terminated | truncated
        # each car's per-step keys (action_clipped, beta, ...), as a DummyVecEnv of single envs gives
        # them; a finished car's are those of its last step
        last = info.get("final_info", {})
        columns = [(np.where(done, last[k], info[k]) if done.any() else info[k]).tolist() for k in PER_STEP_INFO]
        infos: list[dict] = [dict(zip(PER_STEP_INFO, row)) for row in zip(*columns)]  # (column-wise: ~5x cheaper)
        for b in np.flatnonzero(done):
            metrics = last["episode_metrics"][b]
            infos[b].update(
                {
                    "terminal_observation": info["final_obs"][b],
                    "TimeLimit.truncated": bool(truncated[b] and not terminated[b]),
                    "episode": {
                        "r": metrics["return"],
                        "l": metrics["length"],
                        "t": round(time.time() - self._start, 6),
                    },
                    "episode_metrics": metrics,
                }
            )
        return obs, reward.astype(np.float32), done, infos

    def close(self) -> None:
        self.env.close()

    def get_images(self) -> list[np.ndarray | None]:
        """Car 0's frame as a one-element list ([None] unless ``render_mode`` is rgb_array)."""
        frames = self.env.render() if self.env.render_mode == "rgb_array" else None  # (None before a reset)
        return [frames[0]] if frames is not None else [None]

    def get_attr(self, attr_name: str, indices=None) -> list:
        return [getattr(self.env, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        self._all_cars(indices, "set_attr")
        setattr(self.env, attr_name, value)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list:
        self._all_cars(indices, "env_method")
        return [getattr(self.env, method_name)(*args, **kwargs)] * self.num_envs

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        """True for SB3's Monitor: the infos carry its ``episode`` records."""
        from stable_baselines3.common.monitor import Monitor

        return [wrapper_class is Monitor] * len(self._indices(indices))

    def _all_cars(self, indices, method: str) -> None:
        """ValueError naming ``method`` unless ``indices`` select every car."""
        if sorted(self._indices(indices)) != list(range(self.num_envs)):
            raise ValueError(
                f"{method}: the cars are one vector env, which acts on all of them at once, not on indices {indices!r}"
            )

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)


def _vec_env(env_kwargs: dict, n_envs: int, seed: int):
    env = SB3VecEnv(YawStabilityVectorEnv(num_envs=n_envs, autoreset_mode=AutoresetMode.SAME_STEP, **env_kwargs))
    env.seed(seed)
    return env


def _atomic_save_model(model, path: Path) -> Path:
    return atomic_write(path, lambda tmp: model.save(tmp))


def _atomic_save_normalizer(normalizer, path: Path) -> Path:
    return atomic_write(path, lambda tmp: normalizer.save(tmp))


def _atomic_save_replay_buffer(model, path: Path) -> Path:
    return atomic_write(path, lambda tmp: model.save_replay_buffer(tmp))


def _callbacks(out: Path, eval_env, checkpoint_every: int, eval_every: int, eval_episodes: int, resumed: bool):
    from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    def due(callback, every: int) -> bool:
        """True once each time the run's step count passes a multiple of ``every`` (counted over
        the whole run, so a resumed run keeps the schedule); ``callback.last`` is the step count
        at the previous such time or at the start of training."""
        if callback.num_timesteps // every <= callback.last // every:
            return False
        callback.last = callback.num_timesteps
        return True

    class AtomicCheckpoint(BaseCallback):
        """Every ``checkpoint_every`` env steps: model + normaliser into checkpoints/, atomically.
        PPO's are taken after the update of the rollout that passed the step (at the next
        rollout's start or at the end of training), so that step_N holds the policy trained on
        N steps, as model.zip does (SB3 calls _on_step while it collects, before the update)."""

        def _on_training_start(self) -> None:
            self.last = self.num_timesteps
            self.on_policy = isinstance(self.model, OnPolicyAlgorithm)

        def _on_step(self) -> bool:
            if not self.on_policy:
                self._save()
            return True

        def _on_rollout_start(self) -> None:
            if self.on_policy:
                self._save()

        def _on_training_end(self) -> None:
            if self.on_policy:
                self._save()

        def _save(self) -> None:
            if due(self, checkpoint_every):
                stem = out / "checkpoints" / f"step_{self.num_timesteps:09d}"
                model_path = _atomic_save_model(self.model, stem.with_suffix(".zip"))
                _atomic_save_normalizer(self.model.get_vec_normalize_env(), stem.with_suffix(".pkl"))
                if hasattr(self.model, "replay_buffer"):  # the latest checkpoint's only (~26 MB each)
                    buffer = _atomic_save_replay_buffer(self.model, _replay_buffer_path(model_path))
                    for old in buffer.parent.glob("replay_buffer_step_*.pkl"):
                        if old != buffer:
                            old.unlink()

    class Evaluation(EvalCallback):
        """SB3's evaluation at every multiple of ``eval_every`` env steps of the run (a resumed
        run keeps the schedule and extends its evaluations.npz); the file is replaced atomically."""

        def __init__(self) -> None:
            super().__init__(
                eval_env,
                n_eval_episodes=eval_episodes,
                eval_freq=1,
                log_path=str(out / ".evaluating"),
                best_model_save_path=None,
                deterministic=True,
                verbose=0,
            )
            self.target = out / EVALUATIONS

        def _on_training_start(self) -> None:
            self.last = self.num_timesteps
            if resumed and self.target.exists():  # earlier evaluations, up to the resumed step
                with np.load(self.target) as earlier:
                    keep = earlier["timesteps"] <= self.num_timesteps
                    self.evaluations_timesteps = list(earlier["timesteps"][keep])
                    self.evaluations_results = list(earlier["results"][keep])
                    self.evaluations_length = list(earlier["ep_lengths"][keep])

        def _on_step(self) -> bool:
            if not due(self, eval_every):
                return True
            go_on = super()._on_step()  # writes .evaluating/evaluations.npz
            os.replace(out / ".evaluating" / EVALUATIONS, self.target)
            return go_on

    return [AtomicCheckpoint(), Evaluation()]


def train(
    algo: str,
    out: str | Path,
    timesteps: int,
    seed: int | None = None,
    env_kwargs: dict | None = None,
    n_envs: int | None = None,
    eval_scenario: str = EVAL_SCENARIO,
    eval_every: int = 40_000,
    eval_episodes: int = 4,
    checkpoint_every: int = 50_000,
    resume: str | Path | None = None,
    progress: bool = True,
    algo_overrides: dict | None = None,
    overwrite: bool = False,
) -> Path:
    """Train ``algo`` until ``timesteps`` env steps in total (counting a resumed checkpoint's, so
    more than it has; rounded up to whole rollouts); writes the run directory ``out`` and returns
    the path of ``model.zip``. An ``out`` holding another run than the one resumed is refused
    unless ``overwrite`` (which deletes that run's files first). ``seed`` and ``n_envs``
    default to 0 and 16, or to the resumed run's (other values are refused there)."""
    algo_class = _algo_class(algo)
    _check_train_extras(progress)
    import torch

    torch.set_num_threads(TORCH_THREADS)
    if not (is_integer(timesteps) and timesteps > 0):
        raise ValueError(f"timesteps must be a positive integer, got {timesteps!r}")
    env_kwargs = as_json(dict(env_kwargs or {}))  # as config.json records them, so resume and rl: read the same
    if resume is not None:
        seed, n_envs = check_resumable(resume, algo, env_kwargs, seed, n_envs)
        _check_no_abandoned_branch(resume, Path(out))
    seed = 0 if seed is None else seed
    n_envs = 16 if n_envs is None else n_envs
    if not (is_integer(seed) and seed >= 0):
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not (is_integer(n_envs) and n_envs > 0):
        raise ValueError(f"n_envs must be a positive integer, got {n_envs!r}")
    for name, value in (
        ("eval_every", eval_every),
        ("checkpoint_every", checkpoint_every),
        ("eval_episodes", eval_episodes),
    ):
        if not (is_integer(value) and value > 0):
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    timesteps, seed, n_envs = int(timesteps), int(seed), int(n_envs)  # (numpy integers too; config.json takes int)
    eval_every, checkpoint_every, eval_episodes = int(eval_every), int(checkpoint_every), int(eval_episodes)
    try:
        env_config = EnvConfig(**env_kwargs)  # validate now, with clear errors
    except TypeError as err:
        raise ValueError(
            f"bad env_kwargs {env_kwargs!r}: {err}; known: {[f.name for f in fields(EnvConfig)]}"
        ) from None
    out = check_writable(out)  # (after the arguments: a refused run creates no folder)
    replaces = other_run(out, resume)
    if replaces and not overwrite:
        raise ValueError(
            f"{out} already holds a run: continue it with --resume {out}, or give a new --out (--overwrite replaces it)"
        )
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.vec_env import VecNormalize

    off_policy = algo != "ppo"
    train_env = _vec_env(env_kwargs, n_envs, seed)
    eval_kwargs = {**env_kwargs, "scenario": eval_scenario}
    for name in ("speed_kph", "mu", "scenario_kwargs", "max_episode_steps"):  # the held-out scenario, run whole
        eval_kwargs.pop(name, None)
    eval_env = VecNormalize(
        _vec_env(eval_kwargs, min(eval_episodes, 4), seed + 10_000), training=False, norm_reward=False
    )
    if resume is not None:
        model_path, normalizer_path, _ = run_files(resume)
        normalized = load_normalizer(normalizer_path, train_env)
        model = load_model(algo, model_path, env=normalized)
        model.tensorboard_log = str(out / "tb")  # this run's logs in its own folder, not the resumed one's
        if model.num_timesteps >= timesteps:  # checked before anything is written
            raise ValueError(
                f"cannot resume {resume}: it already has {model.num_timesteps} timesteps and "
                f"--timesteps is the total to reach, so give more than {model.num_timesteps}, "
                f"not {timesteps}"
            )
        if off_policy:
            buffer = _replay_buffer_path(model_path)
            if buffer.exists():
                model.load_replay_buffer(str(buffer))
            else:  # an earlier checkpoint's buffer is gone: refill it (random actions) before training
                model.learning_starts = model.num_timesteps + ALGO_CONFIGS[algo]["learning_starts"]
        # carry on through the training distribution rather than replay its start (a seed of its
        # own: seed + steps could meet the evaluation cars' seed + 10,000)
        train_env.seed(int(np.random.SeedSequence([seed, model.num_timesteps]).generate_state(1)[0]))
    else:
        settings = {**ALGO_CONFIGS[algo], **(algo_overrides or {})}
        # the reward scale from returns discounted as the algorithm discounts them
        normalized = VecNormalize(
            train_env, norm_obs=True, norm_reward=not off_policy, clip_obs=10.0, gamma=settings["gamma"]
        )
        if algo == "ppo" and "batch_size" not in (algo_overrides or {}):
            settings["batch_size"] = minibatch(settings["batch_size"], settings["n_steps"] * n_envs)
        noise_std = settings.pop("action_noise_std", None)
        if noise_std is not None:
            dim = train_env.action_space.shape[0]
            settings["action_noise"] = NormalActionNoise(np.zeros(dim), noise_std * np.ones(dim))
        policy = POLICIES[algo] if env_config.privileged else "MlpPolicy"
        model = algo_class(
            policy, normalized, seed=seed, device="cpu", tensorboard_log=str(out / "tb"), verbose=0, **settings
        )
    if replaces:  # no checkpoint or evaluation of the replaced run may pass for this one's
        delete_run(out)
    out.mkdir(parents=True, exist_ok=True)
    config = RunConfig(algo, env_kwargs, seed, n_envs, model.num_timesteps, timesteps)
    atomic_write_json(out / "config.json", asdict(config))
    # the steps SB3 will take: whole rollouts for PPO, whole vector steps otherwise (so that the
    # progress bar's total is what is trained, not what was asked)
    chunk = model.n_steps * n_envs if algo == "ppo" else n_envs
    remaining = -(-(timesteps - model.num_timesteps) // chunk) * chunk
    try:
        model.learn(
            remaining,
            callback=_callbacks(out, eval_env, checkpoint_every, eval_every, eval_episodes, resume is not None),
            progress_bar=progress,
            reset_num_timesteps=resume is None,
            tb_log_name=algo,
        )
        interrupted = False
    except KeyboardInterrupt:  # Ctrl-C: keep the model as it stands (resumable; PPO drops the rollout it was
        interrupted = True  # collecting, whose steps it has counted), then stop
    shutil.rmtree(out / ".evaluating", ignore_errors=True)
    atomic_write_json(out / "config.json", asdict(replace(config, timesteps=model.num_timesteps)))
    if off_policy:  # before the model: a kill in between leaves an old model with a newer buffer
        _atomic_save_replay_buffer(model, out / REPLAY_BUFFER)
    model_path = _atomic_save_model(model, out / "model.zip")
    _atomic_save_normalizer(normalized, out / "vecnormalize.pkl")
    if interrupted:
        raise KeyboardInterrupt(
            f"interrupted after {model.num_timesteps:,} env steps; saved {model_path} "
            f"(--resume {out} continues the run)"
        )
    plot_learning_curve(out)
    return model_path


def _replay_buffer_path(model_path: Path) -> Path:
    """The replay buffer saved with a run's model.zip, or with a checkpoint step_N.zip."""
    if model_path.name == "model.zip":
        return model_path.parent / REPLAY_BUFFER
    return model_path.with_name(f"replay_buffer_{model_path.stem}.pkl")


def _check_no_abandoned_branch(resume: str | Path, out: Path) -> None:
    """ValueError if resuming into the resumed run's own folder ``out`` would leave checkpoints
    beyond the resumed step (a branch the new training abandons: a checkpoint resumed past later
    ones, or a run killed after checkpoints its model.zip predates) beside the new ones."""
    model_path, _, config_path = run_files(resume)
    if config_path.parent.resolve() != out.resolve():
        return
    step = read_run_config(config_path)["timesteps"] if model_path.name == "model.zip" else checkpoint_step(model_path)
    later = sorted(p.name for p in (out / "checkpoints").glob("step_*.zip") if checkpoint_step(p) > step)
    if later:
        raise ValueError(
            f"resuming {resume} into its own run {out} would leave the run's later checkpoints "
            f"{later} beside the new branch's: resume the latest checkpoint, or give a new --out"
        )


def load_normalizer(path: Path, venv=None):
    """The run's VecNormalize statistics from ``path`` (given ``venv``: wrapping it, to train on);
    ValueError naming the file when it cannot be unpickled (a damaged file raises nearly anything:
    UnpicklingError, EOFError, ValueError, ...) or does not fit ``venv``."""
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        if venv is not None:
            return VecNormalize.load(str(path), venv)
        with open(path, "rb") as handle:
            normalizer = pickle.load(handle)
    except OSError:
        raise
    except Exception as err:  # (any unpickling failure)
        raise ValueError(
            f"{path} is damaged: not a VecNormalize file fourwis train writes ({type(err).__name__}: {err})"
        ) from err
    if not isinstance(normalizer, VecNormalize):
        raise ValueError(f"{path} is damaged: it holds a {type(normalizer).__name__}, not the run's VecNormalize")
    return normalizer


def load_model(algo: str, path: Path, **kwargs):
    """The ``algo`` model saved at ``path`` (SB3's ``load`` on the CPU, with ``kwargs``);
    ValueError naming the file when SB3 cannot read it. Torch runs on TORCH_THREADS threads, as
    in training: a process whose torch has run a multi-threaded region cannot fork workers that
    use torch (libgomp's threads do not survive a fork; the child's first parallel op hangs), and
    ``fourwis evaluate`` loads the policy to check it before its pool forks."""
    import torch

    torch.set_num_threads(TORCH_THREADS)
    algo_class = _algo_class(algo)
    try:
        return algo_class.load(str(path), device="cpu", **kwargs)
    except OSError:
        raise
    except Exception as err:  # (a damaged zip: BadZipFile, KeyError, pickle and torch errors)
        raise ValueError(
            f"{path} is damaged: not a {algo} model fourwis train writes ({type(err).__name__}: {err})"
        ) from err


def plot_learning_curve(out: Path) -> Path | None:
    """learning_curve.png and learning_curve.csv from EvalCallback's evaluations.npz (if any)."""
    data_path = out / EVALUATIONS
    if not data_path.exists():
        return None
    data = np.load(data_path)
    steps, returns = data["timesteps"], data["results"]
    mean, std = returns.mean(axis=1), returns.std(axis=1)
    atomic_write_text(
        out / "learning_curve.csv",
        "timesteps,mean_return,std_return\n" + "".join(f"{s},{m:.6g},{d:.6g}\n" for s, m, d in zip(steps, mean, std)),
    )
    plt = pyplot()  # (the CSV first: it needs no matplotlib)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(steps, mean, marker="o")
    ax.fill_between(steps, mean - std, mean + std, alpha=0.25)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("evaluation return (held-out scenario)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = atomic_write(out / "learning_curve.png", lambda tmp: fig.savefig(tmp, format="png", dpi=120))
    plt.close(fig)
    return path


class PolicyController:
    """A trained policy as a :class:`envs.simulation.Controller`: every ``control_dt`` it builds
    the env's observation from the *estimate* (normalised with the run's VecNormalize
    statistics, or for an RLlib run its MeanStdFilter's: training.rllib), asks the policy for
    a deterministic action and holds it, turned into wheel
    torques and rear steer exactly as the env does. A policy trained on ``observation="true"``
    sees whatever estimate the loop runs (the truth only with the oracle: choose the estimator
    accordingly, as README's truth-trained comparison does on purpose); ``"sensors"`` policies
    need raw readings and are not supported here (``fourwis evaluate`` refuses them). A policy
    trained with ``privileged=True`` (training.asymmetric) acts on the agent's slots alone: the
    truth's slots are filled with their normalising mean, which its actor does not read. ``dt``
    [s]: the simulation's step, which it counts to hold each action for ``control_dt``
    (``envs.simulate`` refuses another step, as it does for the estimator and the DYC)."""

    def __init__(self, run: str | Path, params, dt: float = 0.002):
        model_path, normalizer_path, config_path = run_files(run)
        config = read_run_config(config_path)
        try:
            env = EnvConfig(**config["env_kwargs"])
        except (TypeError, ValueError) as err:
            raise ValueError(f"{config_path}: its env_kwargs {config['env_kwargs']!r} build no env: {err}") from None
        if env.observation == "sensors":
            raise ValueError("PolicyController needs a policy trained on estimated or true observations")
        self.framework = config.get("framework", "sb3")
        if self.framework == "rllib":  # an RLModule and RLlib's observation filter (training.rllib)
            from fourwis.training.rllib import RLlibPolicy

            self.model = RLlibPolicy(model_path.parent)
            self.normalise = self.model.normalise
        else:
            self.model = load_model(config["algo"], model_path)
            if env.privileged and not isinstance(self.model.policy, tuple(POLICIES.values())):
                raise ValueError(
                    f"{run} was trained on the privileged observation without an asymmetric policy: its "
                    "actor reads the truth, which a controller does not have"
                )
            normalizer = load_normalizer(normalizer_path)
            self._mean, self._var = normalizer.obs_rms.mean, normalizer.obs_rms.var
            self._clip, self._epsilon = normalizer.clip_obs, normalizer.epsilon
        substeps = int(round(env.control_dt / dt)) if dt > 0 else 0
        if substeps < 1 or abs(env.control_dt - substeps * dt) > 1e-6 * env.control_dt:
            raise ValueError(
                f"the policy acts every control_dt = {env.control_dt!r} s, which is no whole number of "
                f"dt = {dt!r} s steps"
            )
        self.params, self.dt, self.substeps = params, dt, substeps  # dt [s]: the loop's step (ClosedLoop checks it)
        self.env_config = env
        self._agent: AgentController | None = None
        self._k = 0

    def normalise(self, obs: np.ndarray) -> np.ndarray:
        """VecNormalize's observation transform with the run's frozen statistics."""
        return np.clip((obs - self._mean) / np.sqrt(self._var + self._epsilon), -self._clip, self._clip).astype(
            np.float32
        )

    def reset(self) -> None:
        self._agent, self._k = None, 0

    def __call__(self, t, estimate, front_steer, base_torques):
        if self._agent is None:
            self._agent = AgentController(self.params, self.env_config, len(front_steer))
        if self._k % self.substeps == 0:
            obs = state_observation(estimate, front_steer, self.params).astype(np.float32)
            if self.env_config.privileged:  # the actor does not read the truth's slots
                obs = np.concatenate([obs, np.broadcast_to(self._mean[N_OBS:], obs.shape)], axis=1)
            if self.framework == "rllib":
                action = self.model.predict(obs)
            else:
                action, _ = self.model.predict(self.normalise(obs), deterministic=True)
            self._agent.action[:] = np.clip(action, -1.0, 1.0)
        self._k += 1
        return self._agent(t, estimate, front_steer, base_torques)

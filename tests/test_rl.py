"""RL workflow: short training runs of every algorithm, reload, evaluation, resume, bad input."""

import json

import numpy as np
import pytest

from fourwis.envs.gym_env import YawStabilityEnv, YawStabilityVectorEnv
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.training.rl import ALGOS, PolicyController, SB3VecEnv, train

#: the sensor seed of an env reset with seed 0 (EnvConfig.draw: its sensor generator is seeded from the
#: episode's first draw), for simulate to read the same noise: the wheel-slip control acts on the
#: measured wheel speeds, so with the oracle too the trajectory depends on the sensors' noise
ENV_SENSOR_SEED = int(np.random.default_rng(0).integers(2**63))
FAST = {"ppo": {"n_steps": 128, "batch_size": 256}, "sac": {"learning_starts": 256}, "td3": {"learning_starts": 256}}


def _train(algo, out, timesteps=1024, resume=None, **env_kwargs):
    return train(
        algo,
        out,
        timesteps,
        seed=0,
        env_kwargs={"estimator": "oracle", **env_kwargs},
        n_envs=4,
        eval_every=512,
        eval_episodes=2,
        checkpoint_every=512,
        progress=False,
        algo_overrides=FAST[algo],
        resume=resume,
    )


@pytest.mark.parametrize("algo", ALGOS)
def test_train_save_reload_and_evaluate_with_identical_deterministic_actions(algo, tmp_path):
    """The reloaded policy driving the env step by step and the same policy as a controller in
    envs.simulate give the same plant trajectory (same actions, observations and physics)."""
    out = tmp_path / algo
    model_path = _train(algo, out)
    for name in ("model.zip", "vecnormalize.pkl", "config.json", "learning_curve.png", "evaluations.npz"):
        assert (out / name).exists(), name
    assert sorted(p.name for p in (out / "checkpoints").glob("*.zip")) == ["step_000000512.zip", "step_000001024.zip"]
    controller = PolicyController(out, make_scenario("paper_sine").vehicle_params)
    env = YawStabilityEnv(scenario="paper_sine", estimator="oracle")
    obs, _ = env.reset(seed=0)
    actions = []
    for _ in range(40):
        action, _ = controller.model.predict(controller.normalise(obs[None]), deterministic=True)
        actions.append(action[0])
        obs, *_ = env.step(action[0])
    traj = simulate(
        make_scenario("paper_sine", duration=40 * 0.02), controller=controller, estimator="oracle", seed=ENV_SENSOR_SEED
    )
    np.testing.assert_allclose(traj.state[-1], env.unwrapped.core.loop.state[0], rtol=1e-9, atol=1e-9)
    assert np.ptp(np.array(actions), axis=0).max() > 0  # the policy acts, not a constant
    assert model_path == out / "model.zip"
    if algo == "ppo":  # a checkpoint of step N is the policy trained on N steps (after that rollout's update)
        last = PolicyController(out / "checkpoints" / "step_000001024.zip", controller.params).model.policy
        for a, b in zip(last.parameters(), controller.model.policy.parameters()):
            np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())


@pytest.mark.parametrize("algo", ALGOS)
def test_privileged_training_gives_an_actor_that_needs_no_truth(algo, tmp_path):
    """privileged=True trains an asymmetric policy: its action ignores the truth's slots, its
    critic reads them; as a controller (fed the estimate, the truth's slots at their mean) it
    drives the plant exactly as in the privileged env, where those slots hold the truth."""
    import torch as th

    from fourwis.training.asymmetric import POLICIES

    out = tmp_path / algo
    _train(algo, out, privileged=True)
    controller = PolicyController(out, make_scenario("paper_sine").vehicle_params)
    policy = controller.model.policy
    assert type(policy) is POLICIES[algo]
    obs = th.as_tensor(np.random.default_rng(0).normal(size=(8, 28)), dtype=th.float32)
    other = obs.clone()
    other[:, 14:] = -obs[:, 14:]
    with th.no_grad():
        assert th.equal(policy._predict(obs, deterministic=True), policy._predict(other, deterministic=True))
        if algo == "ppo":
            values = policy.predict_values(obs), policy.predict_values(other)
        else:
            act = th.zeros(8, 2)
            values = policy.critic(obs, act)[0], policy.critic(other, act)[0]
    assert (values[0] - values[1]).abs().max() > 1e-3
    env = YawStabilityEnv(scenario="paper_sine", estimator="oracle", privileged=True)
    obs, _ = env.reset(seed=0)
    for _ in range(40):
        action, _ = controller.model.predict(controller.normalise(obs[None]), deterministic=True)
        obs, *_ = env.step(action[0])
    traj = simulate(
        make_scenario("paper_sine", duration=40 * 0.02), controller=controller, estimator="oracle", seed=ENV_SENSOR_SEED
    )
    np.testing.assert_allclose(traj.state[-1], env.unwrapped.core.loop.state[0], rtol=1e-9, atol=1e-9)


def test_asymmetric_policies_refuse_an_observation_without_the_truth_or_a_shared_extractor():
    from fourwis.training.asymmetric import POLICIES
    from fourwis.training.rl import _algo_class

    plain = SB3VecEnv(YawStabilityVectorEnv(num_envs=2, estimator="oracle", autoreset_mode="SameStep"))
    for algo in ALGOS:
        with pytest.raises(ValueError, match="privileged"):
            _algo_class(algo)(POLICIES[algo], plain, device="cpu")
    privileged = SB3VecEnv(
        YawStabilityVectorEnv(num_envs=2, estimator="oracle", privileged=True, autoreset_mode="SameStep")
    )
    with pytest.raises(ValueError, match="share_features_extractor"):
        _algo_class("sac")(POLICIES["sac"], privileged, device="cpu", policy_kwargs={"share_features_extractor": True})


def test_resume_continues_the_step_count_and_the_evaluations(tmp_path):
    """A resumed run counts on from its checkpoint, evaluates on the same schedule (every 512
    steps of the run, not of the resumed part) and keeps the earlier evaluations in its log."""
    from stable_baselines3 import PPO

    out = tmp_path / "run"
    _train("ppo", out, 1024)
    first = np.load(out / "evaluations.npz")
    _train("ppo", out, 2048, resume=out)
    assert PPO.load(out / "model.zip").num_timesteps == 2048
    assert (out / "checkpoints" / "step_000002048.zip").exists()
    assert json.loads((out / "config.json").read_text())["timesteps"] == 2048
    log = np.load(out / "evaluations.npz")
    np.testing.assert_array_equal(log["timesteps"], [512, 1024, 1536, 2048])
    np.testing.assert_array_equal(log["results"][:2], first["results"])
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []  # no temporary left behind
    saved = (out / "config.json").read_text()
    with pytest.raises(ValueError, match="--algo ppo, not sac"):
        train("sac", out, 4096, resume=out, progress=False)
    with pytest.raises(ValueError, match="env_kwargs"):
        train("ppo", out, 4096, resume=out, env_kwargs={"action": "wheel_torques"}, progress=False)
    assert (out / "config.json").read_text() == saved  # a refused resume leaves the run as it was


def test_an_off_policy_resume_keeps_its_replay_buffer_and_an_earlier_checkpoint_refills_it(tmp_path):
    """SAC resumed from its run directory trains on with the saved replay buffer (256 rows of 4
    cars after 1024 steps, not the resumed part's 128), and so does one resumed from the latest
    checkpoint (the only one that keeps a buffer); resumed from an earlier checkpoint it waits
    ALGO_CONFIGS' learning_starts past it before training on a refilled buffer. Resuming into
    the run's own folder past later checkpoints, or with another seed or car count, is refused."""
    from stable_baselines3 import SAC

    from fourwis.training.rl import ALGO_CONFIGS
    from fourwis.training.runs import REPLAY_BUFFER

    out = tmp_path / "run"
    _train("sac", out, 512)
    assert (out / REPLAY_BUFFER).exists()
    _train("sac", out, 1024, resume=out)
    model = SAC.load(out / "model.zip")
    model.load_replay_buffer(out / REPLAY_BUFFER)
    assert model.replay_buffer.size() == 1024 // 4
    assert sorted(p.name for p in (out / "checkpoints").glob("replay_buffer_*")) == ["replay_buffer_step_000001024.pkl"]
    with pytest.raises(ValueError, match=r"later checkpoints \['step_000001024.zip'\]"):
        _train("sac", out, 2048, resume=out / "checkpoints" / "step_000000512.zip")
    for name, value in (("seed", 1), ("n_envs", 2)):
        with pytest.raises(ValueError, match=f"trained with {name} "):
            train(
                "sac",
                tmp_path / "other",
                2048,
                resume=out,
                progress=False,
                env_kwargs={"estimator": "oracle"},
                **{name: value},
            )
    latest = tmp_path / "latest"
    _train("sac", latest, 1536, resume=out / "checkpoints" / "step_000001024.zip")
    assert SAC.load(latest / "model.zip").learning_starts == 256  # trained on the checkpoint's buffer
    branch = tmp_path / "branch"
    _train("sac", branch, 1024, resume=out / "checkpoints" / "step_000000512.zip")
    assert SAC.load(branch / "model.zip").learning_starts == 512 + ALGO_CONFIGS["sac"]["learning_starts"]


def test_a_resumed_run_reseeds_its_cars_and_evaluates_its_held_out_scenario_whole(tmp_path, monkeypatch):
    """The resumed part's cars are seeded from (seed, steps trained), not the run's seed again
    (which replayed its first episodes); the evaluation env drops a training max_episode_steps
    (it would cut the held-out sine with dwell before the FMVSS 126 checks)."""
    import fourwis.training.rl as rl

    seeds, made = [], []
    original_seed, original_vec_env = rl.SB3VecEnv.seed, rl._vec_env

    def recording_seed(self, seed=None):
        seeds.append(seed)
        return original_seed(self, seed)

    def recording_vec_env(env_kwargs, n_envs, seed):
        made.append(dict(env_kwargs))
        return original_vec_env(env_kwargs, n_envs, seed)

    monkeypatch.setattr(rl.SB3VecEnv, "seed", recording_seed)
    monkeypatch.setattr(rl, "_vec_env", recording_vec_env)
    out = tmp_path / "run"
    _train("ppo", out, 512, max_episode_steps=40)
    _train("ppo", out, 1024, resume=out, max_episode_steps=40)
    assert seeds[0] == 0 and seeds[-1] == int(np.random.SeedSequence([0, 512]).generate_state(1)[0])
    assert made[0]["max_episode_steps"] == 40 and "max_episode_steps" not in made[1]  # training, evaluation


def test_a_policy_controller_holds_its_actions_for_control_dt_at_the_loop_step_or_refuses_it(tmp_path):
    """PolicyController counts the loop's steps to hold each action for its control_dt (20 ms): run
    at another dt than it was built for, simulate refuses it naming both steps (it had acted every
    10 ms at dt = 1 ms); built for that dt it acts every 20 steps; a dt that does not divide
    control_dt is refused."""
    from fourwis.envs.sensors import SensorParams

    out = tmp_path / "run"
    _train("ppo", out, 512)
    params, scenario = make_scenario("paper_sine").vehicle_params, make_scenario("paper_sine", duration=0.09)
    fine = {"dt": 0.001, "sensor_params": SensorParams(sample_time=0.001)}
    with pytest.raises(ValueError, match=r"controller steps at dt = 0\.002 s, the simulation at 0\.001 s"):
        simulate(scenario, PolicyController(out, params), "oracle", **fine)
    controller = PolicyController(out, params, dt=0.001)
    predict, calls = controller.model.predict, []
    controller.model.predict = lambda *a, **k: calls.append(1) or predict(*a, **k)
    simulate(scenario, controller, "oracle", **fine)
    assert controller.substeps == 20 and len(calls) == 5
    with pytest.raises(ValueError, match=r"control_dt = 0\.02 s, which is no whole number of dt = 0\.003 s"):
        PolicyController(out, params, dt=0.003)


def test_a_run_with_sensor_faults_resumes_and_becomes_a_controller(tmp_path):
    """config.json holds a Fault as a dict of its fields; resume and PolicyController take it back."""
    from fourwis.envs.sensors import Fault

    faults = (Fault("yaw_rate", "spike", magnitude=0.2, rate=5.0),)
    out = tmp_path / "faults"
    _train("ppo", out, 512, sensor_faults=faults)
    assert json.loads((out / "config.json").read_text())["env_kwargs"]["sensor_faults"][0]["kind"] == "spike"
    _train("ppo", out, 1024, resume=out, sensor_faults=faults)
    controller = PolicyController(out, make_scenario("paper_sine").vehicle_params)
    assert controller.env_config.sensor_faults == faults
    from_json = YawStabilityEnv(sensor_faults=[{"channel": "yaw_rate", "kind": "stuck", "start": 1.0}])  # --env-kwargs
    assert from_json.config.sensor_faults == (Fault("yaw_rate", "stuck", start=1.0),)


def test_env_kwargs_that_config_json_cannot_give_back_are_refused_before_training(tmp_path):
    """A FrictionMap or a steering object would come back from config.json as a dict of its
    fields, which the env cannot take (it had turned the training env's own kwargs into such dicts)."""
    from fourwis.envs.driver import Constant
    from fourwis.envs.road import uniform

    for kwargs in ({"mu": uniform(0.5)}, {"scenario": "paper_step", "scenario_kwargs": {"steering": Constant(0.1)}}):
        with pytest.raises(ValueError, match="cannot be recorded in config.json"):
            train("ppo", tmp_path / "run", 512, env_kwargs=kwargs, progress=False)
    assert not (tmp_path / "run").exists()


def test_reward_normalisation_discounts_as_the_algorithm_does(tmp_path):
    import pickle

    train(
        "ppo",
        tmp_path / "run",
        512,
        env_kwargs={"estimator": "oracle"},
        n_envs=4,
        progress=False,
        algo_overrides={**FAST["ppo"], "gamma": 0.95},
    )
    with open(tmp_path / "run" / "vecnormalize.pkl", "rb") as handle:
        assert pickle.load(handle).gamma == 0.95


def test_ppo_minibatches_split_the_rollout_evenly():
    from fourwis.training.runs import minibatch

    assert minibatch(1024, 16 * 256) == 1024  # the shipped configuration
    assert minibatch(1024, 6 * 256) == 768
    assert minibatch(1024, 2 * 256) == 512
    assert minibatch(1024, 7 * 256) == 896


def test_bad_arguments_give_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="dqn"):
        train("dqn", tmp_path, 100)
    with pytest.raises(ValueError, match="-5"):
        train("ppo", tmp_path, -5)
    with pytest.raises(ValueError, match="warp"):
        train("ppo", tmp_path, 100, env_kwargs={"warp": 9})
    with pytest.raises(ValueError, match="eval_every"):
        train("ppo", tmp_path, 100, eval_every=0)
    with pytest.raises(ValueError, match="checkpoint_every"):
        train("ppo", tmp_path, 100, checkpoint_every=-1)
    with pytest.raises(FileNotFoundError, match="missing_run"):
        PolicyController(tmp_path / "missing_run", make_scenario("paper_sine").vehicle_params)
    with pytest.raises(FileNotFoundError, match="missing_run"):
        train("ppo", tmp_path / "x", 100, resume=tmp_path / "missing_run")


@pytest.mark.parametrize("missing, progress", [("rich", True), ("tensorboard", False), ("matplotlib", False)])
def test_a_missing_extra_is_named_before_the_run_writes_anything(missing, progress, tmp_path, monkeypatch):
    """Without rich (SB3's progress bar) or tensorboard, SB3 failed once training began and left a
    config.json that blocked the next try; without matplotlib the run trained to the end and
    then failed on its learning curve."""
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == missing else find_spec(name, *a))
    if missing == "matplotlib":
        monkeypatch.setitem(__import__("sys").modules, "matplotlib", None)  # import matplotlib now fails
    extra = "plots" if missing == "matplotlib" else "rl"
    with pytest.raises(ModuleNotFoundError, match=rf"fourwis\[{extra}\]"):
        train("ppo", tmp_path / "run", 100, n_envs=1, progress=progress)
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())


def test_sb3_adapter_reports_terminal_observations_and_time_limits():
    env = SB3VecEnv(
        YawStabilityVectorEnv(
            num_envs=2, scenario="paper_sine", estimator="oracle", max_episode_steps=5, autoreset_mode="SameStep"
        )
    )
    env.seed(3)
    obs = env.reset()
    for _ in range(5):
        env.step_async(np.zeros((2, 2), dtype=np.float32))
        new_obs, reward, done, infos = env.step_wait()
        assert new_obs.shape == (2, 14) and reward.dtype == np.float32
    assert done.all()
    for info in infos:
        assert info["TimeLimit.truncated"] and info["episode"]["l"] == 5
        assert info["terminal_observation"].shape == (14,)
    np.testing.assert_array_equal(new_obs, obs)  # autoreset: paper_sine starts the same every time


def test_sb3_adapter_gives_each_car_the_single_envs_per_step_info():
    """As a DummyVecEnv of single envs does: action_clipped and the other per-step keys for every
    car, a finished car's from its last step."""
    env = SB3VecEnv(
        YawStabilityVectorEnv(
            num_envs=2, scenario="paper_sine", estimator="oracle", max_episode_steps=3, autoreset_mode="SameStep"
        )
    )
    single = YawStabilityEnv(scenario="paper_sine", estimator="oracle")
    env.seed(0)
    env.reset()
    single.reset(seed=0)
    actions = np.array([[2.0, 0.0], [0.5, 0.0]], dtype=np.float32)
    for _ in range(3):
        _, _, done, infos = env.step(actions)
        *_, info = single.step(actions[0])
        assert [i["action_clipped"] for i in infos] == [True, False]
        for key in ("beta", "yaw_rate_error", "path_deviation", "spin_out", "phase_plane_index"):
            assert infos[0][key] == pytest.approx(info[key], rel=1e-12, abs=1e-15), key
    assert done.all() and "episode" in infos[0]


def test_sb3_video_recorder_records_car_0_and_the_adapter_refuses_a_later_reset(tmp_path):
    from stable_baselines3.common.vec_env import VecVideoRecorder

    native = YawStabilityVectorEnv(
        num_envs=2, scenario="paper_sine", estimator="oracle", render_mode="rgb_array", autoreset_mode="SameStep"
    )
    assert SB3VecEnv(native).get_images() == [None]  # nothing to show before a reset
    env = VecVideoRecorder(
        SB3VecEnv(native), str(tmp_path), record_video_trigger=lambda step: step == 0, video_length=20
    )
    env.reset()
    for _ in range(25):
        env.step(np.zeros((2, 2), dtype=np.float32))
    env.close()
    movies = list(tmp_path.glob("*.mp4"))
    assert len(movies) == 1 and movies[0].stat().st_size > 1000
    images = SB3VecEnv(native).get_images()
    assert len(images) == 1 and images[0].shape == native.render()[0].shape  # car 0 alone, not the cars tiled
    with pytest.raises(ValueError, match="same step.*'NextStep'"):
        SB3VecEnv(YawStabilityVectorEnv(num_envs=2))  # gymnasium's default


def test_evaluate_runs_the_policy_beside_no_control_and_dyc_lqr_from_its_run_or_its_model_zip(tmp_path):
    import csv

    from fourwis.training.compare import evaluate

    run = tmp_path / "run"
    _train("ppo", run, 512)
    runs = {}
    for given in (run, run / "model.zip"):
        out = tmp_path / f"eval_{given.name}"
        report = evaluate(given, out, ["paper_sine"], seeds=1, jobs=1)  # trained on the oracle: run on it
        text = report.read_text()
        assert f"| rl:{given} |" in text and "| none |" in text and "| dyc-lqr |" in text
        with open(out / "runs.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        assert [r["controller"] for r in rows] == ["none", "dyc-lqr", f"rl:{given}"]
        assert {r["estimator"] for r in rows} == {"oracle"} and all(r["peak_beta [rad]"] for r in rows)
        runs[given.name] = [{k: v for k, v in r.items() if k != "controller"} for r in rows]
    assert runs["run"] == runs["model.zip"]  # the same policy either way
    assert runs["run"][0] != runs["run"][2]  # (the policy acts: not the uncontrolled car again)


def test_an_interrupted_run_saves_its_model_and_resumes(tmp_path, monkeypatch):
    """Ctrl-C during training (a KeyboardInterrupt from inside SB3's loop) saves model.zip, the
    normaliser and config.json with the steps trained so far; --resume then continues."""
    from stable_baselines3.common.callbacks import BaseCallback

    import fourwis.training.rl as rl

    class CtrlC(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps >= 700:
                raise KeyboardInterrupt
            return True

    callbacks = rl._callbacks
    monkeypatch.setattr(rl, "_callbacks", lambda *args: [*callbacks(*args), CtrlC()])
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt, match=f"--resume {out}"):
        _train("ppo", out, 2048)
    trained = json.loads((out / "config.json").read_text())["timesteps"]
    assert 700 <= trained < 2048 and (out / "model.zip").exists() and (out / "vecnormalize.pkl").exists()
    monkeypatch.setattr(rl, "_callbacks", callbacks)
    _train("ppo", out, 2048, resume=out)
    assert json.loads((out / "config.json").read_text())["timesteps"] >= 2048  # (whole rollouts from 700-odd)


def test_sb3_adapter_takes_one_options_dict_and_acts_on_all_cars_only():
    env = SB3VecEnv(
        YawStabilityVectorEnv(num_envs=2, scenario="paper_sine", estimator="oracle", autoreset_mode="SameStep")
    )
    env.set_options({"reset_mask": np.array([True, True])})
    env.reset()
    env.set_options([{"reset_mask": np.array([True, False])}, {}])
    with pytest.raises(ValueError, match="one reset options dict for every car"):
        env.reset()
    with pytest.raises(ValueError, match="set_attr: the cars are one vector env"):
        env.set_attr("render_mode", None, indices=[1])
    assert env.env_method("render", indices=[0, 1]) == [None, None]  # (no render_mode)


def test_training_is_deterministic_for_a_seed(tmp_path):
    """The README: "the run is deterministic: a rerun gives the same learning curve". Two PPO
    runs with seed 0 end with bit-identical policy weights, observation/return normalisers and
    evaluations (hence learning curve); the weights changed after the step-512 checkpoint, so
    the equality covers gradient steps; seed 1 gives other weights."""
    import pickle

    from stable_baselines3 import PPO

    def run(name, seed):
        out = tmp_path / name
        train(
            "ppo",
            out,
            1024,
            seed=seed,
            env_kwargs={"estimator": "oracle"},
            n_envs=4,
            eval_every=512,
            eval_episodes=2,
            checkpoint_every=512,
            progress=False,
            algo_overrides=FAST["ppo"],
        )
        weights = {k: v.numpy() for k, v in PPO.load(out / "model.zip", device="cpu").policy.state_dict().items()}
        normaliser = pickle.loads((out / "vecnormalize.pkl").read_bytes())
        return out, weights, normaliser

    a, weights_a, norm_a = run("a", 0)
    b, weights_b, norm_b = run("b", 0)
    _, weights_c, _ = run("c", 1)
    assert weights_a.keys() == weights_b.keys()
    for key in weights_a:
        np.testing.assert_array_equal(weights_a[key], weights_b[key], err_msg=key)
    for rms in ("obs_rms", "ret_rms"):
        for field in ("mean", "var", "count"):
            np.testing.assert_array_equal(getattr(getattr(norm_a, rms), field), getattr(getattr(norm_b, rms), field))
    evaluations_a, evaluations_b = np.load(a / "evaluations.npz"), np.load(b / "evaluations.npz")
    assert evaluations_a.files == evaluations_b.files and len(evaluations_a["timesteps"]) == 2
    for key in evaluations_a.files:
        np.testing.assert_array_equal(evaluations_a[key], evaluations_b[key], err_msg=key)
    assert (a / "learning_curve.csv").read_bytes() == (b / "learning_curve.csv").read_bytes()
    assert any(not np.array_equal(weights_a[key], weights_c[key]) for key in weights_a)
    halfway = PPO.load(a / "checkpoints" / "step_000000512.zip", device="cpu").policy.state_dict()
    assert any(not np.array_equal(halfway[key].numpy(), weights_a[key]) for key in weights_a)


def test_the_shipped_policy_is_found_from_any_directory(tmp_path, monkeypatch):
    """README's rl:training/policies/ppo_joint names the package's own policy: it resolves from a
    directory that holds no such path (an installed package), and a run of that name there wins."""
    from fourwis.training.runs import SHIPPED_POLICIES, run_files

    monkeypatch.chdir(tmp_path)
    assert run_files("training/policies/ppo_joint")[0] == SHIPPED_POLICIES / "ppo_joint" / "model.zip"
    with pytest.raises(FileNotFoundError, match="no trained policy at training/policies/absent"):
        run_files("training/policies/absent")


def test_a_process_that_loaded_a_policy_forks_workers_that_load_it_too():
    """``fourwis evaluate`` loads the policy to check it, then forks its pool, whose workers load
    it again: that must not hang (libgomp's threads do not survive a fork). A fresh interpreter,
    so that no earlier test has set torch's threads."""
    import subprocess
    import sys

    code = (
        "import multiprocessing as mp\n"
        "from fourwis.envs.vehicle import VehicleParams\n"
        "from fourwis.training.rl import PolicyController\n"
        "from fourwis.training.runs import SHIPPED_POLICIES\n"
        "run = str(SHIPPED_POLICIES / 'ppo_joint')\n"
        "PolicyController(run, VehicleParams())\n"
        "child = mp.get_context('fork').Process(target=PolicyController, args=(run, VehicleParams()))\n"
        "child.start(); child.join(90)\n"
        "if child.exitcode is None: child.kill(); raise SystemExit('the forked worker hangs')\n"
        "raise SystemExit(0 if child.exitcode == 0 else f'child: {child.exitcode}')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=200)
    assert done.returncode == 0, done.stderr[-2000:]

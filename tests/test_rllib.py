"""RLlib PPO on the new API stack (training.rllib): two training iterations on the session's
local Ray instance (tests/conftest.py: ray_instance), checkpoints, the exported policy run by
``fourwis evaluate`` and as an ``rl:`` controller, bad arguments refused."""

import json

import numpy as np
import pytest

pytestmark = pytest.mark.xdist_group("ray")

TINY = {"n_steps": 32, "batch_size": 64, "n_epochs": 2}  #: 4 cars x 32 steps per iteration


@pytest.fixture(scope="module")
def rllib_run(ray_instance, tmp_path_factory):
    from fourwis.training.rllib import train

    out = tmp_path_factory.mktemp("rllib") / "run"
    policy = train(
        out,
        256,
        seed=0,
        env_kwargs={"estimator": "oracle"},
        n_envs=4,
        env_runners=1,
        eval_every=256,
        eval_episodes=1,
        checkpoint_every=128,
        progress=False,
        algo_overrides=TINY,
    )
    assert policy == out / "policy"
    return out


def test_two_iterations_write_the_run_its_checkpoints_and_progress(rllib_run):
    config = json.loads((rllib_run / "config.json").read_text())
    assert (config["framework"], config["algo"], config["timesteps"], config["n_envs"]) == ("rllib", "ppo", 256, 4)
    assert sorted(p.name for p in (rllib_run / "checkpoints").iterdir()) == ["step_000000128", "step_000000256"]
    for folder in (rllib_run, rllib_run / "checkpoints" / "step_000000128"):
        assert (folder / "policy").is_dir() and (folder / "obs_filter.pkl").stat().st_size > 0
    header, *rows = (rllib_run / "progress.csv").read_text().splitlines()
    assert header == "iteration,timesteps,episode_return_mean,eval_return_mean,env_steps_per_s"
    assert [r.split(",")[:2] for r in rows] == [["1", "128"], ["2", "256"]]
    assert rows[-1].split(",")[3] != "nan"  # the held-out evaluation ran at 256 steps


def test_the_exported_policy_acts_as_a_controller_from_the_run_and_from_a_checkpoint(rllib_run):
    from fourwis.envs.gym_env import YawStabilityEnv
    from fourwis.envs.scenarios import make_scenario
    from fourwis.envs.simulation import simulate
    from fourwis.training.rl import PolicyController

    params = make_scenario("paper_sine").vehicle_params
    controller = PolicyController(rllib_run, params)
    env = YawStabilityEnv(scenario="paper_sine", estimator="oracle")
    obs, _ = env.reset(seed=0)
    actions = []
    for _ in range(20):  # the env driven by the exported policy, step by step
        action = controller.model.predict(obs[None])[0]
        actions.append(action)
        obs, *_ = env.step(action)
    traj = simulate(make_scenario("paper_sine", duration=20 * 0.02), controller=controller, estimator="oracle")
    np.testing.assert_allclose(traj.state[-1], env.unwrapped.core.loop.state[0], rtol=1e-9, atol=1e-9)
    assert np.ptp(np.array(actions), axis=0).max() > 0  # it acts on what it sees, not a constant
    early = PolicyController(rllib_run / "checkpoints" / "step_000000128", params)
    assert not np.array_equal(early.model.predict(obs[None]), controller.model.predict(obs[None]))


def test_fourwis_evaluate_runs_the_rllib_policy_in_the_comparison(rllib_run, tmp_path):
    from fourwis.training.cli import main

    out = tmp_path / "eval"
    assert (
        main(
            ["evaluate", str(rllib_run), "--scenarios", "paper_sine:duration=1.0", "--seeds", "1"]
            + ["--backend", "ray", "--out", str(out)]
        )
        == 0
    )
    rows = (out / "runs.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert [r.split(",")[header.index("controller")] for r in rows[1:]] == ["none", "dyc-lqr", f"rl:{rllib_run}"]


def test_a_resumed_run_counts_on_from_its_steps_and_keeps_its_progress(rllib_run, tmp_path):
    """--resume of the run (its algorithm/ checkpoint) into a new folder: one more iteration,
    counted from 256 (RLlib's restored counters), progress.csv carrying the earlier rows."""
    from fourwis.training.rllib import train

    out = tmp_path / "resumed"
    train(out, 384, env_kwargs={"estimator": "oracle"}, env_runners=1, eval_every=10**6, checkpoint_every=10**6,
          progress=False, algo_overrides=TINY, resume=rllib_run)  # fmt: skip
    config = json.loads((out / "config.json").read_text())
    assert (config["timesteps"], config["seed"], config["n_envs"]) == (384, 0, 4)
    rows = (out / "progress.csv").read_text().splitlines()[1:]
    assert [r.split(",")[1] for r in rows] == ["128", "256", "384"]
    with pytest.raises(ValueError, match="already has 256 timesteps"):
        train(tmp_path / "again", 256, env_kwargs={"estimator": "oracle"}, resume=rllib_run, progress=False)
    with pytest.raises(ValueError, match=r"trained with env_kwargs \{'estimator': 'oracle'\}"):
        train(tmp_path / "other", 512, env_kwargs={"estimator": "ckf"}, resume=rllib_run, progress=False)
    with pytest.raises(ValueError, match="later checkpoints"):  # into its own folder, from an earlier checkpoint
        train(rllib_run, 512, env_kwargs={"estimator": "oracle"}, resume=rllib_run / "checkpoints" / "step_000000128",
              progress=False)  # fmt: skip


def test_fourwis_train_framework_rllib_trains_and_checkpoints_from_the_command_line(ray_instance, tmp_path, capsys):
    """The command line's own settings (rollouts of 256 steps per car): 2 cars, 2 iterations."""
    from fourwis.training.cli import main

    out = tmp_path / "cli"
    argv = ["train", "--framework", "rllib", "--timesteps", "1024", "--n-envs", "2", "--env-kwargs"]
    argv += ['{"estimator": "oracle"}', "--eval-every", "100000", "--checkpoint-every", "512", "--out", str(out)]
    assert main(argv) == 0
    config = json.loads((out / "config.json").read_text())
    assert 1024 <= config["timesteps"] < 1024 + 8 and config["env_runners"] == 1  # (RLlib may take a step more)
    assert f"wrote {out / 'policy'}, trained {config['timesteps']:,} env steps" in capsys.readouterr().out
    steps = sorted(int(p.name.removeprefix("step_")) for p in (out / "checkpoints").iterdir())
    assert len(steps) == 2 and 512 <= steps[0] < 1024 <= steps[1]


def test_train_with_rllib_refuses_what_it_does_not_do(tmp_path):
    from fourwis.training.cli import main

    with pytest.raises(SystemExit, match="--framework rllib trains --algo ppo, not sac"):
        main(["train", "--framework", "rllib", "--algo", "sac", "--out", str(tmp_path / "run")])


def test_sb3_training_refuses_the_rllib_options(tmp_path):
    from fourwis.training.cli import main

    with pytest.raises(SystemExit, match="--env-runners and --address are for --framework rllib"):
        main(["train", "--env-runners", "2", "--out", str(tmp_path / "run")])

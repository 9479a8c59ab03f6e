"""The Gymnasium environment: checkers, determinism, estimator in the loop, bad actions."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs  # noqa: F401  (registers the environment)
from envs.gym_env import YawStabilityEnv


@pytest.mark.parametrize("observation, action", [("estimated", "yaw_moment"), ("true", "wheel_torques"),
                                                 ("sensors", "yaw_moment")])
def test_gymnasium_checker_passes(observation, action):
    env = YawStabilityEnv(scenario="paper_sine", estimator="ckf", observation=observation, action=action)
    check_env(env, skip_render_check=True)


def test_stable_baselines3_checker_passes():
    from stable_baselines3.common.env_checker import check_env as sb3_check

    sb3_check(YawStabilityEnv(scenario="paper_sine", estimator="ckf"), warn=True)


def test_make_and_determinism_under_seed():
    env = gym.make("envs:FourWIS/YawStability-v0", scenario="random", estimator="ckf")
    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=7)
        out = [obs]
        for k in range(30):
            obs, *_ = env.step(np.array([0.3 * np.sin(k / 5), 0.0], dtype=np.float32))
            out.append(obs)
        runs.append(np.array(out))
    np.testing.assert_array_equal(runs[0], runs[1])
    other, _ = env.reset(seed=8)
    assert not np.array_equal(other, runs[0][0])


def test_estimated_observation_differs_from_truth_by_the_estimator_error():
    est = YawStabilityEnv(scenario="paper_sine", estimator="ckf")
    true = YawStabilityEnv(scenario="paper_sine", estimator="ckf", observation="true")
    a, _ = est.reset(seed=1)
    b, _ = true.reset(seed=1)
    diffs = []
    for _ in range(100):
        a, *_ = est.step(np.zeros(2, dtype=np.float32))
        b, *_ = true.step(np.zeros(2, dtype=np.float32))
        diffs.append(np.abs(a[:3] - b[:3]))
    diffs = np.array(diffs)
    assert diffs.max() > 0  # not the truth
    assert diffs[:, 2].mean() < 0.02  # yaw rate within 0.02 rad/s on average: not garbage


def test_bad_and_out_of_range_actions():
    env = YawStabilityEnv(scenario="paper_dlc", estimator="oracle")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0.0]))
    *_, info = env.step(np.array([3.0, 0.0]))
    assert info["action_clipped"]
    with pytest.raises(ValueError, match="warp_drive"):
        YawStabilityEnv(action="warp_drive")
    with pytest.raises(ValueError, match="nope"):
        YawStabilityEnv(scenario="nope")


def test_yaw_moment_action_turns_the_car():
    env = YawStabilityEnv(scenario="paper_dlc", estimator="oracle", observation="true")
    env.reset(seed=0)
    for _ in range(25):
        obs, *_ = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert obs[2] > 0.05  # positive (left) moment: positive yaw rate on the straight lead-in


def test_random_actions_across_scenarios_never_produce_nan():
    rng = np.random.default_rng(0)
    for scenario in ("random", "paper_step", "mu_jump", "paper_serpentine"):
        env = YawStabilityEnv(scenario=scenario, estimator="oracle", action="wheel_torques")
        obs, _ = env.reset(seed=int(rng.integers(1000)))
        for _ in range(400):
            obs, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
            assert np.all(np.isfinite(obs)) and np.isfinite(reward)
            assert np.all(np.isfinite(info["truth"].beta))
            if terminated or truncated:
                assert terminated == info["spin_out"] or info["path_deviation"] > 5.0 or truncated
                obs, _ = env.reset()

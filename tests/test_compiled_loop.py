"""The compiled closed loop (envs.compiled_loop) equals the Python loop it replaces, bit for bit."""

import gymnasium as gym
import numpy as np
import pytest

import fourwis  # noqa: F401  (registers the environment)
from fourwis.envs import compiled_loop
from fourwis.envs.gym_env import YawStabilityVectorEnv
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.sensors import Fault
from fourwis.envs.simulation import ClosedLoop, simulate
from fourwis.envs.vehicle import S_R


def _python_loop(monkeypatch) -> None:
    monkeypatch.setattr(compiled_loop, "supports", lambda loop: False)


def _episode_record(make, steps: int) -> list:
    """Everything a user sees over ``steps`` random-action steps (with resets) of the env ``make()``."""
    env = make()
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    seen = [obs]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(
            rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        )
        seen += [obs, np.array([reward, terminated, truncated], dtype=float), *info["truth"], *info["estimate"]]
        metrics = info.get("episode_metrics")
        if metrics is not None:
            seen.append(np.array([float(v) for v in metrics.values() if isinstance(v, (bool, int, float))]))
        if terminated or truncated:
            seen.append(env.reset()[0])
    return seen


def _assert_same(first: list, second: list) -> None:
    assert len(first) == len(second)
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "kwargs",
    [
        {},  # the default: joint estimator, yaw-moment actions, random roads and steering
        {"estimator": "oracle", "action": "wheel_torques", "speed_kph": 70.0},
        {"estimator": "ckf", "scenario_kwargs": {"course_share": 1.0}},  # path-following driver on lane changes
        {"scenario": "sine_with_dwell", "observation": "true"},  # the FMVSS 126 verdict from the steps' series
    ],
)
def test_single_env_steps_equal_the_python_loop(kwargs, monkeypatch):
    def make():
        return gym.make("fourwis:FourWIS/YawStability-v0", max_episode_steps=120, **kwargs)

    env = make()
    env.reset(seed=0)
    assert compiled_loop.supports(env.unwrapped._core.loop)
    compiled = _episode_record(make, 300)  # 3,000 sensor samples: every car refills its noise block
    _python_loop(monkeypatch)
    _assert_same(compiled, _episode_record(make, 300))


def test_vector_env_with_autoresets_equals_the_python_loop(monkeypatch):
    def run() -> list:
        env = YawStabilityVectorEnv(num_envs=3, max_episode_steps=70, scenario_kwargs={"course_share": 0.5})
        obs, _ = env.reset(seed=11)
        rng = np.random.default_rng(2)
        seen, ends = [obs], 0
        for _ in range(200):
            obs, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, (3, 2)).astype(np.float32))
            seen += [obs, reward, terminated, truncated, info["estimate"].mu]
            ends += int(np.count_nonzero(terminated | truncated))
        assert ends >= 6  # (the held cars of the next-step resets are exercised)
        return seen

    compiled = run()
    _python_loop(monkeypatch)
    _assert_same(compiled, run())


def test_loops_the_compiled_path_cannot_run_take_the_python_loop():
    scenario = make_scenario("paper_sine")
    assert compiled_loop.supports(ClosedLoop(scenario, None, "joint", np.random.default_rng(0)))
    faulty = ClosedLoop(scenario, None, "joint", np.random.default_rng(0), faults=(Fault("yaw_rate", "stuck", 1.0),))
    assert not compiled_loop.supports(faulty)
    batch = compiled_loop.MAX_BATCH + 1
    many = ClosedLoop([scenario] * batch, None, "oracle", [np.random.default_rng(b) for b in range(batch)])
    assert not compiled_loop.supports(many)
    for bad in ({"n": 0}, {"n": 2.5}, {"n": 1, "records": "yes"}, {"n": 1, "moving": np.ones(batch)}):
        with pytest.raises(ValueError, match=next(iter(k for k in bad if k != "n"), "n")):
            many.advance_steps(**bad)
    assert many.advance_steps(1, records=False) is None
    records = many.advance_steps(3)  # (the Python loop's records)
    assert records.state.shape[:2] == (3, batch) and np.all(records.t[:, 0] == [0.002, 0.004, 0.006])
    np.testing.assert_array_equal(many.state[:, S_R], many.sample().truth.r)


def test_a_controller_or_estimator_that_only_looks_like_the_compiled_ones_takes_the_python_loop(monkeypatch):
    from dataclasses import replace

    from fourwis.control import StabilityController
    from fourwis.envs.gym_env import AgentController

    class Gentler(StabilityController):  # a user's change to the DYC: the Python loop runs it
        pass

    dyc = ClosedLoop(
        make_scenario("paper_sine"),
        Gentler(make_scenario("paper_sine").vehicle_params),
        "joint",
        np.random.default_rng(0),
    )
    assert not compiled_loop.supports(dyc)

    class Braking(AgentController):  # (inherits kernel_form, but commands something else)
        def __call__(self, t, estimate, front_steer, base_torques):
            command = super().__call__(t, estimate, front_steer, base_torques)
            return command._replace(torques=command.torques - 300.0)

    env = gym.make("fourwis:FourWIS/YawStability-v0")
    env.reset(seed=0)
    loop = env.unwrapped._core.loop
    loop.controller = Braking(loop.params, env.unwrapped.config, 1)
    assert not compiled_loop.supports(loop)

    def run() -> list:  # a StateEstimator that asks for the truth still reports its own estimate
        scenario = make_scenario("paper_sine")
        loop = ClosedLoop(scenario, None, "joint", np.random.default_rng(0))
        loop.estimator = replace(loop.estimator, needs_truth=True)
        loop._needs_truth = True
        loop.estimator.reset(loop.sample().reading, np.array([scenario.speed]))
        return [*loop.advance_steps(20).estimate, *loop.sample().estimate]

    compiled = run()
    _python_loop(monkeypatch)
    _assert_same(compiled, run())


@pytest.mark.parametrize(
    "break_it, error, match",
    [
        (lambda loop: loop.estimator.P.fill(np.nan), ValueError, "the joint filter of vehicle 0 failed"),
        (lambda loop: loop.state.__setitem__((0, S_R), np.nan), ValueError, r"state\[0\] has a non-finite value"),
    ],
)
def test_failures_raise_the_python_loops_errors(break_it, error, match, monkeypatch):
    def failure() -> tuple[str, bool]:
        loop = ClosedLoop(make_scenario("paper_sine"), None, "joint", np.random.default_rng(0))
        loop.advance_steps(5)
        break_it(loop)
        with pytest.raises(error, match=match) as caught:
            loop.advance_steps(5)
        return str(caught.value), bool(loop._stale.all())

    compiled, resense = failure()
    assert resense  # (the compiled loop's next sample senses the vehicles where they stopped)
    _python_loop(monkeypatch)
    assert failure()[0] == compiled


@pytest.mark.parametrize(
    "scenario, controller, estimator",
    [
        ("paper_sine", None, "joint"),
        ("iso3888_2", None, "oracle"),
        ("mu_jump", "dyc-lqr", "joint"),
        ("iso3888_2", "dyc-smc-4ws", "oracle"),
        ("paper_step", "dyc-lqr-4ws", "ckf"),
    ],
)
def test_simulate_equals_the_python_loop(scenario, controller, estimator, monkeypatch):
    compiled = simulate(scenario, controller, estimator, seed=2)
    _python_loop(monkeypatch)
    python = simulate(scenario, controller, estimator, seed=2)
    for name in ("t", "state", "aux", "controls", "steering_wheel", "sensors", "sensor_valid"):
        np.testing.assert_array_equal(getattr(compiled, name), getattr(python, name))
    for group in ("truth", "estimate"):
        for a, b in zip(getattr(compiled, group), getattr(python, group)):
            np.testing.assert_array_equal(a, b)
    if controller is not None:  # (the DYC acted: it is not a run without control)
        assert np.any(compiled.controls[:, :4] != compiled.controls[:, :1])


def test_the_dyc_hands_over_between_the_loops_mid_run(monkeypatch):
    """The controller's memory (lagged reference, rear angle, delivered moment, allocation) is
    one array that both loops update: compiled, Python, compiled again equals Python throughout,
    on two cars of which one, turning, is held for a while: its memory stands still in both."""
    from fourwis.control import StabilityController
    from fourwis.control.dyc import M_REFERENCE

    def run(switch: bool) -> list:
        scenarios = [make_scenario("paper_step", mu=0.4), make_scenario("mu_jump")]
        loop = ClosedLoop(scenarios, "dyc-smc-4ws", "joint", [np.random.default_rng(b) for b in range(2)])
        assert isinstance(loop.controller, StabilityController) and compiled_loop.supports(loop)
        if not switch:
            monkeypatch.setattr(compiled_loop, "supports", lambda loop: False)
        seen = [*loop.advance_steps(900)]  # then car 1 held in its turn (the compiled records leave its rows NaN):
        memory = loop.controller.kernel_arrays(2)[-1]
        assert abs(memory[1, M_REFERENCE]) > 0.05  # (turning: a held step of the law would move it)
        held_row = memory[1].copy()
        seen += [leaf[:, 0] for leaf in _leaves(loop.advance_steps(150, moving=np.array([True, False])))]
        np.testing.assert_array_equal(memory[1], held_row)
        monkeypatch.setattr(compiled_loop, "supports", lambda loop: False)
        seen += [loop.advance() for _ in range(30)]
        monkeypatch.undo()
        if not switch:
            monkeypatch.setattr(compiled_loop, "supports", lambda loop: False)
        seen += [*loop.advance_steps(300), loop.controller.last_allocation]
        monkeypatch.undo()
        return [np.asarray(leaf) for leaf in _leaves(seen)]

    _assert_same(run(True), run(False))


def test_the_dyc_allocates_with_its_own_vehicle_parameters(monkeypatch):
    """A controller designed for other motors than the plant's (150 N m, a heavier car) commands the
    same torques in both loops: its own limits, never more than 150 N m."""
    from dataclasses import replace

    from fourwis.control import StabilityController

    scenario = make_scenario("paper_step", mu=0.4)
    params = scenario.vehicle_params
    designed = replace(params, motor_peak_torque=150.0, mass=1.1 * params.mass)

    def run() -> np.ndarray:
        return simulate(scenario, StabilityController(designed), "oracle", seed=0).controls

    compiled = run()
    assert np.max(np.abs(compiled[:, :4])) <= 150.0 + 1e-9
    _python_loop(monkeypatch)
    np.testing.assert_array_equal(compiled, run())


def test_a_reset_member_restarts_the_dyc_memory_of_that_car_only():
    from fourwis.control.dyc import M_DELIVERED, M_REFERENCE

    scenarios = [make_scenario("paper_sine"), make_scenario("paper_step")]
    loop = ClosedLoop(scenarios, "dyc-lqr", "joint", [np.random.default_rng(b) for b in range(2)])
    loop.advance_steps(800)
    memory = loop.controller.kernel_arrays(2)[-1]
    kept = memory[0].copy()
    loop.reset_members(np.array([False, True]), [make_scenario("paper_step")], [np.random.default_rng(5)])
    np.testing.assert_array_equal(memory[0], kept)
    assert np.isnan(memory[1, M_REFERENCE]) and memory[1, M_DELIVERED] == 0.0


def _leaves(tree) -> list:
    """The arrays of nested tuples / lists of records."""
    if isinstance(tree, (tuple, list)):
        return [leaf for item in tree for leaf in _leaves(item)]
    return [tree]


def test_a_dyc_failure_raises_the_python_loops_error(monkeypatch):
    from fourwis.control.dyc import M_DELIVERED

    def failure() -> str:
        loop = ClosedLoop(make_scenario("paper_step"), "dyc-lqr", "oracle", np.random.default_rng(0))
        loop.advance_steps(5)
        loop.controller.kernel_arrays(1)[-1][:, M_DELIVERED] = np.nan  # a corrupted memory: the LQR's moment is NaN
        with pytest.raises(ValueError, match=r"yaw moment must be finite, got \[nan\]") as caught:
            loop.advance_steps(5)
        return str(caught.value)

    compiled = failure()
    _python_loop(monkeypatch)
    assert failure() == compiled

"""The one closed loop (fourwis.envs.loop): each stage's compiled component equals the same
component served in Python, bit for bit, and a loop's components take the stage they can."""

import gymnasium as gym
import numpy as np
import pytest

import fourwis  # noqa: F401  (registers the environment)
from fourwis.envs import simulation
from fourwis.envs.gym_env import YawStabilityVectorEnv
from fourwis.envs.layout import S_R
from fourwis.envs.loop import STAGES, NoControl, Parts, PlantStage, PythonStage, Stage
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.sensors import Fault
from fourwis.envs.simulation import ClosedLoop, kernel_parts, simulate

#: the smallest batch whose plant the tests step in lanes (PER_CAR_PLANT_MAX lowered to one less:
#: the lanes' path is then tested on a few cars rather than on hundreds)
LANES_FROM = 5


def _python_stages(monkeypatch) -> None:
    """Every stage served in Python: each component's own Python call (the plant's step, the
    sensors' measure, the estimator's step, the controller's call, the drivers' call)."""

    def python(loop):
        return Parts(*(loop.python_stages[stage] for stage in (Stage.CONTROL, Stage.PLANT, Stage.SENSE,
                                                                Stage.ESTIMATE, Stage.STEER, Stage.SPEED)),
                     loop.actuators)  # fmt: skip

    monkeypatch.setattr(simulation, "kernel_parts", python)


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


def test_the_stages_run_in_one_declared_order():
    assert STAGES == (Stage.CONTROL, Stage.PLANT, Stage.SENSE, Stage.ESTIMATE, Stage.STEER, Stage.SPEED)
    assert set(simulation._SERVERS) == set(STAGES)  # (each stage has its Python server, and only that)


@pytest.mark.parametrize(
    "kwargs",
    [
        {},  # the default: joint estimator, yaw-moment actions, random roads and steering
        {"estimator": "oracle", "action": "wheel_torques", "speed_kph": 70.0},
        {"estimator": "ckf", "scenario_kwargs": {"course_share": 1.0}},  # path-following driver on lane changes
        {"scenario": "sine_with_dwell", "observation": "true"},  # the FMVSS 126 verdict from the steps' series
    ],
)
def test_single_env_steps_equal_the_python_stages(kwargs, monkeypatch):
    def make():
        return gym.make("fourwis:FourWIS/YawStability-v0", max_episode_steps=120, **kwargs)

    env = make()
    env.reset(seed=0)
    assert not any(isinstance(part, PythonStage) for part in kernel_parts(env.unwrapped._core.loop))
    compiled = _episode_record(make, 300)  # 3,000 sensor samples: every car refills its noise block
    _python_stages(monkeypatch)
    _assert_same(compiled, _episode_record(make, 300))


@pytest.mark.parametrize("num_envs", [3, LANES_FROM + 3])
def test_vector_env_with_autoresets_equals_the_python_stages(num_envs, monkeypatch):
    monkeypatch.setattr("fourwis.envs.simulation.PER_CAR_PLANT_MAX", LANES_FROM - 1)

    def run() -> list:
        env = YawStabilityVectorEnv(num_envs=num_envs, max_episode_steps=70, scenario_kwargs={"course_share": 0.5})
        obs, _ = env.reset(seed=11)
        rng = np.random.default_rng(2)
        seen, ends = [obs], 0
        for _ in range(160):
            obs, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, (num_envs, 2)).astype(np.float32))
            seen += [obs, reward, terminated, truncated, info["estimate"].mu]
            ends += int(np.count_nonzero(terminated | truncated))
        assert ends >= 2 * num_envs  # (the held cars of the next-step resets are exercised)
        return seen

    compiled = run()
    _python_stages(monkeypatch)
    _assert_same(compiled, run())


def test_each_component_takes_the_compiled_stage_it_can(monkeypatch):
    monkeypatch.setattr("fourwis.envs.simulation.PER_CAR_PLANT_MAX", LANES_FROM - 1)
    scenario = make_scenario("paper_sine")
    plain = ClosedLoop(scenario, None, "joint", np.random.default_rng(0))
    assert isinstance(kernel_parts(plain).estimator, PythonStage)  # (before its first reset: no vehicle reads it)
    plain.sample()
    parts = kernel_parts(plain)
    assert isinstance(parts.controller, NoControl) and isinstance(parts.plant, PlantStage)
    assert not any(isinstance(part, PythonStage) for part in parts)
    faulty = ClosedLoop(scenario, None, "joint", np.random.default_rng(0), faults=(Fault("yaw_rate", "stuck", 1.0),))
    faulty.sample()
    python = [isinstance(part, PythonStage) for part in kernel_parts(faulty)]
    assert python == [False, False, True, False, False, False, False]  # (the sensors; the actuators are compiled)
    bumpy = make_scenario("paper_sine", mu=lambda x, y: np.full_like(x, 0.7))  # a callable friction map
    assert isinstance(kernel_parts(ClosedLoop(bumpy, None, "oracle", np.random.default_rng(0))).plant, PythonStage)
    batch = LANES_FROM  # (the plant of a large batch steps all cars at once, in lanes)
    many = ClosedLoop([scenario] * batch, None, "oracle", [np.random.default_rng(b) for b in range(batch)])
    assert isinstance(kernel_parts(many).plant, PythonStage)
    for bad in ({"n": 0}, {"n": 2.5}, {"n": 1, "records": "yes"}, {"n": 1, "moving": np.ones(batch)}):
        with pytest.raises(ValueError, match=next(iter(k for k in bad if k != "n"), "n")):
            many.advance_steps(**bad)
    assert many.advance_steps(1, records=False) is None
    records = many.advance_steps(3)
    assert records.state.shape[:2] == (3, batch) and np.all(records.t[:, 0] == [0.002, 0.004, 0.006])
    np.testing.assert_array_equal(many.state[:, S_R], many.sample().truth.r)


def test_a_controller_that_only_looks_like_a_compiled_one_is_served_in_python(monkeypatch):
    from fourwis.control import StabilityController
    from fourwis.envs.gym_env import AgentController

    class Gentler(StabilityController):  # a user's change to the DYC: served in Python
        pass

    params = make_scenario("paper_sine").vehicle_params
    dyc = ClosedLoop(make_scenario("paper_sine"), Gentler(params), "joint", np.random.default_rng(0))
    assert isinstance(kernel_parts(dyc).controller, PythonStage)

    class Braking(AgentController):  # (inherits kernel(), but commands something else)
        def __call__(self, t, estimate, front_steer, base_torques):
            command = super().__call__(t, estimate, front_steer, base_torques)
            return command._replace(torques=command.torques - 300.0)

    env = gym.make("fourwis:FourWIS/YawStability-v0")
    env.reset(seed=0)
    loop = env.unwrapped._core.loop
    loop.controller = Braking(loop.params, env.unwrapped.config, 1)
    assert isinstance(kernel_parts(loop).controller, PythonStage)


def test_a_state_estimator_that_asks_for_the_truth_reports_its_own_estimate(monkeypatch):
    from dataclasses import replace

    def run() -> list:
        scenario = make_scenario("paper_sine")
        loop = ClosedLoop(scenario, None, "joint", np.random.default_rng(0))
        loop.estimator = replace(loop.estimator, needs_truth=True)
        loop._needs_truth = True
        return [*loop.advance_steps(20).estimate, *loop.sample().estimate]

    compiled = run()
    _python_stages(monkeypatch)
    _assert_same(compiled, run())


@pytest.mark.parametrize(
    "break_it, error, match",
    [
        (lambda loop: loop.estimator.state.P.fill(np.nan), ValueError, "the joint filter of vehicle 0 failed"),
        (lambda loop: loop.state.__setitem__((0, S_R), np.nan), ValueError, r"state\[0\] has a non-finite value"),
    ],
)
def test_failures_raise_the_same_error_compiled_or_in_python(break_it, error, match, monkeypatch):
    def failure() -> str:
        loop = ClosedLoop(make_scenario("paper_sine"), None, "joint", np.random.default_rng(0))
        loop.advance_steps(5)
        break_it(loop)
        with pytest.raises(error, match=match) as caught:
            loop.advance_steps(5)
        return str(caught.value)

    compiled = failure()
    _python_stages(monkeypatch)
    assert failure() == compiled


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
def test_simulate_equals_the_python_stages(scenario, controller, estimator, monkeypatch):
    compiled = simulate(scenario, controller, estimator, seed=2)
    _python_stages(monkeypatch)
    python = simulate(scenario, controller, estimator, seed=2)
    for name in ("t", "state", "aux", "controls", "steering_wheel", "sensors", "sensor_valid"):
        np.testing.assert_array_equal(getattr(compiled, name), getattr(python, name))
    for group in ("truth", "estimate"):
        for a, b in zip(getattr(compiled, group), getattr(python, group)):
            np.testing.assert_array_equal(a, b)
    if controller is not None:  # (the DYC acted: it is not a run without control)
        assert np.any(compiled.controls[:, :4] != compiled.controls[:, :1])


def test_the_dyc_hands_over_between_compiled_and_python_mid_run(monkeypatch):
    """The controller's memory (lagged reference, rear angle, delivered moment, allocation) is one
    bundle that both the compiled stage and the controller's Python call update: compiled, then
    Python, then compiled again equals Python throughout."""

    def run(switch: bool) -> list:
        scenarios = [make_scenario("paper_step", mu=0.4), make_scenario("mu_jump")]
        loop = ClosedLoop(scenarios, "dyc-smc-4ws", "joint", [np.random.default_rng(b) for b in range(2)])
        if not switch:
            _python_stages(monkeypatch)
        seen = [*loop.advance_steps(900)]
        _python_stages(monkeypatch)
        seen += [loop.advance() for _ in range(30)]
        monkeypatch.undo()
        if not switch:
            _python_stages(monkeypatch)
        seen += [*loop.advance_steps(300), loop.controller.last_allocation]
        monkeypatch.undo()
        return [np.asarray(leaf) for leaf in _leaves(seen)]

    _assert_same(run(True), run(False))


def test_a_held_car_s_dyc_memory_stands_still():
    scenarios = [make_scenario("paper_step", mu=0.4), make_scenario("mu_jump")]
    loop = ClosedLoop(scenarios, "dyc-smc-4ws", "joint", [np.random.default_rng(b) for b in range(2)])
    loop.advance_steps(900)
    memory = loop.controller.kernel(2).memory
    assert abs(memory.reference[1]) > 0.05  # (turning: a held step of the law would move it)
    held = [np.array(field[1]) for field in (memory.reference, memory.rear, memory.previous_reference)]
    records = loop.advance_steps(150, moving=np.array([True, False]))
    assert np.isnan(records.state[:, 1]).all() and not np.isnan(records.state[:, 0]).any()
    for before, field in zip(held, (memory.reference, memory.rear, memory.previous_reference)):
        np.testing.assert_array_equal(field[1], before)


def test_the_dyc_allocates_with_its_own_vehicle_parameters(monkeypatch):
    """A controller designed for other motors than the plant's (150 N m, a heavier car) commands the
    same torques compiled and in Python: its own limits, never more than 150 N m."""
    from dataclasses import replace

    from fourwis.control import StabilityController

    scenario = make_scenario("paper_step", mu=0.4)
    params = scenario.vehicle_params
    designed = replace(params, motor_peak_torque=150.0, mass=1.1 * params.mass)

    def run() -> np.ndarray:
        return simulate(scenario, StabilityController(designed), "oracle", seed=0).controls

    compiled = run()
    assert np.max(np.abs(compiled[:, :4])) <= 150.0 + 1e-9
    _python_stages(monkeypatch)
    np.testing.assert_array_equal(compiled, run())


def test_a_reset_member_restarts_the_dyc_memory_of_that_car_only():
    scenarios = [make_scenario("paper_sine"), make_scenario("paper_step")]
    loop = ClosedLoop(scenarios, "dyc-lqr", "joint", [np.random.default_rng(b) for b in range(2)])
    loop.advance_steps(800)
    memory = loop.controller.kernel(2).memory
    kept = [np.array(field[0]) for field in (memory.reference, memory.delivered, memory.allocation.torques)]
    loop.reset_members(np.array([False, True]), [make_scenario("paper_step")], [np.random.default_rng(5)])
    for before, field in zip(kept, (memory.reference, memory.delivered, memory.allocation.torques)):
        np.testing.assert_array_equal(field[0], before)
    assert np.isnan(memory.reference[1]) and memory.delivered[1] == 0.0


def _leaves(tree) -> list:
    """The arrays of nested tuples / lists of records."""
    if isinstance(tree, (tuple, list)):
        return [leaf for item in tree for leaf in _leaves(item)]
    return [tree]


def test_a_dyc_failure_raises_the_same_error_compiled_or_in_python(monkeypatch):
    def failure() -> str:
        loop = ClosedLoop(make_scenario("paper_step"), "dyc-lqr", "oracle", np.random.default_rng(0))
        loop.advance_steps(5)
        loop.controller.kernel(1).memory.delivered[:] = np.nan  # a corrupted memory: the LQR's moment is NaN
        with pytest.raises(ValueError, match=r"yaw moment must be finite, got \[nan\]") as caught:
            loop.advance_steps(5)
        return str(caught.value)

    compiled = failure()
    _python_stages(monkeypatch)
    assert failure() == compiled

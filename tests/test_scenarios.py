"""Scenario registry, drivers and the simulation loop."""

import math

import numpy as np
import pytest

from fourwis.core.constants import GRAVITY
from fourwis.envs.driver import (
    SWD_DWELL,
    SWD_FREQUENCY,
    Constant,
    DriverBatch,
    Ramp,
    Sine,
    SineWithDwell,
    SpeedHold,
    Step,
)
from fourwis.envs.layout import S_DELTA_R, S_U
from fourwis.envs.road import patch
from fourwis.envs.scenarios import PAPER_SCENARIOS, SCENARIOS, make_scenario
from fourwis.envs.simulation import simulate
from fourwis.envs.vehicle import VehicleParams

STATE = np.zeros(26)


@pytest.mark.parametrize(
    "name, speed_kph, mu",
    [("paper_dlc", 35.0, 0.5), ("paper_step", 40.0, 0.3), ("paper_sine", 40.0, 0.8), ("paper_serpentine", 40.0, 0.5)],
)
def test_paper_scenarios_have_the_papers_speed_and_friction(name, speed_kph, mu):
    scenario = SCENARIOS[name]
    assert scenario.speed_kph == speed_kph
    x = np.linspace(-50, 300, 50)
    np.testing.assert_array_equal(scenario.road.mu_at(x, np.linspace(-5, 5, 50)), mu)


def test_paper_split_dlc_is_split_left_05_right_03():
    scenario = SCENARIOS["paper_split_dlc"]
    assert scenario.speed_kph == 25.0
    assert scenario.road.mu_at(np.array([10.0]), np.array([1.0]))[0] == 0.5
    assert scenario.road.mu_at(np.array([10.0]), np.array([-1.0]))[0] == 0.3


def test_paper_step_is_one_radian_at_five_seconds():
    steer = SCENARIOS["paper_step"].steering
    assert steer(4.99, STATE) == 0.0
    assert steer(5.2, STATE) == 1.0


def test_a_given_manoeuvre_start_before_the_end_steers_and_the_default_start_keeps_short_runs():
    """A step_time or start just before the end gives a run with its manoeuvre; left at its
    default (5 s, 1 s), a shorter run (a quick check) is still built, straight."""
    assert make_scenario("paper_step", step_time=9.9).steering(9.95, STATE) == pytest.approx(0.5)
    assert make_scenario("sine_with_dwell", start=4.5).coast_after == 4.5
    assert make_scenario("paper_step", duration=0.2).steering(0.2, STATE) == 0.0
    assert make_scenario("sine_with_dwell", duration=0.5).coast_after == 1.0


def test_paper_sine_is_a_sine():
    steer = SCENARIOS["paper_sine"].steering
    t = np.linspace(1.0, 9.0, 801)
    values = np.array([steer(x, STATE) for x in t])
    np.testing.assert_allclose(values, math.radians(90.0) * np.sin(2 * np.pi * 0.5 * (t - 1.0)), atol=1e-12)


def test_sine_with_dwell_profile_matches_the_regulation():
    steer = SineWithDwell(math.radians(100.0), start=1.0)
    assert steer(1.0 + 0.25 / SWD_FREQUENCY, STATE) == pytest.approx(math.radians(100.0))
    for t in (1.0 + 1.0714, 1.0 + 1.3, 1.0 + 1.5714):
        assert steer(t, STATE) == pytest.approx(-math.radians(100.0), abs=1e-3)
    assert steer(1.0 + 1.9286 + 0.01, STATE) == 0.0
    assert steer.end == pytest.approx(1.0 + 1.0 / SWD_FREQUENCY + SWD_DWELL)
    # continuous everywhere
    t = np.arange(0.0, 4.0, 1e-4)
    values = np.array([steer(x, STATE) for x in t])
    assert np.abs(np.diff(values)).max() < math.radians(100.0) * 2 * np.pi * SWD_FREQUENCY * 1e-4 * 1.01


def test_a_driver_batch_gives_each_vehicle_its_own_drivers_output():
    """Mixed classes (vectorised ones grouped, a path follower and a plain function looped),
    each vehicle at its own time and state, before and after members are replaced, for all
    vehicles and for a subset."""
    rng = np.random.default_rng(3)
    drivers = [
        Step(0.5, 1.0),
        SineWithDwell(-1.2, 0.5),
        Sine(0.3, 0.7, start=0.2),
        Step(-0.2, 0.3, rise_time=0.5),
        make_scenario("random", seed=4).steering,
        make_scenario("paper_dlc").steering,
        lambda t, state: 0.1 * t + state[S_U],
        Ramp(0.2, limit=0.3),
        Constant(0.4, start=2.0),
    ]
    batch = DriverBatch(drivers)
    t, states = rng.uniform(0.0, 4.0, len(drivers)), rng.normal(0.0, 3.0, (len(drivers), 26))
    states[:, S_U] += 15.0
    np.testing.assert_array_equal(batch(t, states), [d(t[b], states[b]) for b, d in enumerate(drivers)])
    drivers[2], drivers[5] = Step(1.0, 0.0), Sine(0.1, 2.0)
    batch.replace([2, 5], [drivers[2], drivers[5]])
    np.testing.assert_array_equal(batch(t, states), [d(t[b], states[b]) for b, d in enumerate(drivers)])
    rows = np.array([5, 0, 6])
    np.testing.assert_array_equal(batch(t, states, rows), [drivers[b](t[b], states[b]) for b in rows])


def test_speed_hold_feeds_forward_the_resistance_and_coasts():
    p = VehicleParams()
    hold = DriverBatch([SpeedHold(20.0, p), SpeedHold(20.0, p, coast_after=1.0)])
    states = np.zeros((2, 26))
    states[:, S_U] = 20.0
    resistance = p.rolling_resistance * p.mass * GRAVITY + 0.5 * p.air_density * p.drag_area * 20.0**2
    np.testing.assert_allclose(hold(np.array([2.0, 0.5]), states), resistance * p.wheel_radius / 4.0, rtol=1e-12)
    assert hold(np.array([2.0, 2.0]), states)[1] == 0.0
    states[:, S_U] = 0.0  # far below the target: the motors' limit
    assert hold(np.array([0.0, 0.0]), states)[0] == p.motor_peak_torque


@pytest.mark.parametrize(
    "name, kwargs, bad",
    [
        ("no_such_scenario", {}, "no_such_scenario"),
        ("paper_dlc", {"speed_kph": -10.0}, "-10.0"),
        ("paper_dlc", {"mu": 0.0}, "0.0"),
        ("paper_step", {"mu": 2.5}, "2.5"),
        ("paper_sine", {"duration": float("nan")}, "nan"),
        ("paper_sine", {"colour": "red"}, "colour"),
        ("sine_with_dwell", {"direction": 2}, "direction must be .*, got 2"),
        ("sine_with_dwell", {"start": -1.0}, "start"),
        ("paper_step", {"angle": float("nan")}, "angle"),
        ("slowly_increasing_steer", {"direction": 0}, "direction"),
        ("mu_jump", {"mu_patch": 0.0}, "mu_patch"),
        ("random", {"speed_range_kph": (50.0, 40.0)}, "speed_range_kph"),
        ("random", {"lateral_demand": 0.3}, "lateral_demand"),
        ("random", {"lateral_demand": (0.0, 1.0)}, "lateral_demand"),
        ("random", {"course_share": 1.5}, "course_share"),
        ("random", {"speed_range_kph": (30.0, 400.0)}, "speed_range_kph"),  # the draw would exceed 300 km/h
        ("paper_serpentine", {"n_cones": 2.5}, "n_cones"),
        ("paper_serpentine", {"n_cones": "8"}, "n_cones"),
        ("mu_jump", {"speed_kph": 2.0}, "short of the patch"),  # 1.4 m in 6 s
        ("mu_jump", {"speed_kph": 30.0}, "short of the patch"),  # circles 17.7 m across at 0.4 g
        ("mu_jump", {"duration": 1.2}, "short of the patch"),
        ("mu_jump", {"patch_x": 0.5}, "start on the patch"),  # under the front wheels at the start
        # a manoeuvre that starts at or after the end (it had given a run without steering)
        ("paper_step", {"step_time": 20}, r"step_time = 20\.0 s .*duration = 10\.0 s"),
        ("paper_step", {"step_time": 3.0, "duration": 3.0}, r"step_time = 3\.0 s .*duration = 3\.0 s"),
        ("sine_with_dwell", {"start": 6}, r"start = 6\.0 s .*duration = 5\.0 s"),
        ("random", {"seed": -1}, r"seed must be an integer >= 0 \(or a numpy SeedSequence or Generator\), got -1"),
        ("random", {"seed": 1.5}, r"seed must be an integer >= 0 .*, got 1.5"),
    ],
)
def test_bad_scenario_arguments_raise_value_error_naming_the_value(name, kwargs, bad):
    with pytest.raises(ValueError, match=bad):
        make_scenario(name, **kwargs)


def test_the_parameters_rear_steer_switch_reaches_the_scenario():
    on = make_scenario("paper_sine", duration=3.0, params=VehicleParams(rear_steer_feedforward=True))
    assert on.vehicle_params.rear_steer_feedforward
    assert np.abs(simulate(on).state[:, S_DELTA_R]).max() > 1e-3  # the 4WS law steers the rear axle
    from dataclasses import replace

    assert not replace(on, params=VehicleParams()).vehicle_params.rear_steer_feedforward  # the switch is the params'


def test_bad_simulation_arguments_are_named():
    from fourwis.control import StabilityController
    from fourwis.envs.sensors import Fault, SensorParams

    scenario = make_scenario("paper_step", duration=0.1)
    params = scenario.vehicle_params
    for kwargs, named in (
        ({"dt": 0.05}, r"dt must be a step in \(0, 0.01\] s .*, got 0.05"),
        ({"dt": "0.002"}, "dt must be .*, got '0.002'"),
        ({"dt": 0.001}, "the sensors sample every 0.002 s, the simulation steps at dt = 0.001 s"),
        ({"controller": StabilityController(params, dt=0.004)}, "the controller steps at dt = 0.004"),
        ({"seed": -1}, "seed must be an integer >= 0, got -1"),
        ({"seed": None}, "got None"),
        ({"faults": None}, "faults must be a sequence of envs.sensors.Fault"),
        ({"faults": Fault("yaw_rate", "stuck")}, "faults must be a sequence"),
        ({"sensor_params": "x"}, "sensor_params must be an envs.sensors.SensorParams"),
        ({"scenario": None}, "scenarios must be a Scenario"),
    ):
        with pytest.raises(ValueError, match=named):
            simulate(**({"scenario": scenario} | kwargs))
    with pytest.raises(ValueError, match=r"friction map returned shape \(7,\) for positions of shape \(4,\)"):
        simulate(make_scenario("paper_step", duration=0.1, mu=lambda x, y: np.full(7, 0.5)))
    finer = simulate(scenario, dt=0.001, sensor_params=SensorParams(sample_time=0.001))  # the two agree: fine
    assert len(finer.t) == 101
    from fourwis.envs.simulation import ClosedLoop

    loop = ClosedLoop((s for s in [scenario, scenario]), None, "oracle", [np.random.default_rng(k) for k in (0, 1)])
    for bad in ([1, 0], np.array([True]), np.array([1, 0])):
        with pytest.raises(ValueError, match=r"moving must be a bool array of shape \(2,\)"):
            loop.advance(moving=bad)
    loop.advance(moving=[True, False])  # a list of bools is a mask
    np.testing.assert_array_equal(loop.k, [1, 0])


def test_mu_jump_lays_its_patch_over_the_given_road_and_numpy_frictions_are_numbers():
    from fourwis.envs.road import split

    road = make_scenario("mu_jump", mu=split(0.9, 0.5), mu_patch=0.3).road
    np.testing.assert_array_equal(road.mu_at(np.array([0.0, 0.0, 100.0]), np.array([1.0, -1.0, 1.0])), [0.9, 0.5, 0.3])
    assert make_scenario("paper_step", mu=np.int64(1)).road.mu_at(np.zeros(1), np.zeros(1))[0] == 1.0


def test_overrides_apply():
    scenario = make_scenario("paper_dlc", speed_kph=50.0, mu=0.9)
    assert scenario.speed_kph == 50.0
    assert scenario.road.mu_at(np.array([0.0]), np.array([0.0]))[0] == 0.9


@pytest.mark.parametrize("name", PAPER_SCENARIOS)
def test_paper_scenarios_hold_their_speed(name):
    """The speed-holding driver keeps each paper scenario within 3% of its speed (measured at
    most 1.1%, on the step, the sine and the slalom; 0.03% on the lane changes)."""
    traj = simulate(name, seed=1)
    speed = traj.state[:, S_U]
    assert np.all(np.isfinite(traj.state))
    assert np.abs(speed - SCENARIOS[name].speed).max() < 0.03 * SCENARIOS[name].speed


def test_random_scenarios_differ_by_seed_and_repeat_by_seed():
    a, b, c = (make_scenario("random", seed=s) for s in (1, 1, 2))
    assert a.speed_kph == b.speed_kph and a.speed_kph != c.speed_kph
    assert a.steering(3.0, STATE) == b.steering(3.0, STATE)


def test_random_ranges_bound_the_draws_and_keep_the_rest():
    """speed_range_kph and lateral_demand bound the speed and the steering's linear-model
    lateral demand (step amplitudes: demand mu g L / u^2 times the steering ratio); a seed keeps
    its road, its kind of steering and its timing."""
    p = VehicleParams()
    narrow_steps = 0
    for seed in range(40):
        default = make_scenario("random", seed=seed)
        narrow = make_scenario("random", seed=seed, speed_range_kph=[20, 25], lateral_demand=[0.05, 0.1])
        assert 20 <= narrow.speed_kph <= 25 and 30 <= default.speed_kph <= 110
        assert narrow.road == default.road and type(narrow.steering) is type(default.steering)
        if isinstance(narrow.steering, Step):
            assert narrow.steering.start == default.steering.start
            u, mu = narrow.speed, narrow.road.table()[0] if narrow.road.table() is not None else 0.5
            demand = abs(narrow.steering.angle) / p.steering_ratio * u**2 / p.wheelbase / (mu * GRAVITY)
            assert 0.05 <= demand <= 0.1
            narrow_steps += 1
    assert narrow_steps >= 5


def test_a_fixed_speed_or_road_keeps_a_random_seeds_other_draws():
    """Fixing speed_kph keeps the seed's road, kind of steering and timing; fixing mu keeps its
    speed, kind of steering and timing (a sweep over speed or friction runs the same episodes)."""
    for seed in range(20):
        default = make_scenario("random", seed=seed)
        for fixed in (make_scenario("random", seed=seed, speed_kph=50.0), make_scenario("random", seed=seed, mu=0.4)):
            assert type(fixed.steering) is type(default.steering)
            if isinstance(default.steering, Step):
                assert fixed.steering.start == default.steering.start
            else:
                assert fixed.steering.frequencies == default.steering.frequencies
        assert make_scenario("random", seed=seed, speed_kph=50.0).road == default.road
        assert make_scenario("random", seed=seed, mu=0.4).speed_kph == default.speed_kph


def test_random_course_episodes_follow_a_lane_change_with_the_path_follower():
    """course_share 1: every episode is a drawn double lane change steered by the path
    follower, run to 20 m past the exit; the car keeps to the line (uncontrolled, the oracle).
    course_share 0 leaves the draws alone."""
    from fourwis.envs.driver import PathFollower

    for seed in (3, 4):
        s = make_scenario("random", seed=seed, course_share=1.0)
        assert s.course.name == "lane_change" and isinstance(s.steering, PathFollower)
        np.testing.assert_array_equal(s.reference_path[1:], s.course.centreline)
        assert s.duration * s.speed == pytest.approx(s.course.length + 40.0)
    s = make_scenario("random", seed=3, course_share=1.0, speed_kph=40.0)
    traj = simulate(s)
    lateral_error = traj.state[:, 1] - np.interp(traj.state[:, 0], s.reference_path[:, 0], s.reference_path[:, 1])
    assert np.abs(lateral_error).max() < 0.5
    assert make_scenario("random", seed=3, course_share=0.0).steering == make_scenario("random", seed=3).steering


def test_mu_jump_drives_onto_the_low_friction_patch():
    traj = simulate("mu_jump")
    mu = traj.aux[:, 22:26]
    assert mu[0].max() == 0.9 and mu[-1].max() == 0.3
    before = traj.t < 1.0
    assert np.abs(traj.aux[before, 1][-50:]).mean() == pytest.approx(0.4 * GRAVITY, rel=0.1)


def test_simulation_is_deterministic_under_a_seed():
    a = simulate("paper_sine", seed=3)
    b = simulate("paper_sine", seed=3)
    c = simulate("paper_sine", seed=4)
    np.testing.assert_array_equal(a.sensors, b.sensors)
    np.testing.assert_array_equal(a.state, b.state)
    assert not np.array_equal(a.sensors, c.sensors)


@pytest.mark.parametrize("speed_kph, mu", [(60.0, 1.0), (50.0, 0.6)])
def test_driver_clears_iso3888_2_without_cone_hits(speed_kph, mu):
    from fourwis.training.compare import run_metrics

    metrics = run_metrics(simulate(make_scenario("iso3888_2", speed_kph=speed_kph, mu=mu)))
    assert metrics["cone_hits"] == 0
    assert metrics["path_max"] < 0.2  # tracks the line it was given, not just the lanes


def test_iso3888_2_enters_the_course_at_the_test_speed_and_coasts_from_there():
    """ISO 3888-2: the driver holds the test speed up to the first gate (X = 0) and lifts off
    there (before, it lifted off 10 m early, where the driver's line begins, and entered at 59.56
    km/h instead of 60)."""
    from fourwis.envs.layout import C_TORQUE, S_U, S_X

    run = simulate(make_scenario("iso3888_2", speed_kph=60.0, duration=2.5))
    x, torque = run.state[:, S_X], run.controls[:, C_TORQUE : C_TORQUE + 4]
    entry = np.argmax(x >= 0.0)
    assert run.state[entry, S_U] * 3.6 == pytest.approx(60.0, abs=0.02)
    assert np.all(torque[(x > -10.0) & (x < -0.1)] > 0.0)  # holding speed against the resistances
    assert np.all(torque[x > 0.1] == 0.0)


def test_driver_settles_on_a_circle_at_the_neutral_steer_angle():
    from dataclasses import replace

    from fourwis.envs.driver import PathFollower
    from fourwis.envs.layout import S_X, S_Y
    from fourwis.envs.vehicle import VehicleParams

    params, radius, speed, offset = VehicleParams(), 40.0, 8.0, 0.3
    angle = np.linspace(0.0, 1.5 * math.pi, 600)
    # the car starts at the origin heading +X, ``offset`` to the left of the circle's start
    circle = np.column_stack([radius * np.sin(angle), radius * (1.0 - np.cos(angle)) - offset])
    scenario = make_scenario("paper_sine", speed_kph=speed * 3.6, mu=1.0, duration=12.0)
    trajectory = simulate(replace(scenario, steering=PathFollower(circle, params), start_x=0.0))
    late = trajectory.t > 8.0
    distance = np.hypot(trajectory.state[late, S_X], trajectory.state[late, S_Y] - (radius - offset))
    assert np.max(np.abs(distance - radius)) < 0.01
    # neutral steer: the road-wheel angle that holds the circle is the kinematic L / R
    road_wheel = trajectory.steering_wheel[late] / params.steering_ratio
    assert np.mean(road_wheel) == pytest.approx(params.wheelbase / radius, rel=0.02)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"path": np.zeros((3, 2))}, "repeated"),
        ({"path": np.ones((1, 2))}, "shape"),
        ({"preview_time": 0.0}, "preview_time"),
        ({"preview_time": math.inf}, "preview_time .*, got inf"),
        ({"points": 0.5}, "points must be a whole number, got 0.5"),
    ],
)
def test_path_follower_rejects_bad_arguments(kwargs, match):
    from fourwis.envs.driver import PathFollower

    with pytest.raises(ValueError, match=match):
        PathFollower(**({"path": np.column_stack([np.arange(3.0), np.zeros(3)])} | kwargs))


def test_path_follower_scan_steers_as_the_whole_path_seen_from_the_car():
    """The compiled driver scans the path from its start; written out over every point (the
    path in the car's frame, np.interp at the preview distances) it steers the same, for cars
    before the course, on it, past its end and facing away from it."""
    from fourwis.envs.courses import lane_change
    from fourwis.envs.driver import PathFollower, _preview_responses
    from fourwis.envs.layout import NX, S_PSI, S_R, S_U, S_V, S_X, S_Y

    follower, rng = (
        PathFollower(lane_change(2.0, scale=1.4, offset=2.5, direction=-1).centreline),
        np.random.default_rng(5),
    )
    path, p = follower.path, follower.params
    steers, kinds = [], set()
    for _ in range(600):
        state = np.zeros(NX)
        state[[S_U, S_X, S_Y, S_PSI, S_V, S_R]] = (
            rng.uniform(-5.0, 40.0),
            rng.uniform(-30.0, 200.0),
            rng.normal(0.0, 3.0),
            rng.choice([rng.normal(0.0, 0.3), rng.uniform(-4.0, 4.0)]),
            rng.normal(0.0, 1.0),
            rng.normal(0.0, 0.3),
        )
        speed = max(abs(state[S_U]), 1.0)
        free, step = _preview_responses(p, round(speed, 1), follower.preview_time, follower.points)
        c, s = math.cos(state[S_PSI]), math.sin(state[S_PSI])
        dx, dy = path[:, 0] - state[S_X], path[:, 1] - state[S_Y]
        ahead, left = c * dx + s * dy, -s * dx + c * dy
        horizon = speed * follower.preview_time
        first = int(np.argmax(ahead > 0.0))
        stop = first + int(np.argmax(ahead[first:] > horizon)) + 1
        start = max(first - 1, 0)
        if ahead[first] > 0.0 and np.all(np.diff(ahead[start:stop]) > 0):
            target = np.interp(
                horizon * np.arange(1, follower.points + 1) / follower.points, ahead[start:stop], left[start:stop]
            )
            kinds.add("before the course" if state[S_X] < path[0, 0] else "on or past it")
        else:
            target = np.full(follower.points, left[np.argmin(dx * dx + dy * dy)])
            kinds.add("facing away")
        delta = -step @ (free @ [0.0, 0.0, state[S_V], state[S_R]] - target) / (step @ step)
        steers.append((follower(0.0, state), p.steering_ratio * np.clip(delta, -p.max_front_steer, p.max_front_steer)))
    assert kinds == {"before the course", "on or past it", "facing away"}
    np.testing.assert_allclose(*np.array(steers).T, rtol=1e-12, atol=1e-12)


def test_path_follower_names_a_speed_it_cannot_steer_at():
    from fourwis.envs.driver import DriverBatch, PathFollower
    from fourwis.envs.layout import NX, S_U

    follower = PathFollower(np.column_stack([np.arange(50.0), np.zeros(50)]))
    states = np.zeros((2, NX))
    states[:, S_U] = 20.0, np.nan
    assert np.isfinite(follower(0.0, states[0]))
    with pytest.raises(ValueError, match="vehicle 1's pose or speed is not finite"):
        DriverBatch([follower, follower])(np.zeros(2), states)
    states[1, S_U] = 1e18  # overflowed the speed table's index (a crash)
    with pytest.raises(ValueError, match="beyond 150 m/s"):
        DriverBatch([follower, follower])(np.zeros(2), states)


def test_steering_past_the_lock_steers_as_the_lock():
    """The servo stops at max_front_steer; the controller, its allocator and the references see
    that angle too, not the command past it (60 rad of steering wheel gave DYC-LQR 4.7 deg of
    sideslip and 3.8 m/s at the end where the lock gave 1.2 deg and 9.3 m/s)."""
    params = VehicleParams()
    lock = params.max_front_steer * params.steering_ratio

    def run(angle):
        steering = lambda t, state: angle if t >= 1.0 else 0.0  # noqa: E731
        return simulate(make_scenario("paper_step", speed_kph=40.0, mu=0.8, duration=3.0, steering=steering), "dyc-lqr")

    at_lock, past = run(lock), run(4.0 * lock)
    np.testing.assert_array_equal(at_lock.state, past.state)
    np.testing.assert_array_equal(at_lock.controls, past.controls)


@pytest.mark.parametrize(
    "build, bad",
    [
        (lambda: VehicleParams(rear_steer_feedforward="no"), "rear_steer_feedforward must be True or False, got 'no'"),
        (lambda: VehicleParams(tyre=None), "tyre must be an envs.tyre.TyreParams, got None"),
        (lambda: VehicleParams(max_front_steer=3.0), r"max_front_steer must be below pi/2 rad \(90 deg\), got 3.0"),
        (lambda: make_scenario(["paper_step"]), r"unknown scenario \['paper_step'\]"),
        (lambda: make_scenario("paper_step", duration=1e9), "'paper_step': duration must lie in .*, got 1000000000.0"),
        (
            lambda: make_scenario("slowly_increasing_steer", speed_kph=5.0),
            r"duration must lie in \(0, 600\] s, got 6.*5.0 km/h, falls",
        ),
        (lambda: patch(0.9, 0.3, "a", 5.0), "Patch.x0 must be a number .*, got 'a'"),
        (lambda: simulate("paper_step", progress="no"), "progress must be True or False, got 'no'"),
    ],
)
def test_bad_parameters_scenarios_and_switches_are_named(build, bad):
    with pytest.raises(ValueError, match=bad):
        build()


def test_the_random_scenario_steers_no_further_than_the_lock_at_walking_pace():
    params = VehicleParams()
    lock = params.max_front_steer * params.steering_ratio
    for seed in range(20):
        steering = make_scenario("random", speed_kph=1.0, seed=seed).steering
        amplitude = sum(steering.amplitudes) if hasattr(steering, "amplitudes") else abs(steering.angle)
        assert amplitude <= lock * (1 + 1e-12)

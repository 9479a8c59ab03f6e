"""Torque allocation: minimum tyre workload under the drive-force and yaw-moment equalities,
motor, brake and friction bounds; checked against scipy's SLSQP and linprog on random demands,
with steered wheels (the body-frame effect of each wheel's force derived here from the geometry),
and each priority of an infeasible demand (the driver's force first, or the yaw moment)."""

import numpy as np
import pytest
from scipy.optimize import linprog, minimize

from fourwis.control.allocation import allocate_torques
from fourwis.envs.vehicle import VehicleParams

P = VehicleParams()
LEVER = np.array([-1.0, 1.0, -1.0, 1.0]) * P.track_front / 2  # dMz / dFx_i of straight wheels, ISO axes
WHEELS = np.array(
    [
        [P.cg_to_front, P.track_front / 2],
        [P.cg_to_front, -P.track_front / 2],
        [-P.cg_to_rear, P.track_rear / 2],
        [-P.cg_to_rear, -P.track_rear / 2],
    ]
)  # (x, y) [m]


def _body_effect(front_steer: float, rear_steer: float) -> tuple[np.ndarray, np.ndarray]:
    """Body x force and yaw moment (r x F, z component) of a unit force along each wheel's heading."""
    delta = np.array([front_steer, front_steer, rear_steer, rear_steer])
    fx, fy = np.cos(delta), np.sin(delta)
    return fx, WHEELS[:, 0] * fy - WHEELS[:, 1] * fx


def _random_steer(seed: int, batch: int):
    rng = np.random.default_rng(seed + 100)
    return rng.uniform(-0.5, 0.5, batch), rng.uniform(-P.max_rear_steer, P.max_rear_steer, batch)


def _random_demands(seed: int, batch: int):
    rng = np.random.default_rng(seed)
    fz = rng.uniform(500.0, 3500.0, (batch, 4))
    mu = rng.uniform(0.1, 1.0, (batch, 4))
    lateral = rng.uniform(-0.95, 0.95, (batch, 4)) * mu * fz
    speed = rng.uniform(0.0, 35.0, batch)
    base = rng.normal(0.0, 150.0, (batch, 4))
    moment = rng.normal(0.0, 1500.0, batch)
    return base, moment, fz, mu, lateral, speed


def _force_limits(fz, mu, lateral, speed):
    """(lower, upper) (B, 4) [N]: a wheel drives with its motor and brakes with its motor and
    friction brake, both within what the friction ellipse leaves."""
    motor = np.minimum(P.motor_peak_torque, P.motor_peak_power * P.wheel_radius / np.maximum(speed, 1e-9))
    grip = np.sqrt(np.maximum((mu * fz) ** 2 - lateral**2, 0.0))
    upper = np.minimum(motor[:, None] / P.wheel_radius, grip)
    return -np.minimum((motor[:, None] + P.brake_peak_torque) / P.wheel_radius, grip), upper


@pytest.mark.parametrize("steered", [False, True])
def test_feasible_demands_are_met_exactly_at_the_least_workload_scipy_finds(steered):
    base, moment, fz, mu, lateral, speed = _random_demands(0, 60)
    front, rear = _random_steer(0, 60) if steered else (np.zeros(60), np.zeros(60))
    out = allocate_torques(base, moment, fz, mu, P, lateral, speed, front, rear)
    forces = out.torques / P.wheel_radius
    lower, upper = _force_limits(fz, mu, lateral, speed)
    assert np.all((forces <= upper * (1 + 1e-9) + 1e-9) & (forces >= lower * (1 + 1e-9) - 1e-9))
    checked = 0
    for b in np.flatnonzero(out.feasible):
        along, lever = _body_effect(front[b], rear[b])
        drive, cap = along @ base[b] / P.wheel_radius, mu[b] * fz[b]
        assert along @ forces[b] == pytest.approx(drive, abs=1e-6)
        assert lever @ forces[b] == pytest.approx(moment[b], abs=1e-6)
        assert (out.drive_force[b], out.yaw_moment[b]) == pytest.approx((drive, moment[b]), abs=1e-6)
        # the same QP in workload-normalised forces y = Fx / (mu Fz), which SLSQP handles well
        # (scipy 1.17's SLSQP needs more than its default 100 iterations on some of these, and the
        # constraints' exact Jacobian: with finite differences its line search failed on one)
        rows = np.array([along * cap, lever * cap]) / 1e3
        reference = minimize(
            lambda y: y @ y,
            np.zeros(4),
            jac=lambda y: 2 * y,
            method="SLSQP",
            bounds=list(zip(lower[b] / cap, upper[b] / cap)),
            options={"ftol": 1e-13, "maxiter": 1000},
            constraints=[
                {"type": "eq", "fun": lambda y: rows @ y - np.array([drive, moment[b]]) / 1e3, "jac": lambda y: rows}
            ],
        )
        assert reference.success, reference.message
        workload = np.sum((forces[b] / cap) ** 2)
        assert workload <= reference.fun * (1 + 1e-7) + 1e-12
        checked += 1
    assert checked >= 20  # the random set exercises the bounded-QP branch, not only easy cases
    at_bound = np.isclose(forces, lower) | np.isclose(forces, upper)
    assert np.sum(np.any(at_bound, axis=1) & out.feasible) >= 5


def test_without_active_bounds_it_is_the_closed_form_weighted_least_squares():
    fz = np.array([[2400.0, 1800.0, 2200.0, 1600.0]])
    mu = np.array([[0.9, 0.8, 0.9, 0.6]])
    out = allocate_torques(np.full((1, 4), 40.0), np.array([600.0]), fz, mu, P)
    A = np.vstack([np.ones(4), LEVER])
    W_inv = np.diag((mu[0] * fz[0]) ** 2)
    d = np.array([160.0 / P.wheel_radius, 600.0])
    expected = W_inv @ A.T @ np.linalg.solve(A @ W_inv @ A.T, d)
    np.testing.assert_allclose(out.torques[0] / P.wheel_radius, expected, rtol=1e-10)
    assert out.feasible[0]


@pytest.mark.parametrize("steered", [False, True])
def test_infeasible_moment_degrades_to_the_largest_feasible_one_and_is_flagged(steered):
    base, moment, fz, mu, lateral, speed = _random_demands(1, 40)
    front, rear = _random_steer(1, 40) if steered else (np.zeros(40), np.zeros(40))
    moment = np.sign(moment) * 2e4  # beyond any tyre's reach on this car
    out = allocate_torques(base, moment, fz, mu, P, lateral, speed, front, rear)
    lower, upper = _force_limits(fz, mu, lateral, speed)
    assert not out.feasible.any()
    for b in range(len(base)):
        along, lever = _body_effect(front[b], rear[b])
        drive = np.clip(along @ base[b] / P.wheel_radius, along @ lower[b], along @ upper[b])
        best = linprog(
            -np.sign(moment[b]) * lever, A_eq=along[None], b_eq=[drive], bounds=list(zip(lower[b], upper[b]))
        )
        assert out.drive_force[b] == pytest.approx(drive, abs=1e-6)
        assert out.yaw_moment[b] == pytest.approx(lever @ best.x, abs=1e-6)
        np.testing.assert_allclose(along @ out.torques[b] / P.wheel_radius, out.drive_force[b], atol=1e-6)
    assert np.isfinite(out.torques).all()


@pytest.mark.parametrize("steered", [False, True])
def test_stability_first_keeps_the_largest_moment_then_the_drive_force_nearest_the_drivers(steered):
    """Outside the stable region (stability_first) the driver's drive yields (a drive force is
    asked as none, a braking one stands), and an infeasible demand keeps the yaw moment the box
    allows at any drive force (linprog over the box), then the drive force nearest that demand
    which delivers it (linprog with that moment); the driver's force first comes no nearer the
    asked moment. A feasible demand is met either way."""
    base, moment, fz, mu, lateral, speed = _random_demands(2, 40)
    front, rear = _random_steer(2, 40) if steered else (np.zeros(40), np.zeros(40))
    base = base + np.where(np.arange(40) % 2 == 0, -1500.0, 600.0)[:, None]  # a pedal the tyres cannot all take
    moment = np.sign(moment) * np.abs(moment).clip(500.0, None) * 3.0
    first = np.ones(40, dtype=bool)
    out = allocate_torques(base, moment, fz, mu, P, lateral, speed, front, rear, stability_first=first)
    driver = allocate_torques(base, moment, fz, mu, P, lateral, speed, front, rear)
    lower, upper = _force_limits(fz, mu, lateral, speed)
    checked = 0
    for b in range(40):
        along, lever = _body_effect(front[b], rear[b])
        bounds = list(zip(lower[b], upper[b]))
        forces = out.torques[b] / P.wheel_radius
        assert np.all((forces <= upper[b] + 1e-6) & (forces >= lower[b] - 1e-6))
        assert lever @ forces == pytest.approx(out.yaw_moment[b], abs=1e-6)
        assert along @ forces == pytest.approx(out.drive_force[b], abs=1e-6)
        drive = min(along @ base[b] / P.wheel_radius, 0.0)
        if out.feasible[b]:
            assert out.yaw_moment[b] == pytest.approx(moment[b], abs=1e-6)
            assert out.drive_force[b] == pytest.approx(drive, abs=1e-6)
            continue
        reach = -linprog(-np.sign(moment[b]) * lever, bounds=bounds).fun * np.sign(moment[b])
        kept = np.sign(moment[b]) * min(abs(moment[b]), abs(reach))
        assert out.yaw_moment[b] == pytest.approx(kept, abs=1e-6)
        assert abs(out.yaw_moment[b] - moment[b]) <= abs(driver.yaw_moment[b] - moment[b]) + 1e-6
        low = linprog(along, A_eq=lever[None], b_eq=[kept], bounds=bounds).fun
        high = -linprog(-along, A_eq=lever[None], b_eq=[kept], bounds=bounds).fun
        assert out.drive_force[b] == pytest.approx(np.clip(drive, low, high), abs=1e-6)
        checked += 1
    assert checked >= 10


def test_a_wheel_brakes_beyond_its_motor_within_its_grip():
    """At 100 km/h the motors' power limit leaves ~250 N m; a braking demand the grip allows goes
    beyond it (the friction brake), a drive demand stops at it."""
    fz, mu = np.full((1, 4), 2500.0), np.full((1, 4), 1.0)
    speed = np.array([100 / 3.6])
    motor = P.motor_peak_power * P.wheel_radius / speed[0]
    braking = allocate_torques(np.full((1, 4), -500.0), np.zeros(1), fz, mu, P, speed=speed)
    np.testing.assert_allclose(braking.torques[0], -500.0, rtol=1e-12)
    assert braking.feasible[0] and motor < 500.0
    grip = allocate_torques(np.full((1, 4), -1500.0), np.zeros(1), fz, mu, P, speed=speed)
    np.testing.assert_allclose(grip.torques[0], -2500.0 * P.wheel_radius, rtol=1e-9)
    driving = allocate_torques(np.full((1, 4), 500.0), np.zeros(1), fz, mu, P, speed=speed)
    np.testing.assert_allclose(driving.torques[0], motor, rtol=1e-9)


def test_mirrored_demand_mirrors_the_torques_and_a_laterally_saturated_tyre_gets_none():
    fz, mu = np.full((1, 4), 2000.0), np.full((1, 4), 0.8)
    base = np.full((1, 4), 50.0)
    left = allocate_torques(base, np.array([800.0]), fz, mu, P)
    right = allocate_torques(base, np.array([-800.0]), fz, mu, P)
    np.testing.assert_allclose(right.torques[0], left.torques[0, [1, 0, 3, 2]], atol=1e-9)
    assert left.torques[0, 1] > left.torques[0, 0]  # a left (positive) moment drives the right wheels harder
    lateral = np.array([[1600.0, 0.0, 0.0, 0.0]])  # front-left at its friction limit
    saturated = allocate_torques(base, np.array([800.0]), fz, mu, P, lateral)
    assert saturated.torques[0, 0] == pytest.approx(0.0, abs=1e-9)
    assert saturated.feasible[0] and saturated.yaw_moment[0] == pytest.approx(800.0)


def test_steered_front_wheels_drive_the_car_and_turn_it():
    """With the front wheels steered left, equal drive forces on them turn the car left; asked for
    drive without a yaw moment, the allocator drives the front-left wheel harder to cancel it."""
    fz, mu, base = np.full((1, 4), 2000.0), np.full((1, 4), 0.8), np.full((1, 4), 100.0)
    straight = allocate_torques(base, np.zeros(1), fz, mu, P)
    steered = allocate_torques(base, np.zeros(1), fz, mu, P, front_steer=np.array([0.2]))
    np.testing.assert_allclose(straight.torques[0], 100.0, rtol=1e-12)
    _, lever = _body_effect(0.2, 0.0)
    assert lever[:2].sum() > 0.0  # a steered-left front axle's drive force turns the car left...
    assert steered.torques[0, 0] > steered.torques[0, 1]  # ...so the allocator drives the left wheel harder
    assert lever @ steered.torques[0] == pytest.approx(0.0, abs=1e-6)


def test_motor_power_limits_the_torque_at_speed():
    fz, mu = np.full((1, 4), 3000.0), np.full((1, 4), 1.0)
    fast = allocate_torques(np.full((1, 4), 600.0), np.zeros(1), fz, mu, P, speed=np.array([30.0]))
    assert np.abs(fast.torques).max() == pytest.approx(P.motor_peak_power * P.wheel_radius / 30.0)
    assert not fast.feasible[0]


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"yaw_moment": np.array([np.nan])}, "yaw moment"),
        ({"mu": np.full((1, 4), np.inf)}, "friction"),
        ({"fz": np.ones((1, 3))}, "shape"),
        ({"front_steer": np.array([np.nan])}, "front steer"),
        ({"mu": np.array([[1.0, 0.0, 1.0, 1.0]])}, "friction must be > 0"),
        ({"fz": np.array([[1.0, -5.0, 1.0, 1.0]])}, "loads must be >= 0"),
    ],
)
def test_bad_input_names_the_bad_value(bad, match):
    args = {
        "base_torques": np.zeros((1, 4)),
        "yaw_moment": np.zeros(1),
        "fz": np.ones((1, 4)),
        "mu": np.ones((1, 4)),
    } | bad
    with pytest.raises(ValueError, match=match):
        allocate_torques(params=P, **args)


def test_allocation_allocates_nothing_per_vehicle(heap_allocations):
    """The compiled allocator keeps its work arrays on the stack: 64 demands, a third of them
    infeasible (the greedy programmes and the full active-set search), make as many heap
    allocations (the outputs) as one."""
    counts = []
    for batch in (1, 64):
        base, moment, fz, mu, lateral, speed = _random_demands(3, batch)
        if batch > 1:
            feasible = allocate_torques(base, moment, fz, mu, P, lateral_forces=lateral, speed=speed).feasible
            assert 0.2 < 1.0 - feasible.mean() < 0.8
        counts.append(
            heap_allocations(lambda: allocate_torques(base, moment, fz, mu, P, lateral_forces=lateral, speed=speed))
        )
    assert counts[0] == counts[1]

"""The brake-based ESC baseline (control/esc.py) on constructed estimates: the wheel it brakes,
its thresholds and hysteresis, its limits."""

import numpy as np
import pytest

from fourwis.control import make_controller
from fourwis.control.esc import EXIT_YAW_ERROR, BrakeESC
from fourwis.control.reference import STABLE_YAW_ERROR as ENTRY_YAW_ERROR
from fourwis.control.reference import reference_yaw_rate
from fourwis.core.types import Estimate
from fourwis.envs.vehicle import VehicleParams

P = VehicleParams()


def estimate(u, r, beta=0.0, mu=1.0):
    """An Estimate of one car at speed u [m/s], yaw rate r [rad/s], sideslip beta [rad], on mu."""
    one = lambda x: np.array([float(x)])  # noqa: E731
    fz = P.static_wheel_loads[None]
    return Estimate(one(u), one(u * np.tan(beta)), one(beta), one(r), one(0.0), one(0.0),
                    np.full((1, 4), mu), fz, one(0.0), np.zeros((1, 4)))  # fmt: skip


def command(esc, u, r, delta, beta=0.0, mu=1.0, base=100.0):
    return esc(np.zeros(1), estimate(u, r, beta, mu), np.array([delta]), np.full((1, 4), base)).torques[0]


def ref(u, delta, mu=1.0):
    return float(reference_yaw_rate(np.array([u]), np.array([delta]), np.full((1, 4), mu), P)[0])


def test_oversteer_brakes_the_outer_front_wheel_and_understeer_the_inner_rear_one():
    """In a left turn a car yawing faster than its reference gets a clockwise moment from the
    right front brake; one yawing slower a counter-clockwise one from the left rear brake; the
    driver's drive torque is cut while the ESC acts; mirrored for a right turn."""
    u, delta = 20.0, 0.03
    for sign in (1.0, -1.0):
        esc = BrakeESC(P)
        over = command(esc, u, ref(u, sign * delta) + sign * 0.2, sign * delta)
        braked = 1 if sign > 0 else 0  # the outer front wheel
        assert over[braked] < 0.0 and np.all(np.delete(over, braked) == 0.0)
        esc = BrakeESC(P)
        under = command(esc, u, ref(u, sign * delta) - sign * 0.2, sign * delta)
        braked = 2 if sign > 0 else 3  # the inner rear wheel
        assert under[braked] < 0.0 and np.all(np.delete(under, braked) == 0.0)
    # the brake torque delivers the moment -Iz / 0.15 s x error through the half track
    esc = BrakeESC(P)
    torques = command(esc, u, ref(u, delta) + 0.1, delta, base=0.0)
    assert -torques[1] == pytest.approx(P.yaw_inertia / 0.15 * 0.1 * P.wheel_radius / (P.track_front / 2))


def test_entry_and_exit_thresholds_give_hysteresis():
    """Off below the entry error; on past it; still on between the exit and entry errors; off
    again below the exit error; never on below 5 m/s."""
    u, delta = 20.0, 0.02
    base = ref(u, delta)
    esc = BrakeESC(P)
    untouched = np.full(4, 100.0)
    between = 0.5 * (ENTRY_YAW_ERROR + EXIT_YAW_ERROR)
    np.testing.assert_array_equal(command(esc, u, base + between, delta), untouched)
    assert np.any(command(esc, u, base + 1.2 * ENTRY_YAW_ERROR, delta) < 0.0)
    assert np.any(command(esc, u, base + between, delta) < 0.0)
    np.testing.assert_array_equal(command(esc, u, base + 0.5 * EXIT_YAW_ERROR, delta), untouched)
    np.testing.assert_array_equal(command(BrakeESC(P), 4.0, 1.0, delta), untouched)


def test_the_brake_torque_stays_within_the_wheels_estimated_grip_and_the_name_builds_it():
    esc = make_controller("esc", P)
    assert isinstance(esc, BrakeESC)
    torques = command(esc, 20.0, 2.0, 0.02, mu=0.1, base=0.0)
    assert -torques.min() <= 0.1 * P.static_wheel_loads.max() * P.wheel_radius + 1e-9


class PythonESC(BrakeESC):
    """The ESC served in Python by the closed loop (a subclass: the loop compiles only BrakeESC)."""

    def __call__(self, t, estimate, front_steer, base_torques):
        return super().__call__(t, estimate, front_steer, base_torques)


def test_the_compiled_esc_stage_drives_the_car_as_its_python_call_does():
    """On a patch of ice (mu_jump to 0.1, the oracle) the ESC acts, and the closed loop's compiled
    ESC stage and the controller called from Python give the same trajectory."""
    from fourwis.envs.layout import C_BRAKE
    from fourwis.envs.scenarios import make_scenario
    from fourwis.envs.simulation import simulate

    scenario = make_scenario("mu_jump", mu_patch=0.1, duration=4.0)
    compiled = simulate(scenario, BrakeESC(P), "oracle", seed=0)
    python = simulate(scenario, PythonESC(P), "oracle", seed=0)
    assert compiled.controls[:, C_BRAKE : C_BRAKE + 4].max() > 1e4  # it braked a wheel (> 0.1 bar)
    np.testing.assert_allclose(compiled.state, python.state, rtol=1e-9, atol=1e-9)

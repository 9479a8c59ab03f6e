"""Wheel actuation: the motor/brake split, ABS and traction control (control/wheel_slip.py), and
ABS in the closed loop on the straight-line braking scenario."""

import numpy as np
import pytest

from fourwis.control.wheel_slip import MIN_SLIP_BAND, PEAK_SLIP, SLIP_BAND, actuate_batch, wheel_actuators
from fourwis.core.constants import GRAVITY
from fourwis.envs.layout import A_FX, A_FZ, A_KAPPA, S_OMEGA, S_U, S_X
from fourwis.envs.metrics import braking_metrics
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import DT, simulate
from fourwis.envs.tyre import tyre_forces
from fourwis.envs.vehicle import VehicleParams

P = VehicleParams()


def split(demand, omega=50.0, speed=None, mu=1.0, **switches):
    """The (motor, pressure) commands of one car with every wheel at ``omega`` [rad/s]."""
    actuators = wheel_actuators(P, 1, DT, **switches)
    speed = omega * P.wheel_radius if speed is None else speed
    return actuate_batch(
        actuators, np.full((1, 4), demand, dtype=float), np.full((1, 4), omega), np.array([speed]), np.full((1, 4), mu)
    )


def test_the_motors_take_what_they_can_and_the_brakes_the_rest_of_a_braking_demand():
    """At 50 rad/s the motors' power limit is 500 N m: a -300 N m demand is all regenerative, a
    -1,500 N m one leaves 1,000 N m to the brakes; beyond the brakes' peak the pressure is clipped;
    a drive demand never brakes."""
    limit = P.motor_peak_power / 50.0
    motor, pressure = split(-300.0, abs=False)
    np.testing.assert_allclose(motor, -300.0) and np.testing.assert_allclose(pressure, 0.0)
    motor, pressure = split(-1500.0, abs=False)
    np.testing.assert_allclose(motor, -limit)
    np.testing.assert_allclose(pressure * P.brake_gain, 1500.0 - limit)
    _, pressure = split(-1e5, abs=False)
    np.testing.assert_allclose(pressure, P.brake_max_pressure)
    motor, pressure = split(2000.0, tcs=False)
    np.testing.assert_allclose(motor, min(P.motor_peak_torque, limit)) and np.all(pressure == 0.0)


@pytest.mark.parametrize("mu", [1.0, 0.3, 0.1])
def test_abs_and_tcs_fade_the_demand_across_the_friction_scheduled_slip_window(mu):
    """Full demand below peak - band / 2 of slip, none beyond peak + band / 2 (times mu; the band
    at least MIN_SLIP_BAND), a
    straight line between; ABS on braking slip, TCS on drive slip; switched off, the demand stands."""
    speed = 8.0  # (below the motors' power limit at 400 N m)
    peak, band = PEAK_SLIP * mu, max(SLIP_BAND * mu, MIN_SLIP_BAND)
    for slip, share in ((-(peak - band / 2) + 1e-9, 1.0), (-peak, 0.5), (-(peak + band / 2) - 1e-9, 0.0)):
        omega = speed * (1 + slip) / P.wheel_radius
        motor, pressure = split(-1000.0, omega, speed, mu, tcs=False)
        np.testing.assert_allclose(-motor + pressure * P.brake_gain, 1000.0 * share, atol=1e-3)
        motor, pressure = split(400.0, speed * (1 - slip) / P.wheel_radius, speed, mu, abs=False)
        np.testing.assert_allclose(motor, 400.0 * share, atol=1e-3)
    motor, pressure = split(-1000.0, 0.5 * speed / P.wheel_radius, speed, mu, abs=False)
    np.testing.assert_allclose(-motor + pressure * P.brake_gain, 1000.0)


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="abs must be True or False"):
        wheel_actuators(P, 1, DT, abs=1)
    with pytest.raises(ValueError, match="peak_slip must be a finite number > 0"):
        wheel_actuators(P, 1, DT, peak_slip=-0.1)
    with pytest.raises(ValueError, match="peak_slip - slip_band / 2 must be > 0"):
        wheel_actuators(P, 1, DT, peak_slip=0.05, slip_band=0.2)


def stop(mu, slip_control=True, estimator="oracle"):
    scenario = make_scenario("straight_braking", mu=mu)
    run = simulate(scenario, None, estimator, seed=0, slip_control=slip_control)
    rims = run.state[:, S_OMEGA : S_OMEGA + 4] * P.wheel_radius
    return run, braking_metrics(run.t, run.state[:, S_X], run.state[:, S_U], rims, scenario.brake_after)


@pytest.mark.parametrize("mu", [1.0, 0.5, 0.2])
def test_abs_stops_within_15_percent_of_the_ideal_distance_without_locking_a_wheel(mu):
    """From 100 km/h with a full pedal and the true state: the stop takes at most 1.15 v^2 / (2 mu g)
    (the tyres' peak is mu at their static load; drag helps), no wheel locks for 0.2 s above
    15 km/h; without slip control the wheels lock and the stop takes 30% longer."""
    _, result = stop(mu)
    ideal = result.initial_speed**2 / (2 * mu * GRAVITY)
    assert result.stopping_distance is not None and result.stopping_distance <= 1.15 * ideal
    assert result.longest_lock < 0.2
    _, locked = stop(mu, slip_control=False)
    assert locked.longest_lock > 1.0 and locked.stopping_distance > 1.2 * ideal


def test_abs_holds_each_wheel_near_its_tyres_peak_slip():
    """On mu 0.5 (true state): between 1 and 3 s of the stop each wheel's mean slip is within 0.02
    of the slip at which its tyre's Fx peaks at its load, and the tyre delivers over 97% of that peak."""
    run, _ = stop(0.5)
    window = slice(int(1.0 / DT), int(3.0 / DT))
    kappa = run.aux[window, A_KAPPA : A_KAPPA + 4].mean(axis=0)
    fz = run.aux[window, A_FZ : A_FZ + 4].mean(axis=0)
    fx = run.aux[window, A_FX : A_FX + 4].mean(axis=0)
    grid = np.linspace(-0.5, 0.0, 5001)
    for w in range(4):
        curve, _ = tyre_forces(P.tyre, fz[w], grid, 0.0, 0.5, P.reference_wheel_load)
        peak = int(np.argmin(curve))
        assert abs(kappa[w] - grid[peak]) < 0.02, (w, kappa[w], grid[peak])
        assert fx[w] / curve[peak] > 0.97


def test_tcs_sees_four_wheels_spinning_alike_that_abs_reference_would_not():
    """All four wheels spin up together (from 10 to 12 m/s of rim speed in 1 s) while the car, by
    its accelerometer, does not accelerate, and the speed estimate follows the wheels (as a
    wheel-based estimator does): the TCS reference, the slowest wheel held within the measured
    acceleration + REFERENCE_MARGIN, stays near 10 m/s, so the slip reads ~0.19 and a drive demand
    is cut; the ABS reference, the fastest wheel, stays at or below the wheels."""
    from fourwis.control.wheel_slip import REFERENCE_MARGIN, actuate, reference_speeds

    actuators = wheel_actuators(P, 1, DT)
    steps = int(1.0 / DT)
    for k in range(steps + 1):
        rim = 10.0 + 2.0 * k / steps
        omega = np.full(4, rim / P.wheel_radius)
        braking, drive = reference_speeds(actuators, 0, omega, 0.0, rim, 0.0)
    assert drive == pytest.approx(10.0 + REFERENCE_MARGIN * 1.0, abs=1e-9)
    assert braking == pytest.approx(12.0)  # (the estimate, which the wheels carried along)
    motor, pressure = np.empty(4), np.empty(4)
    actuate(actuators, np.full(4, 300.0), omega, braking, drive, 0.0, np.ones(4), motor, pressure)
    np.testing.assert_allclose(motor, 0.0, atol=1e-9)
    assert np.all(pressure == 0.0)

"""Control: references, the 4WS law, LQR/SMC yaw-moment laws, allocation, and closed loop."""

import math

import numpy as np
import pytest

from fourwis.control import CONTROLLERS, MIN_PLANNING_MU, StabilityController, make_controller
from fourwis.control.dyc import LQRWeights, LQRYawController, SlidingModeYawController, bicycle_matrices
from fourwis.control.reference import (
    GRAVITY,
    rear_steer_gain,
    reference_yaw_rate,
    sideslip_bound,
    understeer_gradient,
    weaker_axle_friction,
)
from fourwis.core.types import Estimate
from fourwis.envs.fmvss126 import amplitudes, characterise, run_series
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.envs.vehicle import VehicleParams

P = VehicleParams()


def test_reference_is_kinematic_at_low_speed_and_friction_bounded():
    delta = np.array([0.05])
    assert understeer_gradient(P) == pytest.approx(0.0, abs=1e-9)  # a = b, equal tyres
    r = reference_yaw_rate(np.array([3.0]), delta, np.full((1, 4), 1.0), P)
    assert r[0] == pytest.approx(3.0 * 0.05 / P.wheelbase)
    fast = reference_yaw_rate(np.array([30.0]), delta, np.full((1, 4), 0.3), P)
    assert fast[0] == pytest.approx(0.85 * 0.3 * GRAVITY / 30.0)
    mirrored = reference_yaw_rate(np.array([30.0]), -delta, np.full((1, 4), 0.3), P)
    assert mirrored[0] == -fast[0]
    # atan(0.02 mu g) (Rajamani 2012, sec. 8.5): 11 deg at mu 1, 1.1 deg on 0.1 ice
    for mu in (1.0, 0.3, 0.1):
        assert sideslip_bound(np.full((1, 4), mu))[0] == pytest.approx(math.atan(0.02 * mu * GRAVITY), rel=1e-12)


def test_an_oversteering_car_gets_a_neutral_reference_past_its_critical_speed():
    """CG moved back (a > b): K_us < 0 and the car's own steady state u delta / (L + K u^2) turns
    against the steering above sqrt(L / -K) (~59 m/s here; 0.004 rad of steering); the reference floors K at 0 (neutral)
    and keeps the steering's sign at every speed. A gradient asked for explicitly is used as is."""
    rear_heavy = P.replace(cg_to_front=1.40, cg_to_rear=0.94)
    k = understeer_gradient(rear_heavy)
    critical = math.sqrt(rear_heavy.wheelbase / -k)
    u = np.array([0.5, 0.99, 1.01, 1.5]) * critical
    r = reference_yaw_rate(u, np.full(4, 0.004), np.full((4, 4), 2.0), rear_heavy)
    np.testing.assert_allclose(r, u * 0.004 / rear_heavy.wheelbase)  # below the friction bound at mu 2
    explicit = reference_yaw_rate(u[:1], np.full(1, 0.005), np.full((1, 4), 2.0), rear_heavy, understeer=0.002)
    assert explicit[0] == pytest.approx(u[0] * 0.005 / (rear_heavy.wheelbase + 0.002 * u[0] ** 2))


def test_eq20_gain_changes_phase_at_the_closed_form_speed():
    c_f, c_r = P.axle_cornering_stiffness
    u0 = math.sqrt(P.cg_to_rear * c_r * P.wheelbase / (P.mass * P.cg_to_front))
    assert rear_steer_gain(np.array(u0 * 0.5), P) < 0 < rear_steer_gain(np.array(u0 * 1.5), P)
    assert rear_steer_gain(np.array(u0), P) == pytest.approx(0.0, abs=1e-12)
    assert rear_steer_gain(np.array(0.0), P) == pytest.approx(-P.cg_to_rear / P.cg_to_front)


def _with_actuator_lag(u: float):
    """The 2-DOF model with the delivered moment lagging the command: states [beta, r, M]."""
    from fourwis.control.dyc import actuator_lag

    A, B = bicycle_matrices(u, P)
    tau = float(actuator_lag(u, P))
    return np.block([[A, B], [np.zeros((1, 2)), np.full((1, 1), -1.0 / tau)]]), np.array([[0.0], [0.0], [1.0 / tau]])


def test_lqr_gains_solve_the_riccati_equation_of_the_lagged_model_and_damp_it_well():
    """At every scheduled speed the gains are scipy's Riccati solution for the 2-DOF model with the
    actuator lag (motors + tyre relaxation) and Bryson weights, and the loop they close on that
    model is damped (zeta >= 0.7; measured 0.78-0.90 where the poles are complex). Designed
    without the lag, the 2-DOF gains leave it at zeta 0.41-0.45 from 40 km/h up."""
    from scipy.linalg import solve_continuous_are

    from fourwis.control.dyc import actuator_lag

    # motors 10 ms + sigma_kappa / u (0.39 m at the static load): 28 ms at 80 km/h, 80 ms at 20
    assert float(actuator_lag(80 / 3.6, P)) == pytest.approx(0.0275, abs=5e-4)
    assert float(actuator_lag(20 / 3.6, P)) == pytest.approx(0.080, abs=5e-4)
    lqr = LQRYawController(P)
    w = lqr.weights
    worst_lag_free = 1.0
    for u, k in zip(lqr.speeds, lqr.gains):
        A, B = _with_actuator_lag(float(u))
        Q, R = np.diag([w.beta**-2, w.yaw_rate_error**-2, 0.0]), np.array([[w.yaw_moment**-2]])
        np.testing.assert_allclose(k, (B.T @ solve_continuous_are(A, B, Q, R))[0] / R[0, 0], rtol=1e-9)
        poles = np.linalg.eigvals(A - B @ k[None, :])
        assert np.all(-poles.real / np.abs(poles) >= 0.7)
        A2, B2 = bicycle_matrices(float(u), P)
        k2 = (B2.T @ solve_continuous_are(A2, B2, Q[:2, :2], R))[0] / R[0, 0]
        lag_free = np.linalg.eigvals(A - B @ np.append(k2, 0.0)[None, :])
        worst_lag_free = min(worst_lag_free, float(np.min(-lag_free.real / np.abs(lag_free))))
    assert worst_lag_free < 0.5


@pytest.mark.parametrize("name", ["dyc-lqr", "dyc-lqr-4ws", "dyc-smc-4ws"])
def test_the_dyc_holds_a_gentle_low_speed_turn_without_spinning_its_wheels(name):
    """A 20 km/h steering step of 2 rad (0.17 g) on mu 0.8: after the transient the wheels keep
    their grip (|slip| < 0.05; measured <= 0.001) and the yaw rate settles (std < 0.005 rad/s).
    With a fixed 0.15 s reference lag and the lag-free LQR the wheels spun up to slip 1.2-1.6
    with the motors at +/- 550-590 N m and the yaw rate swinging +/- 0.13 rad/s; dyc-smc-4ws
    spun the car (90 deg)."""
    from fourwis.envs.layout import A_KAPPA
    from fourwis.envs.scenarios import make_scenario

    traj = simulate(
        make_scenario("paper_step", speed_kph=20.0, mu=0.8, angle=2.0),
        controller=make_controller(name, P),
        estimator="oracle",
    )
    late = traj.t > 7.0
    assert np.max(np.abs(traj.aux[late, A_KAPPA : A_KAPPA + 4])) < 0.05
    assert np.std(traj.truth.r[late]) < 0.005


def test_lqr_reduces_yaw_error_on_an_oversteering_plant():
    """Linear 2-DOF plant with 30% less rear stiffness (oversteer) tracking a step reference."""
    c_f, c_r = P.axle_cornering_stiffness

    class Oversteer:
        mass, yaw_inertia, cg_to_front, cg_to_rear, wheelbase = P.mass, P.yaw_inertia, 1.17, 1.17, 2.34
        axle_cornering_stiffness = (c_f, 0.7 * c_r)

    lqr = LQRYawController(P)
    u, delta, dt = 25.0, 0.02, 0.002
    A, B = bicycle_matrices(u, Oversteer)
    E = np.array([c_f / (P.mass * u), P.cg_to_front * c_f / P.yaw_inertia])
    r_ref = u * delta / P.wheelbase
    errors = {}
    for control in (False, True):
        x = np.zeros(2)
        err = []
        for _ in range(1500):
            mz = lqr.moment(np.array([u]), np.array([x[0]]), np.array([x[1]]), np.array([r_ref]))[0] if control else 0
            x = x + dt * (A @ x + B[:, 0] * mz + E * delta)
            err.append(x[1] - r_ref)
        errors[control] = np.sqrt(np.mean(np.square(err)))
    assert errors[True] < 0.5 * errors[False]


def test_bad_input_raises():
    with pytest.raises(ValueError, match="pid"):
        make_controller("pid", P)
    controller = StabilityController(P)
    two = Estimate(
        u=np.full(2, 20.0),
        v=np.zeros(2),
        beta=np.zeros(2),
        r=np.zeros(2),
        ax=np.zeros(2),
        ay=np.zeros(2),
        mu=np.ones((2, 4)),
        fz=np.full((2, 4), 3000.0),
        beta_std=np.zeros(2),
        mu_std=np.zeros((2, 4)),
    )
    controller(np.zeros(2), two, np.zeros(2), np.zeros((2, 4)))
    three = Estimate(*(np.concatenate([field, field[:1]]) for field in two))
    with pytest.raises(ValueError, match="steers 2 vehicles, not 3: reset"):
        controller(np.zeros(3), three, np.zeros(3), np.zeros((3, 4)))
    controller.reset()
    assert controller(np.zeros(3), three, np.zeros(3), np.zeros((3, 4))).torques.shape == (3, 4)
    with pytest.raises(ValueError, match=r"'front_steer': \(1,\)"):  # (not read past its end)
        controller(np.zeros(3), three, np.zeros(1), np.zeros((3, 4)))
    with pytest.raises(ValueError, match=r"'base_torques': \(12,\)"):
        controller(np.zeros(3), three, np.zeros(3), np.zeros(12))
    with pytest.raises(AttributeError):  # frozen: the compiled step reads the fields as its settings
        controller.mu_margin = 0.0
    assert LQRYawController(P).gain(20.0).shape == (3,) and LQRYawController(P).gain(np.ones((2, 2))).shape == (2, 2, 3)


def test_a_failed_dyc_call_changes_nothing():
    """A bad estimate (a negative wheel load on the second of three cars) raises the allocator's
    ValueError naming it and leaves the controller as it was: the same next command."""
    controller = StabilityController(P)
    est = Estimate(
        u=np.full(3, 20.0),
        v=np.zeros(3),
        beta=np.zeros(3),
        r=np.array([0.1, 0.2, 0.3]),
        ax=np.zeros(3),
        ay=np.zeros(3),
        mu=np.ones((3, 4)),
        fz=np.full((3, 4), 3000.0),
        beta_std=np.zeros(3),
        mu_std=np.zeros((3, 4)),
    )
    front = np.full(3, 0.02)
    controller(np.zeros(3), est, front, np.zeros((3, 4)))
    before = controller.last_allocation
    bad = est._replace(fz=np.where(np.arange(3)[:, None] == 1, -10.0, est.fz))
    with pytest.raises(ValueError, match=r"wheel loads must be >= 0 N, got \[-10\."):
        controller(np.zeros(3), bad, front, np.zeros((3, 4)))
    for a, b in zip(controller.last_allocation, before):
        np.testing.assert_array_equal(a, b)
    again = StabilityController(P)
    again(np.zeros(3), est, front, np.zeros((3, 4)))
    np.testing.assert_array_equal(
        controller(np.zeros(3), est, front, np.zeros((3, 4))).torques,
        again(np.zeros(3), est, front, np.zeros((3, 4))).torques,
    )
    assert set(CONTROLLERS) >= {"none", "dyc-lqr", "dyc-smc"}
    with pytest.raises(ValueError, match="-0.01"):
        StabilityController(P, reference_understeer=-0.01)
    for bad, named in (
        ({"dt": 0.0}, "dt must be .*, got 0.0"),
        ({"dt": "x"}, "got 'x'"),
        ({"friction_ellipse": "yes"}, "friction_ellipse must be True or False, got 'yes'"),
        ({"params": None}, "params must be vehicle parameters"),
    ):
        with pytest.raises(ValueError, match=named):
            StabilityController(**({"params": P} | bad))
    with pytest.raises(ValueError, match="controller must be a name .*, got None"):
        make_controller(None, P)
    # the DYC's settings through make_controller, named when wrong
    controller = make_controller("dyc-smc-4ws", P, mu_margin=0.0, friction_ellipse=True)
    assert (controller.law, controller.rear_steer, controller.mu_margin, controller.friction_ellipse) == (
        "smc",
        True,
        0.0,
        True,
    )
    for kwargs, named in (
        ({"mu_margin": "1"}, "mu_margin must be a finite number >= 0, got '1'"),
        ({"gain": 2.0}, r"unknown controller option\(s\) \['gain'\]"),
    ):
        with pytest.raises(ValueError, match=named):
            make_controller("dyc-lqr", P, **kwargs)
    with pytest.raises(ValueError, match="are the DYC controllers'"):
        make_controller("none", P, mu_margin=0.0)


def test_a_reference_understeer_gradient_lowers_the_yaw_reference_the_controller_tracks():
    """StabilityController(reference_understeer=K): the reference u delta / (L + K u^2); with
    2 deg/g at 25 m/s it asks for L / (L + K u^2) of the neutral car's yaw rate."""
    k = math.radians(2.0) / GRAVITY
    u, delta = np.array([25.0]), np.array([0.01])
    est = Estimate(
        u=u,
        v=np.zeros(1),
        beta=np.zeros(1),
        r=np.zeros(1),
        ax=np.zeros(1),
        ay=np.zeros(1),
        mu=np.ones((1, 4)),
        fz=np.full((1, 4), 3000.0),
        beta_std=np.zeros(1),
        mu_std=np.zeros((1, 4)),
    )
    ratio = P.wheelbase / (P.wheelbase + k * 25.0**2)
    neutral, under = StabilityController(P), StabilityController(P, reference_understeer=k)
    for c in (neutral, under):
        c(np.zeros(1), est, delta, np.zeros((1, 4)))
    assert under.reference[0] == pytest.approx(ratio * neutral.reference[0], rel=1e-12)


@pytest.mark.parametrize("law", ["lqr", "smc"])
def test_4ws_variants_add_the_eq20_rear_steer_and_the_plain_ones_do_not(law):
    from fourwis.control.reference import rear_steer_feedforward
    from fourwis.envs.layout import NU
    from fourwis.envs.simulation import truth_of
    from fourwis.envs.vehicle import derivatives, initial_state

    state = initial_state(P, np.array([10.0, 25.0]), 2)
    aux = derivatives(state, np.zeros((2, NU)), np.full((2, 4), 0.9), P)[1]
    estimate = truth_of(state, aux)[1]
    front = np.array([0.02, 0.02])
    base = np.full((2, 4), 50.0)
    controller = make_controller(f"dyc-{law}-4ws", P)
    first = controller(np.zeros(2), estimate, front, base)
    target = rear_steer_feedforward(estimate.u, front, P)
    # the rear angle moves at the servo's rate limit towards the eq. 20 angle, then holds it
    np.testing.assert_allclose(first.rear_steer, np.sign(target) * P.rear_steer_rate * controller.dt)
    for _ in range(30):
        with_4ws = controller(np.zeros(2), estimate, front, base)
    plain = make_controller(f"dyc-{law}", P)(np.zeros(2), estimate, front, base)
    np.testing.assert_allclose(with_4ws.rear_steer, target)
    assert with_4ws.rear_steer[0] * with_4ws.rear_steer[1] < 0  # opposite phase slow, same phase fast
    np.testing.assert_array_equal(plain.rear_steer, 0.0)


def test_the_yaw_reference_is_bounded_by_the_weaker_axle_s_friction():
    """A steady turn needs both axles: the controller's reference is bounded by 0.85 mu g / u with
    mu the lower axle mean, not the four wheels' mean (equal on a road split left / right)."""
    np.testing.assert_allclose(
        weaker_axle_friction(np.array([[0.1, 0.1, 0.9, 0.9], [0.3, 0.9, 0.3, 0.9], [0.8, 0.8, 0.2, 0.4]])),
        [0.1, 0.6, 0.3],
    )
    u, delta = np.array([20.0]), np.array([0.05])  # the steady state asks for ~0.37 rad/s: friction-bounded

    def reference(mu):
        est = Estimate(
            u=u,
            v=np.zeros(1),
            beta=np.zeros(1),
            r=np.zeros(1),
            ax=np.zeros(1),
            ay=np.zeros(1),
            mu=np.array([mu]),
            fz=np.full((1, 4), 3000.0),
            beta_std=np.zeros(1),
            mu_std=np.zeros((1, 4)),
        )
        controller = StabilityController(P)
        controller(np.zeros(1), est, delta, np.zeros((1, 4)))
        return controller.reference[0]

    front_on_ice = reference([0.1, 0.1, 0.9, 0.9])
    assert front_on_ice == pytest.approx(0.85 * 0.1 * GRAVITY / 20.0, rel=1e-12)
    assert reference([0.9, 0.9, 0.1, 0.1]) == pytest.approx(front_on_ice, rel=1e-12)
    assert reference([0.1, 0.9, 0.1, 0.9]) == pytest.approx(0.85 * 0.5 * GRAVITY / 20.0, rel=1e-12)


def test_the_dyc_with_the_truth_does_not_slide_the_car_onto_an_icy_patch():
    """mu_jump onto a 0.1 patch (8 s): the car arrives yawing at 13 deg/s, ~4x what ice holds.
    Bounded by the four wheels' mean friction while only the front axle was on the patch, the
    reference had asked the rear (still on 0.9) to turn the car further in, and the car then slid
    to 4.7 deg with DYC-LQR on the oracle (0.9 uncontrolled). Now its peak stays within a quarter
    above the ice's sideslip bound of ESC practice (atan(0.02 mu g) = 1.1 deg; 1.2 deg measured)."""
    scenario = make_scenario("mu_jump", mu_patch=0.1, duration=8.0)
    traj = simulate(scenario, "dyc-lqr", "oracle", seed=0)
    assert np.max(np.abs(traj.truth.beta)) < 1.25 * math.atan(0.02 * 0.1 * GRAVITY)  # (1.1 deg; not the code's bound)


def test_the_controller_reports_what_the_wheels_delivered():
    """A car yawing too little on ice: the LQR asks for a moment the tyres cannot give;
    ``last_allocation`` flags it and reports the (smaller, same-sign) moment the torques make,
    while on a dry road the same demand is met."""
    from fourwis.envs.layout import NU, S_R, S_U
    from fourwis.envs.simulation import truth_of
    from fourwis.envs.vehicle import derivatives, initial_state

    state = initial_state(P, np.array([20.0, 20.0]), 2)
    mu, front = np.array([[0.1] * 4, [1.0] * 4]), np.array([0.02, 0.02])
    state[:, S_R] = reference_yaw_rate(state[:, S_U], front, mu, P) - 0.06  # 0.06 rad/s short of the reference
    estimate = truth_of(state, derivatives(state, np.zeros((2, NU)), mu, P)[1])[1]
    controller = make_controller("dyc-lqr", P)
    assert controller.last_allocation is None
    command = controller(np.zeros(2), estimate, front, np.zeros((2, 4)))
    delivered = controller.last_allocation
    # the moment reported is the one the torques make: wheel forces T / R along each wheel's
    # heading (fronts steered by ``front``), about the CG (x forward, y left)
    x = np.array([P.cg_to_front, P.cg_to_front, -P.cg_to_rear, -P.cg_to_rear])
    y = np.array([P.track_front, -P.track_front, P.track_rear, -P.track_rear]) / 2
    delta = np.column_stack([front, front, np.zeros(2), np.zeros(2)])
    made = np.sum(command.torques / P.wheel_radius * (x * np.sin(delta) - y * np.cos(delta)), axis=1)
    np.testing.assert_allclose(delivered.yaw_moment, made, rtol=1e-9)
    assert delivered.yaw_moment[0] > 0 and not delivered.feasible[0]  # ice: what the tyres allow
    assert delivered.feasible[1] and delivered.yaw_moment[1] > delivered.yaw_moment[0]
    np.testing.assert_allclose(delivered.drive_force, 0.0, atol=1e-6)


@pytest.mark.parametrize("name", ["dyc-lqr", "dyc-smc"])
def test_dyc_with_the_oracle_passes_sine_with_dwell_across_the_series(name):
    """The issue: DYC with the oracle passes sine with dwell at every amplitude on mu 1.0. Every
    5th amplitude of the series from 1.5A, 5.5A and the last (270 deg), both directions (the
    whole series passes 62 / 62: README); at 5.5A the uncontrolled car spins (tests/test_metrics.py)."""
    A = characterise()
    series = amplitudes(A)
    chosen = np.unique(np.r_[series[::5], 5.5 * A, series[-1]])
    runs = run_series(A, mu=1.0, amplitude_list=chosen, controller_factory=lambda: make_controller(name, P))
    assert len(runs) == 2 * len(chosen) >= 14
    failed = [(math.degrees(r.amplitude), r.direction) for r in runs if not r.result.passed or r.result.spun_out]
    assert not failed
    assert max(r.peak_sideslip for r in runs if math.isclose(r.amplitude, 5.5 * A)) < math.radians(5.0)


def test_the_controller_plans_with_the_lower_confidence_bound_of_the_friction():
    one = np.ones(1)
    estimate = Estimate(
        u=20 * one,
        v=0 * one,
        beta=0 * one,
        r=0 * one,
        ax=0 * one,
        ay=0 * one,
        mu=np.array([[0.8, 0.8, 0.3, 0.3]]),
        fz=np.full((1, 4), 2000.0),
        beta_std=0 * one,
        mu_std=np.array([[0.1, 0.0, 0.25, 0.0]]),
    )
    np.testing.assert_allclose(StabilityController(P, mu_margin=1.0).planning_mu(estimate), [[0.7, 0.8, 0.1, 0.3]])
    assert MIN_PLANNING_MU == 0.1
    # the margin stops at the floor but does not lift a friction already below it (an oracle on ice)
    ice = estimate._replace(mu=np.array([[0.05, 0.05, 0.12, 0.3]]), mu_std=np.array([[0.0, 0.02, 0.05, 0.0]]))
    np.testing.assert_allclose(StabilityController(P, mu_margin=1.0).planning_mu(ice), [[0.05, 0.05, 0.1, 0.3]])
    np.testing.assert_array_equal(StabilityController(P, mu_margin=0.0).planning_mu(estimate), estimate.mu)
    with pytest.raises(ValueError, match="mu_margin must be .*, got -1.0"):
        StabilityController(P, mu_margin=-1.0)
    # closed loop: on a road more slippery than the nominal mu the estimator starts from (the
    # step, 0.3 against 0.8), the margin holds the sideslip lower where mu_hat reads above the
    # road: joint-paper's (0.32-0.34 at the peak) with every sensor-noise draw (measured
    # 2026-12-07: peak 0.479 deg with the margin against 0.496-0.571 without). joint (record
    # 0045) reads the road itself (0.30-0.31 at the peak), so there the margin only plans below
    # it (0.457 against 0.421 deg: it is left out); without the margin joint's peak is below
    # joint-paper's with it: an estimate that reads the road does what the margin stands in for.
    for seed in range(3):
        peaks = []
        for margin in (0.0, 1.0):
            controller = StabilityController(P, "lqr", mu_margin=margin)  # what make_controller("dyc-lqr") builds
            traj = simulate("paper_step", controller=controller, estimator="joint-paper", seed=seed)
            peaks.append(np.abs(traj.truth.beta).max())
        assert peaks[1] < peaks[0], seed
        joint = simulate(
            "paper_step", controller=StabilityController(P, "lqr", mu_margin=0.0), estimator="joint", seed=seed
        )
        after = joint.t >= 6.0  # (a second after the step)
        assert np.max(np.abs(joint.estimate.mu[after].mean(axis=1) - 0.3)) < 0.05, seed
        assert np.abs(joint.truth.beta).max() < peaks[1], seed


def test_sliding_mode_meets_sideslip_with_the_lqr_gains_sign():
    """A car sliding out of a left turn (beta < 0, yaw rate on its reference) needs a clockwise
    moment, as the LQR's optimal gain gives; the sliding surface s = e - lam beta agrees."""
    u, beta, r = np.array([22.0]), np.array([-0.05]), np.array([0.2])
    lqr = LQRYawController(P, LQRWeights())
    smc = SlidingModeYawController(P)
    front, rear = np.array([0.02]), np.zeros(1)
    assert lqr.moment(u, beta, r, r)[0] < 0.0
    assert (
        smc.moment(u, beta, r, r, front, rear, 0.002, np.ones((1, 4)), previous_ref=r)[0]
        < smc.moment(u, np.zeros(1), r, r, front, rear, 0.002, np.ones((1, 4)), previous_ref=r)[0]
    )


def test_sliding_mode_sees_the_rear_steer_angle():
    """On the 2-DOF model in steady state with the eq. 20 rear angle (yaw rate on its reference,
    sideslip at the model's steady value), the sliding-mode moment is ~0, as for the
    front-steered car in its own steady state. A law blind to the rear angle takes the rear
    tyre's moment b C_r delta_r for a disturbance and cancels it (such a law spun dyc-smc-4ws
    on a 90 km/h step, peak sideslip 67 deg)."""
    from fourwis.control.reference import rear_steer_feedforward

    u, front = np.array([25.0]), np.array([0.02])
    rear = rear_steer_feedforward(u, front, P)
    A, _ = bicycle_matrices(float(u[0]), P)
    c_f, c_r = P.axle_cornering_stiffness
    E = np.array(
        [
            [c_f / (P.mass * u[0]), c_r / (P.mass * u[0])],
            [P.cg_to_front * c_f / P.yaw_inertia, -P.cg_to_rear * c_r / P.yaw_inertia],
        ]
    )
    beta, r = -np.linalg.solve(A, E @ np.array([front[0], rear[0]]))  # the 4WS car's steady state
    smc = SlidingModeYawController(P, lam=0.0)
    mu = np.full((1, 4), 1.0)
    moments = []
    for rear_seen in (rear, np.zeros(1)):  # (the reference held: its rate is 0)
        moment = smc.moment(u, np.array([beta]), np.array([r]), np.array([r]), front, rear_seen, 0.002, mu, r)[0]
        moments.append(moment)
    assert abs(moments[0]) < 1.0
    # blind to it, the law cancels the rear tyre's moment b C_r delta_r (827 N m here)
    assert moments[1] == pytest.approx(-P.cg_to_rear * c_r * rear[0], rel=1e-9)
    assert abs(moments[1]) > 500.0


def test_sliding_mode_asks_nothing_of_a_car_on_its_reference_inside_the_deadbands():
    """With the shrunk sideslip 0 and the yaw rate on its reference (a steady 0.43 g turn at 80
    km/h, neutral steer) the moment is 0, as the LQR's (the linear model's beta_dot at beta = 0
    had given -67 N m)."""
    smc = SlidingModeYawController(P)
    u = np.array([22.2])
    delta = 0.43 * GRAVITY * P.wheelbase / u**2
    r_ref = u * delta / P.wheelbase
    moment = smc.moment(u, np.zeros(1), r_ref, r_ref, delta, np.zeros(1), 0.002, np.ones((1, 4)), r_ref)
    np.testing.assert_array_equal(moment, 0.0)
    pushed = smc.moment(u, np.zeros(1), r_ref + 0.1, r_ref, delta, np.zeros(1), 0.002, np.ones((1, 4)), r_ref)
    assert pushed[0] < -0.5 * P.yaw_inertia


def test_sliding_mode_never_pushes_away_from_its_surface_outside_the_boundary_layer():
    """At full right lock (delta -0.6 rad) with the car going straight (r 0 against a reference of
    -0.47 rad/s: s = +0.47, far outside the boundary layer) the linear axle model, clipped at mu Fz,
    predicts a front force the saturated, braked tyre does not have (ISO 3888-2 at 70 km/h: -4.1 kN
    modelled, -1.1 kN in the plant). Cancelling it with a reaching rate eta of 1 rad/s^2 gave +3.4 kN m,
    the sign of s: the car held r ~ 0 at full lock for 4 s and left the course 5.6 m off the line."""
    smc = SlidingModeYawController(P)
    u, r_ref, front, rear, mu = np.array([17.0]), np.array([-0.47]), np.array([-0.6]), np.zeros(1), np.ones((1, 4))
    moment = smc.moment(u, np.zeros(1), np.zeros(1), r_ref, front, rear, 0.002, mu, r_ref)[0]  # (r_ref held)
    assert moment < 0.0  # turns the car towards its reference
    assert moment == pytest.approx(-P.yaw_inertia * smc.eta)


def test_dyc_smc_keeps_the_car_steerable_on_iso3888_2_at_70_kph():
    """Closed loop with the oracle: the car follows the lane change (path within 2 m of the line;
    before the guard above: 3.2 m RMS, 5.6 m at most, yaw-rate RMS error 21 deg/s)."""
    from fourwis.envs.scenarios import make_scenario
    from fourwis.training.compare import run_metrics

    metrics = run_metrics(simulate(make_scenario("iso3888_2", speed_kph=70.0), "dyc-smc", "oracle"))
    assert metrics["path_max"] < 2.0 and not metrics["spin_out"]
    assert metrics["yaw_tracking_rms"] < math.radians(10.0)


def test_the_lqr_subtracts_the_moment_the_wheels_already_deliver():
    """Mz = -K [beta, r - r_ref, M]: the moment M the wheels deliver (a first-order lag tau(u)
    behind the command, :func:`delivered_next`) lowers the next command by K_M M. K_M > 0 at every
    speed: a moment still building up in the tyres is not asked for again (the lag-aware design)."""
    from fourwis.control.dyc import actuator_lag, delivered_next

    lqr = LQRYawController(P)
    assert np.all(lqr.gains[:, 2] > 0.0)
    u, beta, r, r_ref, dt = np.array([20.0]), np.array([-0.01]), np.array([0.25]), np.array([0.2]), 0.002
    k = lqr.gain(u)[0]
    before = lqr.moment(u, beta, r, r_ref)[0]
    assert before == pytest.approx(-(k[0] * beta[0] + k[1] * (r - r_ref)[0]), rel=1e-12)
    given, tau = 1000.0, float(actuator_lag(u, P)[0])  # 30 ms at 72 km/h
    delivered = delivered_next(np.zeros(1), np.array([given]), actuator_lag(u, P), dt)  # dt / tau of the way
    after = lqr.moment(u, beta, r, r_ref, delivered)[0]
    assert after == pytest.approx(before - k[2] * given * dt / tau, rel=1e-9)
    assert after < before
    for _ in range(int(20 * tau / dt)):  # held for 20 time constants: the wheels deliver all of it
        delivered = delivered_next(delivered, np.array([given]), actuator_lag(u, P), dt)
    assert lqr.moment(u, beta, r, r_ref, delivered)[0] == pytest.approx(before - k[2] * given, rel=1e-6)


def test_sliding_mode_switching_is_proportional_to_s_inside_the_boundary_layer():
    """Mz = I_z (equivalent - eta sat(s / phi)): with the state and steering held (the same model
    terms) and only r_ref moved, the moment changes by -I_z eta s / phi for |s| <= phi, linearly
    (s = phi / 4 gives half the change of phi / 2: no chattering), and no further beyond."""
    smc = SlidingModeYawController(P)
    u, beta, r, front, rear = np.array([22.0]), np.zeros(1), np.array([0.2]), np.array([0.02]), np.zeros(1)
    mu = np.ones((1, 4))

    def moment(s):  # beta = 0: s = r - r_ref, held (r_ref_dot = 0)
        return smc.moment(u, beta, r, r - s, front, rear, 0.002, mu, r - s)[0]

    on_surface = moment(0.0)
    assert abs(on_surface) < smc.max_moment - 2 * P.yaw_inertia * smc.eta  # the moment limit is out of the way
    for fraction in (0.25, 0.5, -0.25, -0.5, 1.0):
        assert moment(fraction * smc.phi) - on_surface == pytest.approx(-P.yaw_inertia * smc.eta * fraction, rel=1e-9)
    for side in (1.0, -1.0):  # beyond the layer the switching term is saturated: no further change
        assert moment(2.0 * side * smc.phi) == moment(3.0 * side * smc.phi)


def test_only_a_moment_that_turns_the_car_further_fades_near_the_sideslip_bound():
    """At |beta| = 0.9 of the sideslip bound, the law's moment that turns the car further into the
    bend (an understeering car, r short of r_ref: same sign as r_ref) is scaled by
    1 - |beta| / bound = 0.1; the counter-moment to an oversteering car (r beyond r_ref) is delivered
    in full, as at beta = 0; beyond STABLE_SIDESLIP (0.6) of the bound the sideslip moment
    (SIDESLIP_GAIN times the sideslip past it, against the slide) adds to either. Both turns, mu 1
    (moments well within what the tyres give)."""
    u, front, mu = np.full(8, 20.0), np.repeat([0.02, -0.02], 4), np.ones((8, 4))
    r_ref = reference_yaw_rate(u, front, mu, P)  # the lagged reference starts on the steady state
    bound = sideslip_bound(mu)
    # per turn: (yaw-rate error, |beta| / bound) for oversteer and understeer at 0 and 0.9 of the bound;
    # the sideslip is the sliding-out kind (against the turn)
    error = np.tile([0.03, 0.03, -0.03, -0.03], 2) * np.sign(r_ref)
    share = np.tile([0.0, 0.9, 0.0, 0.9], 2)
    beta = -np.sign(r_ref) * share * bound
    est = Estimate(
        u=u,
        v=u * np.tan(beta),
        beta=beta,
        r=r_ref + error,
        ax=np.zeros(8),
        ay=np.zeros(8),
        mu=mu,
        fz=np.full((8, 4), P.mass * GRAVITY / 4),
        beta_std=np.zeros(8),
        mu_std=np.zeros((8, 4)),
    )
    # what the law asks for: LQR on the state shrunk by the deadbands (0.02 rad/s, half the bound)
    from fourwis.control import YAW_DEADBAND

    shrunk_error = np.sign(error) * (np.abs(error) - YAW_DEADBAND)
    shrunk_beta = np.sign(beta) * np.maximum(np.abs(beta) - 0.5 * bound, 0.0)
    asked = LQRYawController(P).moment(u, shrunk_beta, r_ref + shrunk_error, r_ref)
    oversteer = np.sign(error) == np.sign(r_ref)
    assert np.all(np.sign(asked) == np.where(oversteer, -1.0, 1.0) * np.sign(r_ref))
    assert np.all((200.0 < np.abs(asked)) & (np.abs(asked) < 1000.0))
    controller = StabilityController(P)
    controller(np.zeros(8), est, front, np.zeros((8, 4)))
    delivered = controller.last_allocation
    assert np.all(delivered.feasible)
    from fourwis.control.reference import SIDESLIP_GAIN, STABLE_SIDESLIP

    beyond = beta - np.clip(beta, -STABLE_SIDESLIP * bound, STABLE_SIDESLIP * bound)
    held = SIDESLIP_GAIN * beyond
    assert np.all(np.sign(held[share > 0]) == -np.sign(r_ref[share > 0]))  # against the slide out of the turn
    np.testing.assert_allclose(
        delivered.yaw_moment, np.where(oversteer, 1.0, 1.0 - share) * asked + held, rtol=1e-6, atol=1e-6
    )


def test_with_rear_steer_the_reference_is_the_four_wheel_steered_car_s():
    """dyc-lqr-4ws asks for the yaw rate of the car as steered (front minus the eq. 20 rear
    angle), so at steady state it leaves the 4WS law alone instead of cancelling it; and a
    scenario that adds eq. 20 itself cannot be combined with it."""
    from fourwis.control.reference import rear_steer_feedforward
    from fourwis.envs.scenarios import make_scenario

    controller = make_controller("dyc-lqr-4ws", P)
    u, delta = np.array([22.0]), np.array([0.02])
    est = Estimate(
        u=u,
        v=np.zeros(1),
        beta=np.zeros(1),
        r=np.zeros(1),
        ax=np.zeros(1),
        ay=np.zeros(1),
        mu=np.ones((1, 4)),
        fz=np.full((1, 4), 3000.0),
        beta_std=np.zeros(1),
        mu_std=np.zeros((1, 4)),
    )
    rear = rear_steer_feedforward(u, delta, P)
    steady = reference_yaw_rate(u, delta - rear, np.ones((1, 4)), P)
    controller(np.zeros(1), est._replace(r=steady), delta, np.zeros((1, 4)))
    for _ in range(2000):  # the reference's lag settles on the steady state; the car on it needs no moment
        command = controller(np.zeros(1), est._replace(r=steady), delta, np.zeros((1, 4)))
    assert abs(controller.last_allocation.yaw_moment[0]) < 1.0 and command.rear_steer[0] == rear[0]
    with pytest.raises(ValueError, match="rear_steer_feedforward"):
        simulate(make_scenario("paper_sine", rear_steer_feedforward=True), controller)


def test_the_shipped_phase_plane_region_is_a_refit_and_grows_with_friction():
    """control/data/phase_plane.json is what training.phase_plane_fit derives (two cells refit),
    the interpolation returns the table at its nodes, and more grip means a wider band."""
    from fourwis.control.reference import PhasePlaneRegion
    from fourwis.training.phase_plane_fit import FRICTIONS, SPEEDS, fit_cell

    region = PhasePlaneRegion.default()
    for i, j in ((2, 2), (4, 4)):
        c1, c2, _ = fit_cell(SPEEDS[i], FRICTIONS[j])
        assert (region.slope[i][j], region.bound[i][j]) == pytest.approx((c1, c2), rel=1e-9)
        got = region.coefficients(np.array([SPEEDS[i]]), np.full((1, 4), FRICTIONS[j]))
        assert (got[0][0], got[1][0]) == pytest.approx((c1, c2), rel=1e-12)
    assert np.all(np.diff(np.asarray(region.bound), axis=1) > 0.0)


def test_phase_plane_fit_help_prints_usage_and_leaves_the_table_alone(monkeypatch, capsys, tmp_path):
    """``python -m fourwis.training.phase_plane_fit --help`` prints usage and exits without fitting (the
    fit takes minutes and overwrites control/data/phase_plane.json); unknown arguments are
    refused; a plain run still fits and writes the table."""
    import fourwis.training.phase_plane_fit as phase_plane_fit

    monkeypatch.setattr(phase_plane_fit, "fit_table", lambda *a, **k: pytest.fail("--help ran the fit"))
    with pytest.raises(SystemExit) as exit_info:
        phase_plane_fit.main(["--help"])
    assert exit_info.value.code == 0 and "usage: python -m fourwis.training.phase_plane_fit" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:
        phase_plane_fit.main(["--bogus"])
    assert exit_info.value.code == 2 and "--bogus" in capsys.readouterr().err
    monkeypatch.setattr(phase_plane_fit, "fit_table", lambda: {"slope": [[1.0]]})
    monkeypatch.setattr(phase_plane_fit, "OUTPUT", tmp_path / "phase_plane.json")
    phase_plane_fit.main([])
    assert '"slope"' in (tmp_path / "phase_plane.json").read_text()


@pytest.mark.parametrize("u, mu", [(20.0, 0.5), (15.0, 0.3), (30.0, 1.0)])
def test_the_phase_plane_band_separates_recovery_from_spin_on_the_full_plant(u, mu):
    """Started with the steering straight and no torque, the full plant (load transfer, wheel
    dynamics, tyre lag: not the 2-DOF model the band was derived on) recovers from 3 and 6 deg of
    sideslip at 0.8 of the band's half-width on the spin side, and from 3 deg it spins
    (|beta| > 20 deg) at 1.2: the band is close to the boundary there. (From 6 deg at 15 m/s on
    mu 0.3 it also recovers at 1.2: the band is conservative, as its fit intends.) Mirror-symmetric."""
    from scipy.optimize import brentq

    from fourwis.control.reference import PhasePlaneRegion
    from fourwis.envs.layout import NU, S_R, S_U, S_V
    from fourwis.envs.road import uniform
    from fourwis.envs.vehicle import initial_state, step
    from fourwis.training.phase_plane_fit import sideslip_dynamics

    p = VehicleParams()
    region = PhasePlaneRegion.default()
    c1, c2 = (c[0] for c in region.coefficients(np.array([u]), np.full((1, 4), mu)))
    starts = [(math.radians(b), k) for b in (3.0, -3.0, 6.0, -6.0) for k in (0.8, 1.2)]
    x = initial_state(p, u, batch_size=len(starts))
    for car, (beta, k) in enumerate(starts):
        beta_rate = math.copysign(k * c2, beta) - c1 * beta  # the spin side: sideslip growing
        r = brentq(lambda r: sideslip_dynamics(np.array([beta]), np.array([r]), u, mu, p)[0][0] - beta_rate, -3, 3)
        x[car, S_V], x[car, S_R] = u * math.tan(beta), r
        index = region.index(np.array([u]), np.array([beta]), np.array([beta_rate]), np.array([r]), np.full((1, 4), mu))
        assert index[0] == pytest.approx(k)
    peak = np.zeros(len(starts))
    for _ in range(20):
        x = step(x, np.zeros((len(starts), NU)), p, uniform(mu), 0.002, 100).state
        peak = np.maximum(peak, np.abs(np.arctan2(x[:, S_V], x[:, S_U])))
    final = np.degrees(np.abs(np.arctan2(x[:, S_V], x[:, S_U])))
    for car, (beta, k) in enumerate(starts):
        if k < 1.0:
            assert final[car] < 0.5, (math.degrees(beta), k, final[car])
        elif abs(beta) < math.radians(4.0):
            assert math.degrees(peak[car]) > 20.0, (math.degrees(beta), k, math.degrees(peak[car]))
    mirrored = peak.reshape(2, 2, 2)  # (|beta|, sign, k)
    assert mirrored[:, 0] == pytest.approx(mirrored[:, 1], rel=1e-9)


@pytest.mark.parametrize("scenario", ["paper_sine", "iso3888_2"])
def test_sideslip_rate_from_the_specific_forces_matches_the_derivative_of_sideslip(scenario):
    """beta_dot from (u, v, r, ax, ay) against the numerical derivative of the plant's sideslip
    within 0.01 deg/s (measured 0.0013 on the sine steer, 0.0006 on ISO 3888-2, peaks 3.9 and
    9.9 deg/s; the constant-speed form u (ay - u r) / (u^2 + v^2) errs 0.010 and 0.14 deg/s:
    the lane change slows the car)."""
    from fourwis.control.reference import sideslip_rate
    from fourwis.envs.layout import A_AX, A_AY
    from fourwis.envs.scenarios import make_scenario

    traj = simulate(make_scenario(scenario), estimator="oracle")
    T = traj.truth
    rate = sideslip_rate(T.u, T.v, T.r, traj.aux[:, A_AX], traj.aux[:, A_AY])
    numeric = np.gradient(T.beta, traj.t)
    assert np.max(np.abs(numeric)) > math.radians(3.0)
    assert np.max(np.abs(rate - numeric)[5:-5]) < math.radians(0.01)


def test_the_phase_plane_region_refuses_bad_tables_and_mismatched_shapes():
    from fourwis.control.reference import PhasePlaneRegion

    with pytest.raises(ValueError, match="speeds"):
        PhasePlaneRegion((20.0, 10.0), (0.5, 1.0), ((1.0, 1.0), (1.0, 1.0)), ((0.1, 0.1), (0.1, 0.1)))
    with pytest.raises(ValueError, match="bound"):
        PhasePlaneRegion((10.0, 20.0), (0.5, 1.0), ((1.0, 1.0), (1.0, 1.0)), ((0.1, 0.0), (0.1, 0.1)))
    with pytest.raises(ValueError, match="slope"):
        PhasePlaneRegion((10.0, 20.0), (0.5, 1.0), ((1.0, 1.0),), ((0.1, 0.1), (0.1, 0.1)))
    with pytest.raises(ValueError, match="shape"):
        PhasePlaneRegion.default().index(np.full(3, 20.0), np.zeros(3), np.zeros(3), np.zeros(3), np.full((2, 4), 0.5))
    with pytest.raises(ValueError, match="shape"):
        PhasePlaneRegion.default().index(
            np.full(3, 20.0), np.zeros((3, 1)), np.zeros(3), np.zeros(3), np.full((3, 4), 0.5)
        )


def test_the_reference_lag_is_the_2dof_models_slower_mode_capped_for_an_oversteering_car():
    from fourwis.control.reference import MAX_YAW_TIME_CONSTANT, yaw_time_constant

    speeds = np.array([3.0, 5.56, 12.0, 22.2, 40.0])
    slower = [max(np.linalg.eigvals(bicycle_matrices(float(u), P)[0]).real) for u in speeds]
    np.testing.assert_allclose(yaw_time_constant(speeds, P), -1.0 / np.array(slower), rtol=1e-9)
    # an oversteering car (CG 1.5 m behind the front axle) above its critical speed has an
    # unstable mode: the lag stays positive and bounded instead of turning negative
    oversteer = P.replace(cg_to_front=1.5, cg_to_rear=0.84)
    lag = yaw_time_constant(np.array([22.2, 55.5]), oversteer)
    assert max(np.linalg.eigvals(bicycle_matrices(55.5, oversteer)[0]).real) > 0.0
    assert 0.0 < lag[0] < MAX_YAW_TIME_CONSTANT and lag[1] == MAX_YAW_TIME_CONSTANT


def test_simulate_takes_a_controller_by_name_as_it_takes_an_estimator():
    from fourwis.envs.scenarios import make_scenario
    from fourwis.envs.simulation import simulate

    scenario = make_scenario("paper_step", duration=1.5)
    by_name = simulate(scenario, "dyc-lqr", "joint", seed=1)
    built = simulate(scenario, make_controller("dyc-lqr", scenario.vehicle_params), "joint", seed=1)
    np.testing.assert_array_equal(by_name.controls, built.controls)
    assert np.any(by_name.controls != simulate(scenario, "none", "joint", seed=1).controls)
    for bad, match in (("pid", "'pid'"), (3, "got 3")):
        with pytest.raises(ValueError, match=match):
            simulate(scenario, bad)


def _turning(u: np.ndarray, r: float, ay: float = 0.0) -> Estimate:
    """Estimates of B cars at speeds u (B,) yawing at r [rad/s] straight ahead, on a dry road."""
    B = u.shape[0]
    return Estimate(
        u=u,
        v=np.zeros(B),
        beta=np.zeros(B),
        r=np.full(B, r),
        ax=np.zeros(B),
        ay=np.full(B, ay),
        mu=np.ones((B, 4)),
        fz=np.full((B, 4), 2000.0),
        beta_std=np.zeros(B),
        mu_std=np.zeros((B, 4)),
    )


@pytest.mark.parametrize("law", ["lqr", "smc"])
def test_the_dyc_asks_no_moment_below_its_active_speed_but_still_shares_the_drive(law):
    """Below ACTIVE_SPEED (2 m/s: slip angles mean little at walking pace) the law's moment is 0
    and the allocator only shares the driver's torque, however the car yaws; just above it a car
    yawing at 0.3 rad/s with the wheels straight (outside its stable region) gets a counter-moment
    (clockwise), and the driver's drive yields to it."""
    from fourwis.control.dyc import ACTIVE_SPEED

    controller = StabilityController(P, law=law)
    u = np.array([0.5 * ACTIVE_SPEED, 0.99 * ACTIVE_SPEED, 1.5 * ACTIVE_SPEED])
    base = np.full((3, 4), 40.0)
    command = controller(np.zeros(3), _turning(u, 0.3), np.zeros(3), base)
    moment = controller.last_allocation.yaw_moment
    np.testing.assert_array_equal(moment[:2], 0.0)
    np.testing.assert_allclose(command.torques[:2], base[:2])
    assert moment[2] < -50.0
    np.testing.assert_allclose(command.torques[2].sum(), 0.0, atol=1e-9)


def test_the_friction_ellipse_leaves_a_cornering_tyre_less_longitudinal_force():
    """friction_ellipse=True bounds each tyre's Fx by what its quasi-static lateral force
    Fz ay / g leaves of mu Fz: at ay = 0.8 g on mu 1, sqrt(1 - 0.8^2) = 0.6 of the circle. A
    moment the circle meets is cut to the ellipse's largest, 4 x 0.6 x 2 kN x half-track
    0.708 m = 3.4 kN m with no drive force asked, and flagged infeasible; a small one is met by
    both."""
    from fourwis.control.allocation import allocate_for_estimate

    estimate = _turning(np.full(2, 10.0), 0.0, ay=0.8 * GRAVITY)
    base, demand = np.zeros((2, 4)), np.array([4000.0, 500.0])
    circle = allocate_for_estimate(base, demand, estimate, P)
    ellipse = allocate_for_estimate(base, demand, estimate, P, friction_ellipse=True)
    np.testing.assert_allclose(circle.yaw_moment, demand, rtol=1e-6)
    assert circle.feasible.all()
    half_track = P.track_front / 2
    bound = 4 * 0.6 * 2000.0 * half_track
    assert not ellipse.feasible[0]
    np.testing.assert_allclose(ellipse.yaw_moment[0], bound, rtol=1e-6)
    np.testing.assert_allclose(ellipse.yaw_moment[1], 500.0, rtol=1e-6)
    assert ellipse.feasible[1]
    tyre_fx = np.abs(ellipse.torques[0]) / P.wheel_radius
    assert np.all(tyre_fx <= 0.6 * 2000.0 * (1 + 1e-6))


def test_inside_the_stable_region_a_moment_against_the_yaw_error_fades_over_the_deadband():
    """A sliding-mode DYC on a car cornering hard on mu 0.65 at 22 m/s just short of its reference
    (inside the stable region, sideslip within half its bound): the law's model term asks for a
    moment that would turn the car out of the bend, away from the reference; the controller scales
    it by 1 - |r - r_ref| / YAW_DEADBAND, to nothing at the deadband, and lets a moment towards the
    reference through whole."""
    from fourwis.control import YAW_DEADBAND
    from fourwis.control.dyc import SlidingModeYawController

    u, front, mu = np.full(3, 22.0), np.full(3, 0.088), np.full((3, 4), 0.65)
    r_ref = reference_yaw_rate(u, front, mu, P)  # (the lagged reference starts on the steady state)
    error = np.array([-0.25, -1.5, 0.5]) * YAW_DEADBAND  # short of it twice, then past it
    est = Estimate(
        u=u, v=np.zeros(3), beta=np.zeros(3), r=r_ref + error, ax=np.zeros(3), ay=np.zeros(3), mu=mu,
        fz=np.full((3, 4), P.mass * GRAVITY / 4), beta_std=np.zeros(3), mu_std=np.zeros((3, 4)),
    )  # fmt: skip
    shrunk = np.sign(error) * np.maximum(np.abs(error) - YAW_DEADBAND, 0.0)
    asked = SlidingModeYawController(P).moment(u, 0.0, r_ref + shrunk, r_ref, front, 0.0, 0.002, mu)
    assert np.all(asked < -100.0)  # the model's phantom yaw acceleration, cancelled: out of the bend
    controller = StabilityController(P, law="smc")
    controller(np.zeros(3), est, front, np.zeros((3, 4)))
    delivered = controller.last_allocation.yaw_moment
    np.testing.assert_allclose(delivered[0], asked[0] * 0.75, rtol=1e-6)  # against the error: faded
    assert delivered[1] == 0.0  # beyond the deadband against the error: none
    np.testing.assert_allclose(delivered[2], asked[2], rtol=1e-6)  # towards the reference: whole

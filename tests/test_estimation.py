"""Estimation: CKF maths (exact on linear systems, SPD covariance, robust to outliers), federated
fusion, the estimation model's physics, and estimator accuracy on the paper's scenarios."""

import math

import numpy as np
import pytest

from fourwis.core.types import CHANNELS
from fourwis.envs.layout import A_USAGE
from fourwis.envs.metrics import rmse
from fourwis.envs.scenarios import PAPER_SCENARIOS, make_scenario
from fourwis.envs.sensors import N_SENSORS, Fault, SensorParams
from fourwis.envs.simulation import simulate
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation import ESTIMATORS, make_estimator
from fourwis.estimation.ckf import ckf_predict, ckf_update
from fourwis.estimation.federated import BETA_FLOOR, SubMeasurement, federated_step, fuse, sharing_coefficients
from fourwis.estimation.joint import SLIDE_RATE, YAW_BALANCE_STD, ZERO_POINT_TIME_CONSTANT, ZP_OFFSET, StateEstimator
from fourwis.estimation.model import GRAVITY, Inputs, ModelParams, dugoff, normal_loads, state_transition

RNG = np.random.default_rng(0)
F_LIN = np.array([[1.0, 0.1], [0.0, 0.95]])
H_LIN = np.array([[1.0, 0.0]])


def kalman(x, P, z, Q, R):
    x, P = F_LIN @ x, F_LIN @ P @ F_LIN.T + Q
    S = H_LIN @ P @ H_LIN.T + R
    K = P @ H_LIN.T @ np.linalg.inv(S)
    return x + K @ (z - H_LIN @ x), P - K @ S @ K.T


def test_ckf_equals_the_kalman_filter_on_a_linear_system():
    Q, R = np.diag([0.01, 0.02]), np.array([[0.5]])
    x, P = np.array([[1.0, -1.0]]), np.eye(2)[None] * 2.0
    xk, Pk = x[0].copy(), P[0].copy()
    for z in RNG.normal(size=50):
        x, P = ckf_predict(x, P, lambda pts: pts @ F_LIN.T, Q)
        upd = ckf_update(x, P, np.array([[z]]), lambda pts: pts @ H_LIN.T, R)
        x, P = upd.x, upd.P
        xk, Pk = kalman(xk, Pk, np.array([z]), Q, R)
    np.testing.assert_allclose(x[0], xk, atol=1e-9)
    np.testing.assert_allclose(P[0], Pk, atol=1e-9)


def _turn(x, dt=0.1):
    px, py, speed, heading, turn = np.moveaxis(np.asarray(x), -1, 0)
    return np.stack(
        [px + speed * np.cos(heading) * dt, py + speed * np.sin(heading) * dt, speed, heading + turn * dt, turn],
        axis=-1,
    )


def _range_bearing(x):
    px, py = np.asarray(x)[..., 0], np.asarray(x)[..., 1]
    return np.stack([np.hypot(px, py), np.arctan2(py, px)], axis=-1)


def test_ckf_equals_filterpy_ukf_with_cubature_weights_on_a_nonlinear_system():
    """A UKF with alpha = 1, beta = 0, kappa = 0 has no centre weight and 1/2n on +/- sqrt(n)
    columns of chol(P): the cubature rule. filterpy 1.4's UKF redraws its sigma points from the
    predicted (x, P) before the update, as the CKF does, so the two must agree on a nonlinear
    model (coordinated turn, range-bearing measurements)."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    def fx(x, dt=0.1):
        return _turn(x, dt)

    hx = _range_bearing
    Q, R = np.diag([0.01, 0.01, 0.1, 0.01, 0.05]), np.diag([0.3, 0.01])
    ukf = UnscentedKalmanFilter(5, 2, 0.1, hx, fx, MerweScaledSigmaPoints(5, alpha=1.0, beta=0.0, kappa=0.0))
    ukf.x, ukf.P, ukf.Q, ukf.R = np.array([10.0, 5.0, 3.0, 0.4, 0.2]), np.diag([1.0, 1.0, 0.5, 0.1, 0.05]), Q, R
    x, P = ukf.x[None].copy(), ukf.P[None].copy()
    rng = np.random.default_rng(3)
    for _ in range(30):
        z = hx(ukf.x) + rng.normal(size=2) * np.sqrt(np.diag(R))
        ukf.predict()
        ukf.update(z)
        x, P = ckf_predict(x, P, fx, Q)
        upd = ckf_update(x, P, z[None], hx, R)
        x, P = upd.x, upd.P
        np.testing.assert_allclose(x[0], ukf.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(P[0], ukf.P, rtol=1e-9, atol=1e-9)


def test_ckf_is_consistent_nees_within_the_chi_square_band():
    """Monte Carlo NEES (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4): 100 runs of a noisy
    coordinated turn seen by range-bearing; at each step the mean of e^T P^-1 e over runs must
    lie in the two-sided 95% chi-square band of 100 n degrees of freedom (n = 5) on at least
    90% of the steps, and its overall mean within 10% of n."""
    from scipy.stats import chi2

    runs, n, steps = 100, 5, 60
    Q, R = np.diag([1e-3, 1e-3, 1e-2, 1e-3, 1e-3]), np.diag([0.05, 1e-4])
    rng = np.random.default_rng(11)
    P0 = np.diag([0.5, 0.5, 0.2, 0.02, 0.01])
    truth = np.array([20.0, 5.0, 5.0, 0.3, 0.1]) + rng.multivariate_normal(np.zeros(n), P0, runs)
    x, P = np.tile([20.0, 5.0, 5.0, 0.3, 0.1], (runs, 1)), np.broadcast_to(P0, (runs, n, n)).copy()
    nees = []
    for _ in range(steps):
        truth = _turn(truth) + rng.multivariate_normal(np.zeros(n), Q, runs)
        z = _range_bearing(truth) + rng.multivariate_normal(np.zeros(2), R, runs)
        x, P = ckf_predict(x, P, _turn, Q)
        upd = ckf_update(x, P, z, _range_bearing, R)
        x, P = upd.x, upd.P
        e = truth - x
        nees.append(np.mean(np.sum(e * np.linalg.solve(P, e[..., None])[..., 0], axis=1)))
    nees = np.array(nees)
    low, high = chi2.ppf([0.025, 0.975], runs * n) / runs
    assert np.mean((nees >= low) & (nees <= high)) >= 0.9, nees
    assert abs(nees.mean() - n) < 0.1 * n


def test_batched_ckf_equals_one_member_at_a_time():
    """Members of a batch do not interact: a batch of three equals three single runs to 1e-12."""
    rng = np.random.default_rng(5)
    x = np.array([[20.0, 5.0, 5.0, 0.3, 0.1], [15.0, -3.0, 4.0, -0.2, 0.0], [25.0, 8.0, 6.0, 1.0, -0.1]])
    P = np.stack([np.diag(d) for d in rng.uniform(0.01, 0.5, (3, 5))])
    Q, R = np.diag([1e-3] * 5), np.diag([0.05, 1e-4])
    z = _range_bearing(x) + rng.normal(size=(3, 2)) * 0.05
    xb, Pb = ckf_predict(x, P, _turn, Q)
    batch = ckf_update(xb, Pb, z, _range_bearing, R, huber_c=1.5)
    for i in range(3):
        xs, Ps = ckf_predict(x[i : i + 1], P[i : i + 1], _turn, Q)
        single = ckf_update(xs, Ps, z[i : i + 1], _range_bearing, R, huber_c=1.5)
        np.testing.assert_allclose(batch.x[i], single.x[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(batch.P[i], single.P[0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("huber_c", [None, 1.5])
def test_covariance_stays_symmetric_positive_definite_over_100k_steps_with_outliers(huber_c):
    """100,000 steps of a stiff two-state model (tiny Q and R) with 1% of the measurements
    replaced by 10-sigma outliers: P stays symmetric positive definite and the state finite."""
    Q, R = np.diag([1e-8, 1e-8]), np.array([[1e-6]])
    rng = np.random.default_rng(2)
    x, P = np.zeros((2, 2)), np.broadcast_to(np.eye(2), (2, 2, 2)).copy()
    noise = rng.normal(size=(100_000, 2, 1)) * 1e-3
    outlier = rng.random((100_000, 2, 1)) < 0.01
    z_all = np.where(outlier, 10e-3 * np.sign(noise), noise)
    for k, z in enumerate(z_all):
        x, P = ckf_predict(x, P, lambda pts: pts @ F_LIN.T, Q)
        upd = ckf_update(x, P, z, lambda pts: pts @ H_LIN.T, R, huber_c=huber_c)
        x, P = upd.x, upd.P
        if k % 1000 == 0:
            assert np.linalg.eigvalsh(P).min() > 0, k
    assert outlier.sum() > 1500
    np.testing.assert_array_equal(P, np.swapaxes(P, 1, 2))
    assert np.all(np.linalg.eigvalsh(P) > 0) and np.all(np.isfinite(x))


def test_a_10_sigma_spike_moves_the_robust_estimate_less_than_20_percent_of_the_plain_one():
    """With the prior tighter than the sensor (a filter in its normal, converged state), the
    Huber weight c / 10 = 0.15 inflates R so the robust update moves < 20% as far."""
    x, P = np.zeros((1, 2)), np.diag([1e-3, 1e-3])[None]
    R = np.array([[0.01]])
    z = np.array([[10 * math.sqrt(0.011)]])  # 10 sigma of the innovation
    plain = ckf_update(x, P, z, lambda pts: pts @ H_LIN.T, R)
    robust = ckf_update(x, P, z, lambda pts: pts @ H_LIN.T, R, huber_c=1.5)
    ratio = robust.x[0, 0] / plain.x[0, 0]
    assert 0.1 < ratio < 0.2  # down-weighted, not discarded
    w = 1.5 / 10  # the gains P / (P + R / w) and P / (P + R) on the observed state
    assert ratio == pytest.approx((1e-3 / (1e-3 + 0.01 / w)) / (1e-3 / (1e-3 + 0.01)), rel=1e-6)


def test_huber_update_limits_an_outlier():
    x, P = np.zeros((1, 2)), np.eye(2)[None] * 0.1
    R = np.array([[0.01]])
    z = np.array([[50 * math.sqrt(0.11)]])  # a 50-sigma outlier
    plain = ckf_update(x, P, z, lambda pts: pts @ H_LIN.T, R)
    robust = ckf_update(x, P, z, lambda pts: pts @ H_LIN.T, R, huber_c=1.5)
    w = 1.5 / 50
    assert robust.weights[0, 0] == pytest.approx(w, rel=1e-6)
    # inflated noise R / w: the gain drops from P / (P + R) to P / (P + R / w)
    assert robust.x[0, 0] == pytest.approx(0.1 / (0.1 + 0.01 / w) * z[0, 0], rel=1e-6)
    assert abs(robust.x[0, 0]) < 0.3 * abs(plain.x[0, 0])


def test_dropout_channels_carry_no_information():
    x, P = np.zeros((1, 2)), np.eye(2)[None]
    upd = ckf_update(x, P, np.array([[7.0]]), lambda pts: pts @ H_LIN.T, np.array([[0.1]]), valid=np.array([[False]]))
    np.testing.assert_allclose(upd.x, x, atol=1e-9)
    np.testing.assert_allclose(upd.P, P, atol=1e-9)


def test_fusion_is_the_information_weighted_average():
    x, P, confidence = np.empty(1), np.empty((1, 1)), np.empty(2)
    assert fuse(np.array([[1.0], [3.0]]), np.array([[[1.0]], [[3.0]]]), x, P, confidence)
    assert x[0] == pytest.approx((1.0 / 1 + 3.0 / 3) / (1 + 1 / 3))
    assert P[0, 0] == pytest.approx(0.75)
    np.testing.assert_allclose(confidence, [1.0, 1.0 / 3.0])


@pytest.mark.parametrize(
    "confidence, expected",
    [
        ([1.0, 3.0], [0.25, 0.75]),  # proportional to the confidences
        ([2.0, 1.0, 1.0], [0.5, 0.25, 0.25]),
        ([1.0, 99.0], [BETA_FLOOR / (BETA_FLOOR + 0.99), 0.99 / (BETA_FLOOR + 0.99)]),  # 1% floored at 5%, renormalised
        ([1.0, 1.0, 98.0], np.array([BETA_FLOOR, BETA_FLOOR, 0.98]) / (2 * BETA_FLOOR + 0.98)),
    ],
)
def test_sharing_coefficients_follow_the_confidences_with_a_floor_and_sum_to_one(confidence, expected):
    """beta_i = max(c_i / sum c, BETA_FLOOR), normalised to sum 1 (federated module docstring:
    a confident sub-filter gets the larger share; none falls below ~4.8%)."""
    beta = np.empty(len(confidence))
    sharing_coefficients(np.array(confidence), beta)
    np.testing.assert_allclose(beta, expected, rtol=1e-12)
    assert beta.sum() == pytest.approx(1.0, rel=1e-12) and beta.min() >= BETA_FLOOR / (1 + len(beta) * BETA_FLOOR)


def test_federated_filter_with_reset_equals_the_centralised_filter_on_a_linear_system():
    Q = np.diag([0.01, 0.02])
    H2 = np.array([[0.0, 1.0]])
    R1, R2 = np.array([[0.5]]), np.array([[0.3]])
    x, P, beta = np.zeros((1, 2)), np.eye(2)[None], np.full((1, 2), 0.5)
    xc, Pc = x.copy(), P.copy()
    for z1, z2 in RNG.normal(size=(40, 2)):
        out = federated_step(
            x,
            P,
            lambda pts: pts @ F_LIN.T,
            Q,
            [
                SubMeasurement(np.array([[z1]]), lambda pts: pts @ H_LIN.T, R1, None),
                SubMeasurement(np.array([[z2]]), lambda pts: pts @ H2.T, R2, None),
            ],
            beta,
        )
        x, P, beta = out.x, out.P, out.beta
        xc, Pc = ckf_predict(xc, Pc, lambda pts: pts @ F_LIN.T, Q)
        both = np.vstack([H_LIN, H2])
        upd = ckf_update(xc, Pc, np.array([[z1, z2]]), lambda pts: pts @ both.T, np.diag([0.5, 0.3]))
        xc, Pc = upd.x, upd.P
    np.testing.assert_allclose(x, xc, atol=1e-8)
    np.testing.assert_allclose(P, Pc, atol=1e-8)
    assert beta.sum() == pytest.approx(1.0)


PARAMS = ModelParams.from_vehicle(VehicleParams())


@pytest.mark.parametrize("group, huber_c", [("state", None), ("state", 3.0), ("mu", 3.0)])
def test_the_compiled_federated_cycle_equals_federated_step_on_the_vehicle_model(group, huber_c):
    """The estimators' compiled cycle (joint._federated: share, predict, update, fuse) is the
    one federated_step runs, model for model: both driven by the compiled vehicle models, in
    a hard turn (ay 6 m/s^2 at 20 m/s on mu 0.8), with one invalid channel."""
    from fourwis.estimation.joint import (
        MU_1,
        MU_2,
        RANDOM_WALK,
        STATE_1,
        STATE_2,
        TRANSITION,
        FrictionInputs,
        MeasurementInputs,
        ModelArgs,
        _evaluate,
        _federated,
    )  # fmt: skip
    from fourwis.estimation.model import ModelInputs, fill_steer_trig

    pk, dt = PARAMS.kernel, 0.002
    state = np.array([20.0, -0.4, -0.3, 6.0, 0.3, 0.01])  # [u, v, ax, ay, r, Gamma]
    steer = np.empty((4, 4))
    fill_steer_trig((0.06, 0.06, 0.0, 0.0), steer)
    omega, torque, omega_dot = np.full(4, 20.0 / PARAMS.wheel_radius), np.full(4, 150.0), np.zeros(4)
    mu = np.array([0.8, 0.75, 0.82, 0.8])
    args = ModelArgs(
        ModelInputs(mu, steer, omega, torque, omega_dot, pk, dt), MeasurementInputs(steer, pk),
        FrictionInputs(state, steer, omega, torque, omega_dot, pk, dt),
    )  # fmt: skip
    if group == "state":
        x, P = state, np.diag([0.3, 0.1, 0.5, 0.5, 0.01, 50.0]) ** 2
        Q, models = np.diag([0.05, 0.02, 0.3, 0.3, 0.005, 5.0]) ** 2, (TRANSITION, STATE_1, STATE_2)
        z1 = np.array([-0.2, 5.7, 0.31, *(omega * PARAMS.wheel_radius + 0.05)])
        R1, R2 = np.diag([0.05, 0.05, 0.002, 0.02, 0.02, 0.02, 0.02]) ** 2, np.diag([0.05, 0.002]) ** 2
    else:
        x, P = mu, 0.01 * (0.99 * np.ones((4, 4)) + 0.01 * np.eye(4))
        Q, models = 1e-6 * np.eye(4), (RANDOM_WALK, MU_1, MU_2)
        z1 = np.array([-0.2, 5.7, 0.31])
        R1, R2 = np.diag([0.6, 0.6, 0.002]) ** 2, np.diag([0.6, 0.002]) ** 2
    valid1 = np.ones(len(z1), dtype=bool)
    valid1[0] = False
    z2, valid2 = z1[1:3].copy(), valid1[1:3].copy()
    beta = np.array([0.6, 0.4])

    def model(code):
        def evaluate(points):  # (1, K, n) -> (1, K, k), one compiled model call
            out = np.empty((1, points.shape[1], {TRANSITION: 6, RANDOM_WALK: 4, STATE_1: 7, MU_1: 3}.get(code, 2)))
            _evaluate(code, np.ascontiguousarray(points[0]), out[0], args)
            return out

        return evaluate

    reference = federated_step(
        x[None],
        P[None],
        model(models[0]),
        Q,
        [
            SubMeasurement(z1[None], model(models[1]), R1, valid1[None]),
            SubMeasurement(z2[None], model(models[2]), R2, valid2[None]),
        ],
        beta[None],
        huber_c,
    )
    x_out, P_out, beta_out = np.empty_like(x), np.empty_like(P), np.empty(2)
    m1, m2 = len(z1), len(z2)  # (the innovations and their covariances, kept for NIS: written, not compared)
    nu1, S1, nu2, S2 = np.empty(m1), np.empty((m1, m1)), np.empty(m2), np.empty((m2, m2))
    nll = _federated(
        x,
        P,
        Q,
        beta,
        models[0],
        z1,
        valid1,
        R1,
        models[1],
        z2,
        valid2,
        R2,
        models[2],
        math.inf if huber_c is None else huber_c,
        args,
        x_out,
        P_out,
        beta_out,
        nu1,
        S1,
        nu2,
        S2,
    )
    np.testing.assert_allclose(x_out, reference.x[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(P_out, reference.P[0], rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(beta_out, reference.beta[0], rtol=1e-12)
    assert nll == pytest.approx(reference.nll.sum(), rel=1e-12)
    assert np.max(np.abs(x_out - x)) > 1e-4  # the measurements moved the estimate


def test_dugoff_is_linear_at_small_slip_and_follows_its_closed_form_in_saturation():
    """Dugoff (eps = 0, slip s positive when driving): lambda = mu Fz (1 + s) / (2 D),
    D = sqrt(Cx^2 s^2 + Cy^2 tan^2 a); for lambda >= 1 the force is linear, for lambda < 1 its
    magnitude D / (1 + s) lambda (2 - lambda) reduces to exactly mu Fz (1 - lambda / 2), in pure
    cornering and in combined slip alike; driving slip lowers the lateral force. mu
    is the friction the tyre sees: the estimator passes k mu (AxleTyre.mu_scale), as here."""
    fx, fy, lam = dugoff(2000.0, 0.0, math.tan(1e-3), 0.8, 3e4, 4e4, 20.0, 0.0)
    assert fy == pytest.approx(4e4 * math.tan(1e-3)) and fx == 0.0 and lam > 1.0
    mu, fz, cx, cy = PARAMS.front.mu_scale * 0.8, 2000.0, 3e4, 4e4
    for slip, alpha in ((0.0, 0.05), (0.0, 0.3), (0.05, 0.3), (-0.1, 0.1)):
        fx, fy, lam = dugoff(fz, slip, math.tan(alpha), mu, cx, cy, 20.0, 0.0)
        demand = math.hypot(cx * slip, cy * math.tan(alpha))
        assert lam == pytest.approx(mu * fz * (1 + slip) / (2 * demand), rel=1e-12)
        assert lam < 1.0  # saturating: every case above is past the linear range
        assert math.hypot(fx, fy) == pytest.approx(mu * fz * (1 - lam / 2), rel=1e-12)
        if slip == 0.0:
            assert fx == 0.0 and fy > 0.0
    # linear range: the lateral force Cy tan(a) / (1 + s) is smaller when driving, larger when braking
    fy = [dugoff(fz, s, math.tan(1e-3), mu, cx, cy, 20.0, 0.0)[1] for s in (1e-3, 0.0, -1e-3)]
    assert fy[0] == pytest.approx(cy * math.tan(1e-3) / 1.001, rel=1e-12) and fy[0] < fy[1] < fy[2]
    # Dugoff's speed reduction: friction mu (1 - eps u V), V = sqrt(s^2 + tan^2 a) the sliding
    # speed per unit speed (dimensionless: no stiffness inside), so lambda scales by that factor
    eps, u, slip, alpha = 0.01, 20.0, 0.05, 0.3
    plain = dugoff(fz, slip, math.tan(alpha), mu, cx, cy, u, 0.0)[2]
    reduced = dugoff(fz, slip, math.tan(alpha), mu, cx, cy, u, eps)[2]
    assert reduced == pytest.approx(plain * (1 - eps * u * math.hypot(slip, math.tan(alpha))), rel=1e-12)


@pytest.mark.parametrize(
    "params",
    [
        PARAMS,
        ModelParams.from_vehicle(VehicleParams(cg_to_front=0.95, cg_to_rear=1.39)),
        ModelParams.from_vehicle(VehicleParams(cg_to_front=1.39, cg_to_rear=0.95)),
    ],
    ids=["paper", "front_cg", "rear_cg"],
)
def test_normal_loads_follow_the_quasi_static_closed_form(params):
    """estimation.model.wheel_load: static share m g b/L (front) and m g a/L (rear), a pitch
    shift m ax h / L from the front axle to the rear, and a roll moment m ay h shared by the
    axles in proportion to their static loads (front b/L, rear a/L), each axle's left-right
    difference times half its track balancing its share; the loads sum to m g (the model's g).
    The paper's car has a = b; a CG off the middle tells a/L from b/L (the paper's eq. 14 typo)."""
    m, a, b, h = params.mass, params.cg_to_front, params.cg_to_rear, params.cg_height
    L, g = params.wheelbase, GRAVITY
    for ax, ay in ((0.0, 0.0), (-5.0, 0.0), (0.0, 4.0), (2.0, -3.0), (-3.0, 5.0)):
        fz = normal_loads(np.array(ax), np.array(ay), params)
        assert fz.sum() == pytest.approx(m * g, rel=1e-12)
        assert fz[0] + fz[1] == pytest.approx(m * g * b / L - m * ax * h / L, rel=1e-12)
        assert fz[2] + fz[3] == pytest.approx(m * g * a / L + m * ax * h / L, rel=1e-12)
        # ay > 0 (left turn) loads the right wheels (FR, RR)
        assert fz[1] - fz[0] == pytest.approx(2 * m * ay * h * (b / L) / params.track_front, rel=1e-12, abs=1e-9)
        assert fz[3] - fz[2] == pytest.approx(2 * m * ay * h * (a / L) / params.track_rear, rel=1e-12, abs=1e-9)
        roll_moment = (fz[1] - fz[0]) * params.track_front / 2 + (fz[3] - fz[2]) * params.track_rear / 2
        assert roll_moment == pytest.approx(m * ay * h, rel=1e-12, abs=1e-9)
    # beyond the inner wheels' lift-off (2 g) they are floored at 5% of their static load
    fz = normal_loads(np.array(0.0), np.array(20.0), params)
    np.testing.assert_allclose(fz[[0, 2]], [0.05 * m * g * b / (2 * L), 0.05 * m * g * a / (2 * L)], rtol=1e-12)


def test_one_state_transition_names_a_wrong_shape():
    inputs = Inputs(np.zeros(4), np.full(4, 30.0), np.zeros(4), np.zeros(4))
    x = np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    for kwargs, named in (
        ({"mu": 0.8}, r"mu must have shape \(4,\), got \(1,\)"),
        ({"inputs": inputs._replace(delta=np.zeros(2))}, r"delta must have shape \(4,\)"),
        ({"x": x[:5]}, r"x must have shape \(6,\)"),
    ):
        with pytest.raises(ValueError, match=named):
            state_transition(**({"x": x, "mu": np.full(4, 0.8), "inputs": inputs, "p": PARAMS, "dt": 0.002} | kwargs))


def test_model_yaw_rate_is_kinematic_at_low_speed():
    delta = 0.05
    inputs = Inputs(np.array([delta, delta, 0.0, 0.0]), np.full(4, 3.0 / PARAMS.wheel_radius), np.zeros(4), np.zeros(4))
    x = np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    for _ in range(3000):
        x = state_transition(x, np.full(4, 0.8), inputs, PARAMS, 0.002)
    assert x[4] == pytest.approx(3.0 * delta / PARAMS.wheelbase, rel=0.03)


#: Sideslip RMSE / RMS(truth sideslip) bound: the estimate must account for at least 3/4 of the
#: sideslip's mean square (1 - 0.5^2), where beta_hat = 0 scores 1. Measured 0.36-0.38 on the
#: sine for every estimator (seed 1), joint 0.25 / 0.36 / 0.40 on step / sine / slalom (seed 0);
#: README Table 2's 5-seed means give joint 0.26 / 0.36 / 0.41, and its worst step seed (0.19
#: deg) 0.40, so 0.5 holds with a >= 20% margin.
BETA_RELATIVE = 0.5


def _beta_errors(traj) -> tuple[float, float]:
    """(sideslip RMSE [deg], RMSE / RMS of the true sideslip)."""
    error = rmse(traj.estimate.beta, traj.truth.beta)
    return float(np.degrees(error)), float(error / np.sqrt(np.mean(traj.truth.beta**2)))


@pytest.mark.parametrize("name", ["ekf", "ckf", "fkf", "joint"])
@pytest.mark.parametrize("scenario, beta_deg", [("paper_dlc", 0.02), ("paper_sine", 0.25)])
def test_estimators_track_sideslip_and_yaw_rate(name, scenario, beta_deg):
    """Sideslip RMSE bounds: README Table 2 (5-seed means) gives 0.0087-0.0092 deg on the lane
    change, the sensor-noise floor, and 0.177-0.189 deg on the sine; measured on seed 1
    0.0077-0.0084 and 0.179-0.188. Bounds ~2x the floor and ~1.3x the sine's worst estimator.
    Both are far below the truth's own RMS sideslip (0.141 / 0.498 deg), and the relative bound
    (BETA_RELATIVE) fails a filter that reports beta = 0. Yaw rate (measured <= 0.0027 rad/s)
    and speed (<= 0.011 m/s) keep their earlier loose bounds."""
    traj = simulate(scenario, estimator=name, seed=1)
    T, E = traj.truth, traj.estimate
    beta_rmse, beta_relative = _beta_errors(traj)
    assert beta_rmse < beta_deg
    assert beta_relative < BETA_RELATIVE
    assert rmse(E.r, T.r) < 0.005
    assert rmse(E.u, T.u) < 0.05
    assert np.all(np.isfinite(E.mu))


def test_robust_filter_shrugs_off_gyro_spikes():
    """0.5 rad/s gyro spikes at 20/s for 6 s of paper_sine: alo-fkf's Huber weighting (c = 3)
    keeps the yaw-rate RMSE below 0.4 of the same filter's with the weighting off (measured 0.20:
    0.0030 against 0.0149 rad/s) and of the plain fkf's (0.078)."""
    faults = (Fault("yaw_rate", "spike", start=2.0, end=8.0, magnitude=0.5, rate=20.0),)
    robust = simulate("paper_sine", estimator="alo-fkf", seed=2, faults=faults)
    error = rmse(robust.estimate.r, robust.truth.r)
    unweighted = make_estimator("alo-fkf", VehicleParams(), huber_c=math.inf)
    for plain in (
        simulate("paper_sine", estimator=unweighted, seed=2, faults=faults),
        simulate("paper_sine", estimator="fkf", seed=2, faults=faults),
    ):
        assert error < 0.4 * rmse(plain.estimate.r, plain.truth.r)


def test_estimator_is_deterministic_under_a_seed_and_names_are_checked():
    a = simulate("paper_step", estimator="joint", seed=3).estimate.beta
    b = simulate("paper_step", estimator="joint", seed=3).estimate.beta
    np.testing.assert_array_equal(a, b)
    assert "joint" in ESTIMATORS
    with pytest.raises(ValueError, match="kalman9000"):
        make_estimator("kalman9000", VehicleParams())
    for args, kwargs, named in (
        ((None,), {}, "params must be vehicle parameters"),
        ((VehicleParams(),), {"noise": "x"}, "noise must be an estimation.NoiseParams"),
        ((VehicleParams(),), {"foo": 1}, r"unknown keyword argument\(s\) \['foo'\]"),
        ((VehicleParams(), "0.002"), {}, "dt must be .*, got '0.002'"),
    ):
        for name in ("joint", "joint+true-mu"):
            with pytest.raises(ValueError, match=named):
                make_estimator(name, *args, **kwargs)


def test_a_partial_oracle_reports_the_true_groups_and_the_estimators_own_rest():
    """joint+true-mu-fz: friction and loads from the truth (their sigma zero), everything else
    exactly the joint estimator's (it never sees the truth); bad names name the bad part."""
    scenario = make_scenario("mu_jump", duration=3.0)
    plain = simulate(scenario, estimator="joint", seed=2)
    part = simulate(scenario, estimator="joint+true-mu-fz", seed=2)
    np.testing.assert_array_equal(part.estimate.mu, part.truth.mu)
    np.testing.assert_array_equal(part.estimate.fz, part.truth.fz)
    assert not part.estimate.mu_std.any() and plain.estimate.mu_std.all()
    assert np.abs(plain.estimate.mu - plain.truth.mu).max() > 0.1  # so the substitution shows
    for field in ("u", "v", "beta", "r", "ax", "ay", "beta_std"):
        np.testing.assert_array_equal(getattr(part.estimate, field), getattr(plain.estimate, field))
    for bad, word in (("joint+true-speed", "speed"), ("kalman9+true-mu", "kalman9"), ("joint+true-mu-mu", "once")):
        with pytest.raises(ValueError, match=word):
            make_estimator(bad, VehicleParams())


@pytest.mark.parametrize("scenario, stays_below", [("paper_step", True), ("paper_serpentine", False)])
def test_dugoff_at_the_true_state_matches_the_plant_force_near_saturation(scenario, stays_below):
    """The estimator's tyre (Dugoff, eq. 17 stiffness, its own quasi-static loads), evaluated at
    the plant's true state and road friction, against the plant's PAC2002 lateral force wherever
    a tyre uses more than half its grip; errors in mu Fz, signed along the plant force (< 0: the
    model's force is smaller). Measured with the fitted friction scale k / with k = 1: mean
    |error| 0.052 / 0.100 on the step, 0.039 / 0.041 on the slalom; signed mean -0.048 / -0.098
    on the step (97% of samples below), +0.018 / -0.008 on the slalom (34% below: there the
    model scatters around the plant through the transients, so only the step's sign is asserted).
    Bound 0.07 on the mean |error|: ~1.35x the step's measured value, below k = 1's 0.10 on the
    step. Where the step saturates, the model stays below the plant, so there the joint
    estimator's mu reads a few hundredths high (README, comparison section)."""
    import dataclasses

    from fourwis.envs.layout import A_AX, A_AY, A_FY, A_FZ, A_MU, A_USAGE, S_DELTA_F, S_DELTA_R, S_OMEGA, S_R, S_U, S_V
    from fourwis.estimation.model import dugoff, steer_trig, tyre_operating_point, wheel_loads

    traj = simulate(scenario, seed=1)
    S, A = traj.state, traj.aux

    def errors(params: ModelParams) -> np.ndarray:
        pk, out = params.kernel, []
        for k in range(0, len(traj.t), 5):
            fz = np.empty(4)
            wheel_loads(A[k, A_AX], A[k, A_AY], pk, fz)
            steer = steer_trig(np.array([S[k, S_DELTA_F]] * 2 + [S[k, S_DELTA_R]] * 2))
            for w in np.flatnonzero(A[k, A_USAGE : A_USAGE + 4] > 0.5):
                tan_alpha, slip, cx, cy = tyre_operating_point(
                    S[k, S_U], S[k, S_V], S[k, S_R], fz[w], tuple(steer[:, w]), S[k, S_OMEGA + w], pk, w
                )
                k_mu = params.front.mu_scale * A[k, A_MU + w]
                fy = dugoff(fz[w], slip, tan_alpha, k_mu, cx, cy, S[k, S_U], 0.0)[1]
                plant = A[k, A_FY + w]
                out.append(math.copysign(1.0, plant) * (fy - plant) / (A[k, A_MU + w] * A[k, A_FZ + w]))
        return np.array(out)

    unit = dataclasses.replace(PARAMS.front, mu_scale=1.0)
    fitted, unscaled = errors(PARAMS), errors(dataclasses.replace(PARAMS, front=unit, rear=unit))
    assert PARAMS.front.mu_scale > 1.0 and len(fitted) > 500
    assert np.mean(np.abs(fitted)) < 0.07
    assert np.mean(np.abs(fitted)) < np.mean(np.abs(unscaled))  # the fitted k beats k = 1
    if stays_below:
        assert np.mean(fitted) < 0.0


@pytest.mark.parametrize("speed, torque", [(10.0, 0.0), (25.0, 0.0), (35.0, 0.0), (25.0, 150.0)])
def test_the_model_loses_speed_to_drag_and_rolling_resistance_as_the_plant_does(speed, torque):
    """On a straight, after 1 s of coasting or of driving with 150 N m per wheel (the tyres'
    slip settled), the estimation model with resistances (``from_vehicle(..., resistances=True)``),
    at the plant's true state and measured wheel inputs, gives the plant's ax within 0.01 m/s^2:
    both lose (1/2) rho Cd A u^2 to drag and f_r Fz to rolling resistance (coasting from 25 m/s,
    -0.34 m/s^2 after the second, 0.08 of it rolling resistance). Without them (the paper's model) its ax is off
    by the whole loss (> 0.1 m/s^2)."""
    from fourwis.envs.layout import A_AX, C_TORQUE, NU, S_OMEGA, S_TORQUE, S_U
    from fourwis.envs.road import uniform
    from fourwis.envs.vehicle import derivatives, initial_state, step

    vehicle = VehicleParams()
    controls = np.zeros((1, NU))
    controls[0, C_TORQUE : C_TORQUE + 4] = torque
    state = step(initial_state(vehicle, speed), controls, vehicle, uniform(1.0), n_steps=500).state
    dx, aux = derivatives(state, controls, np.ones((1, 4)), vehicle)
    plant_ax = aux[0, A_AX]
    assert (plant_ax > 0.1) if torque else (plant_ax < -0.1)
    inputs = Inputs(
        np.zeros(4), state[0, S_OMEGA : S_OMEGA + 4], state[0, S_TORQUE : S_TORQUE + 4], dx[0, S_OMEGA : S_OMEGA + 4]
    )
    x = np.array([state[0, S_U], 0.0, plant_ax, 0.0, 0.0, 0.0])

    def model_ax(params: ModelParams) -> float:
        return state_transition(x, np.ones(4), inputs, params, 1e-9)[2]

    assert PARAMS.rolling_resistance == PARAMS.drag_factor == 0.0  # the paper's model, shipped
    assert model_ax(ModelParams.from_vehicle(vehicle, resistances=True)) == pytest.approx(plant_ax, abs=0.01)
    assert abs(model_ax(PARAMS) - plant_ax) > 0.1


def test_tyre_relaxation_follows_the_plants_lateral_force_build_up():
    """Along the plant's true states in the step steer (open loop, mu 0.3), the estimation model
    with the tyre's relaxation length (``from_vehicle(..., relaxation=True)``; slip angles
    relaxed step by step as the joint estimator does) follows the plant's lateral acceleration
    (PAC2002 tyres with relaxation) while it builds up: its RMS error over the first 0.25 s of the
    steer is less than half the paper's instantaneous tyre's (measured 0.054 against 0.25 m/s^2),
    and once the turn is steady the two models agree within 1%."""
    from fourwis.envs.layout import S_DELTA_F, S_DELTA_R, S_OMEGA, S_R, S_TORQUE, S_U, S_V
    from fourwis.estimation.joint import _relax_slip
    from fourwis.estimation.model import body_forces, steer_trig

    traj, dt = simulate("paper_step", seed=0), 0.002
    T, S = traj.truth, traj.state
    onset = int(np.argmax(np.abs(S[:, S_DELTA_F]) > 1e-4))
    window, steady = range(onset, onset + 125), range(onset + 1000, onset + 1010)
    omega_dot = np.gradient(S[:, S_OMEGA : S_OMEGA + 4], dt, axis=0)

    def model_ay(params: ModelParams, steps) -> np.ndarray:
        relaxed, out = np.full(4, np.nan), []
        for k in range(onset - 50, steps[-1] + 1):
            table, relaxed_new = steer_trig(np.array([S[k, S_DELTA_F]] * 2 + [S[k, S_DELTA_R]] * 2)), np.empty(4)
            x_prev = np.array([T.u[k - 1], T.v[k - 1], T.ax[k - 1], T.ay[k - 1], T.r[k - 1], 0.0])
            _relax_slip(x_prev, table, relaxed, params.kernel, dt, relaxed_new)
            relaxed = relaxed_new
            if k in steps:
                forces = np.empty((3, 1))
                body_forces(
                    np.array([[S[k, S_U]], [S[k, S_V]], [S[k, S_R]], [T.ax[k]], [T.ay[k]]]),
                    T.mu[k][:, None].copy(),
                    table,
                    S[k, S_OMEGA : S_OMEGA + 4].copy(),
                    S[k, S_TORQUE : S_TORQUE + 4].copy(),
                    omega_dot[k].copy(),
                    params.kernel,
                    forces,
                )
                out.append(forces[1, 0])
        return np.array(out)

    relaxing = ModelParams.from_vehicle(VehicleParams(), relaxation=True)
    assert PARAMS.front.relaxation_length == 0.0 and 0.3 < relaxing.front.relaxation_length < 0.4
    assert relaxing.rear == relaxing.front
    plant = T.ay[list(window)]
    error_relaxed = rmse(model_ay(relaxing, window), plant)
    error_instant = rmse(model_ay(PARAMS, window), plant)
    assert error_relaxed < 0.5 * error_instant
    assert model_ay(relaxing, steady) == pytest.approx(model_ay(PARAMS, steady), rel=0.01)


def test_tyre_relaxation_cuts_the_joint_estimators_sideslip_error_in_the_sine():
    """make_estimator(..., tyre_relaxation=True), the joint estimator's default since
    docs/decisions/0045 (by name also ``fourwis.estimation:relaxed_joint``): on the paper's sine
    steer (open loop, sensor seed 0) the joint estimator's sideslip RMSE falls below 0.6x the
    paper model's (measured before 0045, on Dugoff's tyre: 0.059 against 0.177 deg): without the
    lag the model's lateral force leads the plant's at every steering reversal. Off for the
    other estimators, and refused by those without the model."""
    scenario = make_scenario("paper_sine")
    params = scenario.params
    errors = [
        rmse(traj.estimate.beta, traj.truth.beta)
        for traj in (
            simulate(scenario, estimator=make_estimator("joint", params, tyre_relaxation=relaxation))
            for relaxation in (False, None)
        )
    ]
    assert errors[1] < 0.6 * errors[0]
    assert make_estimator("fourwis.estimation:relaxed_joint", params).params.rear.relaxation_length > 0.3
    assert make_estimator("joint", params).params.rear.relaxation_length > 0.3
    assert make_estimator("joint-paper", params).params.rear.relaxation_length == 0.0
    for name in ("oracle", "fourwis.estimation:relaxed_joint"):
        with pytest.raises(ValueError, match="tyre_relaxation"):
            make_estimator(name, params, tyre_relaxation=True)
    with pytest.raises(ValueError, match="tyre_relaxation must be True, False or None"):
        make_estimator("joint", params, tyre_relaxation="yes")


def test_a_masked_reset_restarts_the_relaxed_slip_with_the_row():
    """A row of a batch of relaxed joint estimators restarted mid-run by a masked reset (the
    vector env's autoreset) continues exactly as a fresh estimator started on the same readings:
    its relaxed slip angles restart with it (none of the old car's lag is carried over), and
    the other rows go on as before."""
    from fourwis.core.types import SensorReading

    traj = simulate("paper_sine", seed=0)  # readings of a car in the sine: its slip keeps moving
    params, restart = traj.scenario.params, 1400

    def reading(k: int, n: int) -> SensorReading:
        return SensorReading(
            np.repeat(traj.sensors[k][None], n, 0), np.repeat(traj.sensor_valid[k][None], n, 0), np.full(n, traj.t[k])
        )

    batch, fresh, alone = (make_estimator("joint", params, tyre_relaxation=True) for _ in range(3))
    batch.reset(reading(0, 3), traj.scenario.speed)
    alone.reset(reading(0, 1), traj.scenario.speed)
    for k in range(1, restart):
        batch.step(reading(k, 3))
        alone.step(reading(k, 1))
    assert np.ptp(batch.state.slip_relaxed[1]) > 0.0  # a lagging row, mid-turn
    batch.reset(reading(restart, 3), traj.truth.u[restart], mask=np.array([False, True, False]))
    fresh.reset(reading(restart, 1), traj.truth.u[restart])
    for k in range(restart + 1, restart + 300):
        rows, one, other = batch.step(reading(k, 3)), fresh.step(reading(k, 1)), alone.step(reading(k, 1))
        np.testing.assert_array_equal(rows.beta[1], one.beta[0])
        np.testing.assert_array_equal(rows.beta[[0, 2]], np.repeat(other.beta, 2))


def test_the_dugoff_fit_reproduces_the_plant_tyre():
    """Eq. 17 stiffness within 5% of the plant tyre's cornering and slip stiffness over 1-5 kN
    (the issue's bound); the fitted friction scale k lowers the lateral-force error up to the
    plant tyre's peak (measured 0.057 -> 0.043 mu Fz RMS at k = 1.066); and refitting reproduces
    every field of the shipped estimation/data/dugoff_fit.json (which ModelParams loads) to
    rel 1e-6 (measured: identical but for mu_scale at 6e-15; the fit is deterministic and the
    bounded scalar search stops at xatol 1e-5 in k, so 1e-6 still catches a stale file)."""
    import json
    from importlib import resources

    from fourwis.training.tyre_fit import LOADS, fit_dugoff

    fit = fit_dugoff()
    tyre = VehicleParams().tyre
    for (m, n), exact in (
        ((fit["m1"], fit["n1"]), tyre.slip_stiffness(LOADS)),
        ((fit["m2"], fit["n2"]), tyre.cornering_stiffness(LOADS)),
    ):
        np.testing.assert_allclose(m * LOADS - n * LOADS**2, exact, rtol=0.05)
    assert 1.0 < fit["mu_scale"] < 1.2
    assert fit["lateral_rms_error_mu_fz"] < 0.8 * fit["lateral_rms_error_mu_fz_unscaled"]
    shipped = json.loads(resources.files("fourwis.estimation").joinpath("data/dugoff_fit.json").read_text())
    assert set(shipped) == set(fit) and set(shipped["magic"]) == set(fit["magic"])
    for part, fitted in ((shipped, fit), (shipped["magic"], fit["magic"])):
        for key, value in part.items():
            if isinstance(value, str):
                assert value == fitted[key], key
            elif not isinstance(value, dict):
                np.testing.assert_allclose(value, fitted[key], rtol=1e-6, atol=0, err_msg=key)
    # the joint estimator's Magic Formula shape: an order of magnitude closer (measured 0.0018 mu Fz)
    assert fit["magic"]["lateral_rms_error_mu_fz"] < 0.1 * fit["lateral_rms_error_mu_fz"]
    assert PARAMS.front.mu_scale == PARAMS.rear.mu_scale == pytest.approx(fit["mu_scale"], rel=1e-6)


@pytest.mark.parametrize("load", [2000.0, 5000.0])
def test_tyre_curves_of_the_papers_figures_2_and_3(load, tmp_path):
    """The tyre figure's curves (training/tyre_fit.py, paper Figures 2-3): at small slip the fitted
    Dugoff follows the plant (secant at 1% slip ratio / 0.5 deg within 10%); towards large slip
    Dugoff approaches k mu Fz from below and does not fall, while the plant's Magic Formula
    peaks at mu Fz scaled by its load-dependent peak friction relative to the reference load
    (to 1%; 0.95 / 0.87 at 5 kN longitudinally / laterally) and falls beyond (the shapes the
    README names as the friction estimate's limit). The PNG is written and not blank."""
    from fourwis.training.tyre_fit import plot_tyre_curves, tyre_curves

    mu = 0.5
    c = tyre_curves(load, mu)
    k = PARAMS.front.mu_scale
    small_x, small_y = np.searchsorted(c.kappa, 0.01), np.searchsorted(c.alpha, np.radians(0.5))
    assert c.fx_dugoff[small_x] == pytest.approx(c.fx_plant[small_x], rel=0.10)
    assert c.fy_dugoff[small_y] == pytest.approx(c.fy_plant[small_y], rel=0.10)
    vehicle = VehicleParams()
    peak_scale = np.array(vehicle.tyre.peak_friction(load)) / np.array(
        vehicle.tyre.peak_friction(vehicle.reference_wheel_load)
    )
    for dugoff_force, plant_force, scale in (
        (c.fx_dugoff, c.fx_plant, peak_scale[0]),
        (c.fy_dugoff, c.fy_plant, peak_scale[1]),
    ):
        assert np.all(np.diff(dugoff_force) >= -1e-9) and dugoff_force[-1] < k * mu * load
        assert dugoff_force[-1] > 0.9 * k * mu * load
        assert plant_force.max() == pytest.approx(scale * mu * load, rel=0.01)
    assert c.fx_plant[-1] < 0.95 * c.fx_plant.max()  # the Magic Formula falls beyond its peak
    import matplotlib.image

    assert matplotlib.image.imread(plot_tyre_curves(tmp_path / "tyre_curves.png", mu=mu, loads=(load,))).std() > 0.01


def test_tyre_fit_plot_option_draws_the_figure_and_leaves_the_fit_alone(tmp_path, monkeypatch):
    """``python -m fourwis.training.tyre_fit --plot DIR`` (README) writes DIR/tyre_curves.png and does not
    refit: the shipped fit file is not touched."""
    import fourwis.training.tyre_fit as tyre_fit

    monkeypatch.setattr(tyre_fit, "fit_dugoff", lambda *a, **k: pytest.fail("--plot refitted the tyre"))
    tyre_fit.main(["--plot", str(tmp_path / "figures")])
    assert (tmp_path / "figures" / "tyre_curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_joint_estimator_follows_a_friction_drop_and_the_dyc_stays_stable():
    """mu_jump (0.9 -> 0.3 in a 0.4 g turn) with DYC-LQR on the estimate: the joint estimator's
    mu follows the drop (measured mean 0.34 over the last 2 s, 2026-12-01) and the car's peak
    sideslip stays below half of what the fixed-dry-mu ckf lets it reach (measured 1.2 against
    14.6 deg; the oracle 1.2)."""
    from fourwis.control import make_controller

    runs = {
        name: simulate("mu_jump", controller=make_controller("dyc-lqr", VehicleParams()), estimator=name, seed=0)
        for name in ("joint", "ckf")
    }
    peak = {name: np.degrees(np.abs(run.truth.beta).max()) for name, run in runs.items()}
    assert peak["joint"] < 0.5 * peak["ckf"]
    joint = runs["joint"]
    last = joint.t >= joint.t[-1] - 2.0
    assert abs(joint.estimate.mu[last].mean() - 0.3) < 0.1
    assert np.all(joint.truth.mu[last] == pytest.approx(0.3))


def test_the_gate_sees_a_friction_drop_from_a_high_start_and_slide_detection_stays_silent():
    """The drop with the estimator started from mu 0.9 (as after hard driving on the dry road).
    Before record 0045 the friction gate, judging from mu_hat = 0.9, stayed shut: without the
    slide detection mu_hat stayed at 0.9 and the DYC slid the car to 13.9 deg, with it mu_hat came
    down (0.42 over the last 2 s) and the peak sideslip was 2.6 deg. joint's gate (the innovation
    at mu_hat, the Magic Formula tyre) now opens on the drop by itself: with the slide detection
    off, mu_hat falls below 0.6 within 0.3 s of the front wheels reaching the patch, reads the
    road over the last 2 s, and the peak sideslip stays under half of what the detection gave
    (measured 2026-12-07: 0.14 s, 0.32 on 0.30, 1.27 deg; from 0.8: 0.10 s, 0.31, 1.20 deg). The
    detection
    (SLIDE_*) then never fires, from 0.9 or the nominal 0.8: the estimates are identical with it
    off."""
    from fourwis.control import make_controller

    def run(nominal_mu, slide_rate):
        estimator = make_estimator("joint", VehicleParams(), nominal_mu=nominal_mu, slide_rate=slide_rate)
        return simulate("mu_jump", controller=make_controller("dyc-lqr", VehicleParams()), estimator=estimator, seed=0)

    for nominal_mu in (0.9, 0.8):
        gate, seeing = run(nominal_mu, math.inf), run(nominal_mu, SLIDE_RATE)
        last = gate.t >= gate.t[-1] - 2.0
        assert abs(gate.estimate.mu[last].mean() - gate.truth.mu[last].mean()) < 0.05, nominal_mu
        on_patch = gate.t[np.flatnonzero(gate.truth.mu.min(axis=1) < 0.5)[0]]  # (the front wheels)
        seen = gate.t[np.flatnonzero(gate.estimate.mu.mean(axis=1) < 0.6)[0]]
        assert 0.0 <= seen - on_patch < 0.3, nominal_mu
        assert np.abs(gate.truth.beta).max() < math.radians(2.6) / 2, nominal_mu
        for field in ("mu", "beta", "u"):
            np.testing.assert_array_equal(getattr(seeing.estimate, field), getattr(gate.estimate, field))


def test_slide_detection_stays_silent_while_the_car_turns_and_on_an_accelerometer_reading_high():
    """No steady turn, no detection: the sine's estimates with DYC-LQR (steering always moving)
    are identical with it on and off (without the steady-turn condition it fired there). And an ay
    offset fault reading high in a steady turn on a gripping road (mu_jump onto a 0.9 patch,
    estimator from 0.9, DYC-LQR, +1 m/s^2 from 2.5 s) is no slide: the car cannot give more
    lateral force than the turn takes (one reading low, -1 m/s^2, is the documented false
    alarm); estimates identical with it on and off, and mu_hat does not fall after the fault
    (the high reading asks for more grip: measured 2026-12-07, 0.76 at 2.5 s to 0.96). Before
    record 0045 the gate stayed shut there and mu_hat stayed 0.9; that it now reads the road
    low before the fault is test_joint_reads_a_gripping_road_low_in_a_steady_turn_under_dyc."""
    from fourwis.control import make_controller
    from fourwis.envs.sensors import Fault

    dyc = make_controller("dyc-lqr", VehicleParams())
    on, off = (
        simulate(
            "paper_sine", controller=dyc, seed=0, estimator=make_estimator("joint", VehicleParams(), slide_rate=rate)
        )
        for rate in (SLIDE_RATE, math.inf)
    )
    np.testing.assert_array_equal(on.estimate.mu, off.estimate.mu)
    np.testing.assert_array_equal(on.estimate.beta, off.estimate.beta)
    gripping = make_scenario("mu_jump", mu_patch=0.9)
    fault = (Fault("ay", "bias_step", 2.5, math.inf, 1.0),)
    on, off = (
        simulate(
            gripping,
            controller=dyc,
            seed=0,
            faults=fault,
            estimator=make_estimator("joint", VehicleParams(), nominal_mu=0.9, slide_rate=rate),
        )
        for rate in (SLIDE_RATE, math.inf)
    )
    np.testing.assert_array_equal(on.estimate.mu, off.estimate.mu)
    faulty = on.t >= 2.5
    assert np.all(on.estimate.mu[faulty].mean(axis=1) >= on.estimate.mu[faulty][0].mean())


@pytest.mark.xfail(strict=True, reason="found 2026-12-07 on issue-41, reported, not fixed: a behaviour change")
@pytest.mark.parametrize("seed", [0, 3])
def test_joint_reads_a_gripping_road_low_in_a_steady_turn_under_dyc(seed):
    """A steady turn at 0.3-0.44 of the grip on a uniform 0.9 road (mu_jump with a 0.9 patch),
    DYC-LQR, joint from its nominal 0.8: mu_hat should not read the road low by more than 0.05
    (record 0037's target below half the grip). It does (measured 2026-12-07: 0.642 with seed
    0, 0.338 with seed 3, whose DYC then drives a differential torque of up to 100 N m), and the
    steady hold keeps it; docs/decisions/0048 on what does and does not cause it. Expected to
    fail until the friction filter is fixed."""
    from fourwis.control import make_controller

    traj = simulate(
        make_scenario("mu_jump", mu_patch=0.9),
        controller=make_controller("dyc-lqr", VehicleParams()),
        estimator="joint",
        seed=seed,
    )
    assert traj.estimate.mu[-1].mean() > 0.9 - 0.05


#: joint's sideslip RMSE bound [deg] per paper scenario: the issue's 0.2 deg target where
#: README Table 2's 5-seed mean approaches it (step 0.124 with seeds up to 0.174, sine 0.178,
#: slalom 0.123); on the two lane changes, where every filter sits at the sensor-noise floor
#: (Table 2: 0.0085 / 0.0050 deg), about 2x that floor, rounded up (0.2 would pass beta_hat = 0 on the lane
#: change, RMS sideslip 0.141 deg).
JOINT_BETA_RMSE_DEG = {
    "paper_dlc": 0.02,
    "paper_step": 0.2,
    "paper_sine": 0.2,
    "paper_split_dlc": 0.012,
    "paper_serpentine": 0.2,
}


@pytest.mark.parametrize("scenario", PAPER_SCENARIOS)
def test_joint_meets_the_papers_accuracy_targets_on_its_scenarios(scenario):
    """Issue 4 on the mismatched plant with data-sheet sensor noise (seed 0): joint's sideslip
    RMSE within JOINT_BETA_RMSE_DEG, below BETA_RELATIVE of the truth's RMS sideslip and below
    ekf's and ckf's (measured 0.008 / 0.123 / 0.177 / 0.005 / 0.121 deg, relative 0.06 / 0.25 /
    0.36 / 0.02 / 0.40, in PAPER_SCENARIOS order; the step's bound is the issue's 0.2, which
    every sensor seed 0-4 meets, the worst at 0.174: README Table 2). mu: from 1 s after the first instant a tyre
    of the truth
    uses more than half its grip (Dugoff's mu-sensitive regime), the per-wheel error averages
    <= 0.05 (measured step 0.024, sine 0.023, slalom 0.036; single samples reach 0.08-0.10 on
    the sine and the slalom, so a per-sample bound of 0.05 does not hold); where no tyre ever
    does (both lane changes), mu_hat is held at its prior."""
    runs = {name: simulate(scenario, estimator=name, seed=0) for name in ("ekf", "ckf", "joint")}
    beta = {name: _beta_errors(traj)[0] for name, traj in runs.items()}
    assert beta["joint"] <= JOINT_BETA_RMSE_DEG[scenario]
    assert _beta_errors(runs["joint"])[1] < BETA_RELATIVE  # the truth's RMS is only 0.14-0.50 deg
    assert beta["joint"] < min(beta["ekf"], beta["ckf"])
    joint = runs["joint"]
    observable = np.flatnonzero(joint.aux[:, A_USAGE : A_USAGE + 4].max(axis=1) > 0.5)
    assert (len(observable) == 0) == (scenario in ("paper_dlc", "paper_split_dlc"))
    if len(observable) == 0:
        assert np.all(joint.estimate.mu == 0.8)  # the prior (make_estimator's nominal mu), held
        return
    after = joint.t >= joint.t[observable[0]] + 1.0
    assert after.sum() > 500  # seconds of observable driving are left to judge
    assert np.mean(np.abs(joint.estimate.mu[after] - joint.truth.mu[after])) <= 0.05


@pytest.mark.parametrize("seed", [11, 12])
def test_joint_mu_converges_on_a_friction_value_never_used_in_development(seed):
    """Open loop, a 0.4 g turn from mu 0.9 onto 0.27 (a value no tuning or design choice saw):
    over the last half of the run the wheel-mean mu_hat is within 0.1 of the truth (measured
    0.05 for both seeds before record 0045; with the wheels' mu correlated at 0.8 instead of 0.99
    it stayed near 0.9, an error of ~0.6); measured 2026-12-07: 0.022 and 0.026 (record 0047 on
    the gate judged at mu_hat alone, which kept seed 12's mu_hat at 0.93)."""
    from fourwis.envs.scenarios import make_scenario

    traj = simulate(make_scenario("mu_jump", mu_patch=0.27, duration=8.0), estimator="joint", seed=seed)
    half = traj.t > traj.t[-1] / 2
    assert np.all(traj.truth.mu[half] == pytest.approx(0.27))
    assert np.mean(np.abs(traj.estimate.mu[half].mean(axis=1) - 0.27)) < 0.1


@pytest.mark.parametrize("name", ["ckf", "joint"])
def test_a_stuck_gyro_is_detected_and_bridged_by_the_model(name):
    """A yaw-rate sensor frozen for 2 s of a sine steer: after STUCK_SAMPLES identical readings
    the channel counts as invalid, and the estimate keeps following the car from the model and
    the other sensors (its yaw-rate error stays far below the frozen reading's)."""
    faults = (Fault("yaw_rate", "stuck", start=2.0, end=4.0),)
    traj = simulate("paper_sine", estimator=name, seed=4, faults=faults)
    window = (traj.t > 2.1) & (traj.t < 4.0)
    sensor_error = rmse(traj.sensors[window, 2], traj.truth.r[window])
    assert sensor_error > 0.1  # the frozen reading is far off while the car keeps turning
    checked = rmse(traj.estimate.r[window], traj.truth.r[window])
    assert checked < 0.1 * sensor_error
    # with the check off (for noise-free or quantised readings) the frozen value is used: the
    # plain CKF follows it, the robust joint filter's Huber weights only soften it
    trusting = make_estimator(name, VehicleParams(), stuck_samples=math.inf)
    traj = simulate("paper_sine", estimator=trusting, seed=4, faults=faults)
    unchecked = rmse(traj.estimate.r[window], traj.truth.r[window])
    assert unchecked > (0.5 * sensor_error if name == "ckf" else 1.5 * checked)


def test_the_kernel_cache_follows_every_compiled_module(tmp_path):
    """numba invalidates a cached kernel only when its own file changes; fourwis keys its cache
    directory on the source of every module with kernels, so editing a module a kernel calls
    (here: the tyre model) moves to a fresh cache, while editing a module without kernels does not."""
    import os

    import numba

    from fourwis.core.kernels import cache_dir, kernel_fingerprint, package_dirs

    folders = [tmp_path / package for package in ("core", "envs", "estimation", "control")]
    for folder in folders:
        folder.mkdir()
    (tmp_path / "envs" / "tyre.py").write_text("import numba\ndef force(): return 1.0\n")
    (tmp_path / "envs" / "gym_env.py").write_text("import gymnasium\n")
    before = kernel_fingerprint(folders)
    (tmp_path / "envs" / "gym_env.py").write_text("import gymnasium  # edited\n")
    assert kernel_fingerprint(folders) == before
    (tmp_path / "envs" / "tyre.py").write_text("import numba\ndef force(): return 1.1\n")
    assert kernel_fingerprint(folders) != before
    assert {folder.name for folder in package_dirs()} == {"core", "envs", "estimation", "control"}
    if "NUMBA_CACHE_DIR" not in os.environ:
        assert numba.config.CACHE_DIR == str(cache_dir())


def test_an_installed_package_caches_its_kernels_in_the_users_cache(tmp_path, monkeypatch):
    """A checkout (pyproject.toml beside the layer folders) keeps its kernels in .numba_cache; an
    installed package, whose site-packages may be read-only and which pip should be able to
    uninstall whole, in $XDG_CACHE_HOME/fourwis/numba (numba's own fallback has no fingerprint)."""
    from fourwis.core.kernels import cache_dir, kernel_fingerprint

    folders = [tmp_path / "fourwis" / "core", tmp_path / "envs"]
    for folder in folders:
        folder.mkdir(parents=True)
    (tmp_path / "envs" / "tyre.py").write_text("import numba\n")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert cache_dir(folders) == tmp_path / "cache" / "fourwis" / "numba" / kernel_fingerprint(folders)
    (tmp_path / "pyproject.toml").write_text("")
    assert cache_dir(folders) == tmp_path / ".numba_cache" / kernel_fingerprint(folders)


def test_scratch_arrays_live_on_the_stack_and_large_ones_on_the_heap(heap_allocations):
    import numba

    from fourwis.core.kernels import SCRATCH_BYTES, scratch

    @numba.njit
    def fill(rows, cols):
        a, flags = scratch((rows, cols)), scratch((rows,), np.bool_)
        for i in range(rows):
            flags[i] = i % 2 == 0
            for j in range(cols):
                a[i, j] = 10.0 * i + j
        return a.copy(), flags.copy()  # copies: a scratch array must not leave its function

    small, large = (2, 3), (SCRATCH_BYTES // 8, 2)
    for shape in (small, large):
        a, flags = fill(*shape)
        np.testing.assert_array_equal(a, 10.0 * np.arange(shape[0])[:, None] + np.arange(shape[1]))
        np.testing.assert_array_equal(flags, np.arange(shape[0]) % 2 == 0)
    assert heap_allocations(lambda: fill(*small)) == 2  # the two copies
    assert heap_allocations(lambda: fill(*large)) == 3  # and the matrix
    from_python = scratch((3, 2), np.bool_)  # outside compiled code: an ordinary array
    assert isinstance(from_python, np.ndarray) and from_python.shape == (3, 2) and from_python.dtype == np.bool_


def test_a_borrowed_bundle_shares_its_data_and_owns_no_array():
    """kernels.borrowed: every array of a nested bundle keeps its data, shape and strides but loses
    its owner (NULL meminfo: nothing to count references on); writes through it, in the borrowing
    function and in those it calls, reach the caller's arrays; the arrays' Python reference counts
    are as before; the other values pass as they are; from Python it is the bundle itself."""
    import sys
    from typing import NamedTuple

    import numba
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic
    from numba.np.arrayobj import make_array

    from fourwis.core.kernels import borrowed

    @intrinsic
    def owned(typingctx, array):
        def codegen(context, builder, signature, args):
            meminfo = make_array(signature.args[0])(context, builder, value=args[0]).meminfo
            return cgutils.is_not_null(builder, meminfo)

        return types.boolean(array), codegen

    class Inner(NamedTuple):
        rows: np.ndarray
        scale: float

    class Outer(NamedTuple):
        inner: Inner
        column: np.ndarray
        count: int

    @numba.njit
    def add_where_positive(bundle, i):  # (branches: where numba's pruning leaves the counts)
        if bundle.inner.rows[i, 0] < 0.0:
            return 0
        bundle.inner.rows[i, 1] += bundle.inner.scale * bundle.column[i]
        return 1

    @numba.njit
    def run(bundle):
        before = (owned(bundle.inner.rows), owned(bundle.column))
        bundle = borrowed(bundle)
        added = 0
        for i in range(bundle.column.shape[0]):
            added += add_where_positive(bundle, i)
            bundle.column[i] += 10.0  # (a write in the borrowing function itself)
        return before, (owned(bundle.inner.rows), owned(bundle.column)), added, bundle.count, bundle.inner.scale

    rows, column = np.array([[1.0, 0.0], [-1.0, 0.0], [2.0, 0.0]]), np.arange(3.0)
    bundle = Outer(Inner(rows, 2.0), column, 7)
    counts = sys.getrefcount(rows), sys.getrefcount(column)
    before, after, added, count, scale = run(bundle)
    assert before == (True, True) and after == (False, False)
    assert (added, count, scale) == (2, 7, 2.0)
    np.testing.assert_array_equal(rows[:, 1], [0.0, 0.0, 4.0])
    np.testing.assert_array_equal(column, [10.0, 11.0, 12.0])
    run(bundle)
    assert (sys.getrefcount(rows), sys.getrefcount(column)) == counts
    assert borrowed(bundle) is bundle


@pytest.mark.parametrize("name", ESTIMATORS[1:])
def test_an_estimator_step_allocates_nothing_per_vehicle(name, heap_allocations):
    """The compiled step keeps its work arrays on the stack: a step of 64 vehicles makes as
    many heap allocations (the Python entry's output arrays) as a step of one."""
    from fourwis.core.types import SensorReading

    counts = []
    for batch in (1, 64):
        est = make_estimator(name, VehicleParams())
        values = np.zeros((batch, len(CHANNELS)))
        values[:, 3:7] = 20.0 / VehicleParams().wheel_radius
        reading = SensorReading(values, np.ones_like(values, dtype=bool), np.zeros(batch))
        est.reset(reading, np.full(batch, 20.0))
        est.step(reading)
        counts.append(heap_allocations(lambda: est.step(reading)))
    assert counts[0] == counts[1]


def test_zero_point_learning_finds_an_accelerometer_offset_in_steady_driving_only():
    """A 0.2 m/s^2 lateral accelerometer offset (perfect gyro): learnt on a 10 s straight to
    within 0.01, never while the steering moves, and it cuts the sideslip error once
    the tyres saturate on mu 0.3, where the filter without learning drifts."""
    sensors = SensorParams(bias_std=(0.0,) * N_SENSORS)  # (per sensor of the simulated car)
    offset = (Fault("ay", "bias_step", magnitude=0.2),)
    straight = make_estimator("joint", VehicleParams())
    simulate(
        make_scenario("paper_step", duration=9.99, angle=0.0),
        estimator=straight,
        seed=0,
        sensor_params=sensors,
        faults=offset,
    )
    assert straight.state.zero_point[0, ZP_OFFSET] == pytest.approx(0.2, abs=0.01)
    errors = {}
    for tau in (ZERO_POINT_TIME_CONSTANT, math.inf):
        estimator = make_estimator("joint", VehicleParams(), zero_point_time_constant=tau)
        traj = simulate(
            make_scenario("paper_step", duration=7.0), estimator=estimator, seed=0, sensor_params=sensors, faults=offset
        )
        errors[tau] = rmse(traj.estimate.beta, traj.truth.beta)
    assert errors[ZERO_POINT_TIME_CONSTANT] < 0.5 * errors[math.inf]
    sine = make_estimator("joint", VehicleParams())
    simulate("paper_sine", estimator=sine, seed=0, sensor_params=sensors, faults=offset)
    assert sine.state.zero_point[0, ZP_OFFSET] == 0.0  # the steering never rests for ZERO_POINT_SETTLE


@pytest.mark.parametrize("members", [[3], [-1], [1, 1], [0.5]])
def test_a_step_on_bad_members_raises_and_leaves_the_filters_alone(members):
    from fourwis.core.types import SensorReading

    est = make_estimator("joint", VehicleParams())
    values = np.zeros((3, len(CHANNELS)))
    values[:, 3:7] = 20.0 / VehicleParams().wheel_radius
    reading = SensorReading(values, np.ones_like(values, dtype=bool), np.zeros(3))
    est.reset(reading, np.full(3, 20.0))
    before = est.state.x.copy()
    with pytest.raises(ValueError, match="members"):
        est.step(reading, members=np.array(members))
    np.testing.assert_array_equal(est.state.x, before)


def test_a_nan_input_is_named_even_on_an_invalid_channel():
    """Wheel speeds, steer angles and torques drive the model every step: a NaN there, flagged
    invalid or not, is named (not reported as a failed covariance)."""
    from fourwis.core.types import SensorReading

    est = make_estimator("joint", VehicleParams())
    values = np.zeros((2, len(CHANNELS)))
    values[:, 3:7] = 20.0 / VehicleParams().wheel_radius
    valid = np.ones_like(values, dtype=bool)
    est.reset(SensorReading(values, valid, np.zeros(2)), np.full(2, 20.0))
    values[1, CHANNELS.index("delta_rl")], valid[1, CHANNELS.index("delta_rl")] = np.nan, False
    with pytest.raises(ValueError, match=r"\['delta_rl'\] of vehicle 1"):
        est.step(SensorReading(values, valid, np.zeros(2)))
    values[1, CHANNELS.index("delta_rl")] = 0.0  # an inf is refused as well (it had been clipped to a force)
    values[0, CHANNELS.index("torque_fl")], valid[0, CHANNELS.index("torque_fl")] = np.inf, False
    with pytest.raises(ValueError, match=r"\['torque_fl'\] of vehicle 0"):
        est.step(SensorReading(values, valid, np.zeros(2)))


@pytest.mark.parametrize("speed", [0.0, 0.5, 2.0])
def test_a_standing_or_creeping_car_keeps_its_friction_and_a_bounded_sideslip(speed):
    """10 s straight at 0, 0.5 or 2 m/s with data-sheet sensor noise: slip angles of a car at
    rest are noise over a floored speed, which once drove Dugoff's lambda below 1 and mu to its
    0.1 bound (0.31 after 2 s at rest) with a confident covariance. Below MU_MIN_SPEED the
    friction filter holds mu and its covariance; the sideslip stays within 3 deg (v noise over
    a floored 1 m/s) and, after the first second, within 3 of its reported sigmas (measured
    <= 0.43; at rest the sigma was 0 while the sideslip reached 88 deg). With the tyre
    relaxation (joint's default, docs/decisions/0045) a wheel below 1 m/s has no lag: lagging
    its noise slip over the floored speed rang the sideslip at 0.3 deg, 7.6 sigmas at 1 s
    (measured 2026-12-07: 0.37 at 0 and 0.5 m/s without the lag below 1 m/s, 1.24 at 2 m/s,
    where the lag is the tyre's)."""
    from fourwis.core.types import SensorReading
    from fourwis.estimation.joint import MU_MIN_SPEED

    assert speed < MU_MIN_SPEED
    params = VehicleParams()
    est = make_estimator("joint", params)
    rng = np.random.default_rng(3)
    from fourwis.envs.sensors import CHANNEL_PRESENT, SENSOR_OF_CHANNEL

    noise_std = np.asarray(SensorParams().noise_std)
    values = np.zeros((1, len(CHANNELS)))
    valid = CHANNEL_PRESENT[None].copy()  # (the car's sensors fill the channels: no forward-speed sensor)
    mu0, std0 = None, None
    for k in range(5000):
        values[0] = np.where(CHANNEL_PRESENT, rng.normal(0.0, noise_std)[np.maximum(SENSOR_OF_CHANNEL, 0)], np.nan)
        values[0, 3:7] += speed / params.wheel_radius
        reading = SensorReading(values.copy(), valid, np.full(1, k * 0.002))
        if k == 0:
            est.reset(reading, np.full(1, speed))
        e = est.step(reading)
        if k == 0:
            mu0, std0 = e.mu.copy(), e.mu_std.copy()
        assert abs(e.beta[0]) < math.radians(3.0)
        if k >= 500:
            assert abs(e.beta[0]) <= 3.0 * e.beta_std[0]
    np.testing.assert_array_equal(e.mu, mu0)
    np.testing.assert_array_equal(e.mu_std, std0)


def test_a_sustained_differential_torque_on_a_straight_does_not_move_mu():
    """A yaw moment from +-190 N m left / right on the 0.5 lane change at 35 km/h (the path
    follower steers against it): the tyres use ~75% of their grip longitudinally and little
    laterally. Fx is measured (torque balance), so the only friction information Dugoff offers
    is its combined-slip cut of the lateral force, which the plant's Magic Formula hardly has
    (at slip 0.023 on mu 0.5: Dugoff -18%, the plant -1%). Gated on the longitudinal slip too,
    the joint estimator ran mu to its 1.2 bound within 1.5 s; gated on the lateral demand it
    does not read the road high: mu_hat stays between the truth (0.5) and its nominal 0.8 and
    holds after the first second (measured 2026-12-07: 0.661 from 0.5 s on; record 0047's gate
    judged a sigma below mu_hat lets it fall, never rise)."""
    from fourwis.core.types import Command

    class Differential:
        def reset(self):
            pass

        def __call__(self, t, estimate, front_steer, base_torques):
            return Command(base_torques + np.array([190.0, -190.0, 190.0, -190.0]), np.zeros(len(base_torques)))

    traj = simulate(make_scenario("paper_dlc", duration=3.0), controller=Differential(), estimator="joint", seed=0)
    late = traj.t > 1.0
    assert traj.aux[late][:, A_USAGE : A_USAGE + 4].mean() > 0.6  # real excitation, not a coasting car
    mu = traj.estimate.mu[late]
    assert np.all(mu <= 0.8 + 1e-9) and np.all(mu >= traj.truth.mu[late] - 0.05)
    assert np.ptp(mu, axis=0).max() < 1e-3  # (held, wheel by wheel)


def test_without_its_friction_gate_the_joint_estimator_reads_model_error_as_friction():
    """On the straight before paper_step's steer (4.5 s, tyres far from half their grip: Dugoff's
    lambda >= 1, so dF/dmu = 0) the gated estimator holds its nominal mu exactly; with
    ``friction_gate=False`` (the paper's joint estimator, which updates mu every step) mu leaves
    it by more than 0.05, driven by nothing but the model's error."""
    scenario = make_scenario("paper_step", duration=4.5)
    held, moved = (
        simulate(scenario, None, make_estimator("joint", scenario.vehicle_params, friction_gate=gate), seed=0)
        for gate in (True, False)
    )
    assert held.aux[:, A_USAGE : A_USAGE + 4].max() < 0.5
    np.testing.assert_array_equal(held.estimate.mu, 0.8)
    assert np.abs(moved.estimate.mu - 0.8).max() > 0.05
    with pytest.raises(ValueError, match="friction_gate must be True or False, got 1"):
        make_estimator("joint", scenario.vehicle_params, friction_gate=1)
    with pytest.raises(ValueError, match="friction_gate applies to the joint estimator; 'ckf'"):
        make_estimator("ckf", scenario.vehicle_params, friction_gate=False)


def test_estimator_input_errors_name_the_bad_value():
    from dataclasses import replace

    from fourwis.core.types import SensorReading
    from fourwis.estimation import NoiseParams

    params = VehicleParams()
    est = make_estimator("joint", params)
    values = np.zeros((1, len(CHANNELS)))
    values[:, 3:7] = 20.0 / params.wheel_radius
    reading = SensorReading(values, np.ones_like(values, dtype=bool), np.zeros(1))
    with pytest.raises(RuntimeError, match="reset"):
        est.step(reading)
    with pytest.raises(ValueError, match="initial_speed"):
        est.reset(reading, np.full(1, np.nan))
    with pytest.raises(ValueError, match=r"\(B, 16\)"):
        est.reset(SensorReading(values[:, :15], reading.valid[:, :15], np.zeros(1)), 20.0)
    with pytest.raises(ValueError, match=r"initial_speed must be .* \(1,\), got \[20.0, 20.0\]"):
        est.reset(reading, [20.0, 20.0])
    three = SensorReading(np.repeat(values, 3, axis=0), np.ones((3, len(CHANNELS)), dtype=bool), np.zeros(3))
    with pytest.raises(ValueError, match=r"mask must be a bool array of shape \(3,\), got array\(\[1, 0, 0\]\)"):
        est.reset(three, 20.0, mask=np.array([1, 0, 0]))  # (as indices it had reset rows 0 and 1)
    first = make_estimator("joint", params)  # a first reset starts every row: every row is checked
    three.values[2, 0] = np.nan
    with pytest.raises(ValueError, match="first reading must be finite"):
        first.reset(three, 20.0, mask=np.array([True, False, False]))
    for name, value in (
        ("huber_c", "3"),
        ("nominal_mu", "0.8"),
        ("stuck_samples", None),
        ("slide_rate", 0.0),
        ("slide_rate", math.nan),
    ):
        with pytest.raises(ValueError, match=f"{name} must"):
            make_estimator("joint", params, **{name: value})
    with pytest.raises(ValueError, match="dt must be .*, got inf"):
        make_estimator("joint", params, dt=math.inf)
    with pytest.raises(ValueError, match="dt must be .*, got -1.0"):
        make_estimator("oracle", params, dt=-1.0)
    with pytest.raises(ValueError, match="foo"):
        make_estimator("oracle", params, foo=1)
    with pytest.raises(ValueError, match=r"process_std needs 6 values.*shape \(7,\)"):
        NoiseParams(process_std=(0.01,) * 7)
    with pytest.raises(ValueError, match="ax_std must be .*, got -0.1"):
        replace(NoiseParams(), ax_std=-0.1)
    with pytest.raises(ValueError, match="gyro_std must be .*, got nan"):
        NoiseParams(gyro_std=math.nan)
    with pytest.raises(ValueError, match=r"mu_accel_std must be .*, got array\(\[0.3, 0.6\]\)"):  # shared by the batch
        NoiseParams(mu_accel_std=np.array([0.3, 0.6]))
    with pytest.raises(ValueError, match="number of members"):
        NoiseParams(ax_std=np.array([0.1, 0.2]), gyro_std=np.array([0.01, 0.02, 0.03]))
    with pytest.raises(ValueError, match=r"mu_walk_std must be .*\(a scalar\), got \(0.001, 0.001\)"):
        NoiseParams(mu_walk_std=(1e-3, 1e-3))
    with pytest.raises(ValueError, match="ax_std must be .*, got 1e\\+200"):  # its variance overflows
        NoiseParams(ax_std=1e200)
    for kind in ("ekf", "ckf", "fkf"):  # plain updates: a Huber threshold would be ignored
        with pytest.raises(ValueError, match=f"huber_c applies to the robust estimators.*'{kind}'"):
            make_estimator(kind, params, huber_c=0.5)
    make_estimator("alo-fkf", params, huber_c=0.5)
    # per-member sensor noise with a shared process noise reaches every member's row
    two = make_estimator("ckf", params, noise=NoiseParams(ax_std=np.array([0.1, 10.0])))
    np.testing.assert_allclose(two.noise_variances.sensor_var[:, 0], [0.01, 100.0], rtol=1e-12)
    assert two.noise_variances.process_var.shape == (2, 6)
    with pytest.raises(ValueError, match="dt = 0.01"):
        simulate("paper_step", estimator=make_estimator("joint", params, dt=0.01))


def test_the_low_passes_stay_stable_on_a_log_sampled_slower_than_their_time_constants():
    """The wheel-acceleration low-pass (20 ms) and the zero-point ones take Euler steps with the
    gain dt / tau capped at 1: on paper_step's readings sampled at 50 ms the wheel acceleration
    stays physical and the friction is still read (before the cap it grew to 4e21 rad/s^2 and
    the mean friction error after the step reached 0.65)."""
    from fourwis.core.types import SensorReading

    run = simulate("paper_step", estimator="oracle", seed=1)
    every = 25  # 50 ms
    est = make_estimator("joint", VehicleParams(), dt=0.05)
    first = SensorReading(run.sensors[:1], run.sensor_valid[:1], run.t[:1])
    est.reset(first, np.array([run.scenario.speed]))
    errors = []
    for k in range(0, len(run.t), every):
        out = est.step(SensorReading(run.sensors[k][None], run.sensor_valid[k][None], run.t[k : k + 1]))
        assert np.all(np.abs(est.state.omega_dot) < 50.0)
        if run.t[k] >= 6.0:
            errors.append(np.abs(out.mu[0] - run.truth.mu[k]).mean())
    assert np.mean(errors) < 0.2


def test_a_filter_at_another_step_keeps_its_noise_per_unit_time():
    """The noise is given per 2 ms step: at 10 ms the process and mu random-walk variances are
    5x (the sensors' stay per sample), and the joint estimator still follows the mu jump
    (without the scaling its mean mu error over the last half was 0.53)."""
    from fourwis.envs.sensors import SensorParams

    fine, coarse = (make_estimator("joint", VehicleParams(), dt=dt) for dt in (0.002, 0.01))
    np.testing.assert_allclose(coarse.noise_variances.process_var, 5.0 * fine.noise_variances.process_var, rtol=1e-12)
    np.testing.assert_allclose(coarse.noise_variances.mu_var, fine.noise_variances.mu_var * [5.0, 1.0, 1.0], rtol=1e-12)
    np.testing.assert_array_equal(coarse.noise_variances.sensor_var, fine.noise_variances.sensor_var)
    traj = simulate("mu_jump", estimator=coarse, dt=0.01, sensor_params=SensorParams(sample_time=0.01))
    half = len(traj.t) // 2
    assert np.mean(np.abs(traj.estimate.mu - traj.truth.mu)[half:]) < 0.05


def test_the_reusable_filters_refuse_bad_noise_and_sharing_coefficients():
    x, P = np.zeros((1, 2)), np.eye(2)[None]

    def f(points):
        return points

    np.testing.assert_allclose(
        ckf_predict(np.zeros((2, 2)), np.stack([np.eye(2)] * 2), f, np.eye(2)[None])[1][1], 2.0 * np.eye(2)
    )  # a (1, n, n) Q serves the batch
    for Q, match in (
        (np.full((2, 2), np.nan), "finite"),
        (-np.eye(2), "positive semi-definite"),
        (np.array([[1.0, 0.5], [0.0, 1.0]]), "symmetric"),
        (np.eye(3), "shape"),
    ):
        with pytest.raises(ValueError, match=match):
            ckf_predict(x, P, f, Q)
    # the state's covariance too: the compiled steps' jitter repairs rounding, not a wrong P
    z = np.zeros((1, 2))
    for bad_P, match in (
        (np.diag([1.0, -0.01])[None], "covariance P must be a symmetric positive semi"),
        (np.array([[[1.0, 0.5], [0.0, 1.0]]]), "covariance P must be a symmetric"),
    ):
        for call in (lambda: ckf_predict(x, bad_P, f, np.eye(2)), lambda: ckf_update(x, bad_P, z, f, np.eye(2))):
            with pytest.raises(ValueError, match=match):
                call()
    with pytest.raises(ValueError, match="state must be finite"):
        ckf_predict(np.full((1, 2), np.inf), P, f, np.eye(2))
    z = np.zeros((1, 2))
    for kwargs, match in (
        ({"huber_c": -1.0}, "huber_c"),
        ({"huber_c": math.nan}, "huber_c"),
        ({"valid": np.ones((1, 3), bool)}, "valid"),
    ):
        with pytest.raises(ValueError, match=match):
            ckf_update(x, P, z, f, np.eye(2), **kwargs)
    subs = [SubMeasurement(z, f, np.eye(2), None), SubMeasurement(z, f, np.eye(2), None)]
    with pytest.raises(ValueError, match="sum to 1"):
        federated_step(x, P, f, 0.01 * np.eye(2), subs, np.array([[5.0, 5.0]]))


def test_the_yaw_balance_keeps_a_long_turn_at_the_limit_from_drifting():
    """paper_step held for 30 s (mu 0.3, the front axle saturated): in the steady turn the net yaw
    moment is zero, and sub-filter 2's yaw balance (YAW_BALANCE_STD) keeps the sideslip from
    drifting. Before record 0045, without it (the paper's sub-filter 2) the filters drifted
    towards a car with more friction and less slip (mu_hat 0.45, sideslip +0.55 against -0.57
    deg at 30 s). joint's steady hold now keeps mu in the steady turn by itself, so the balance
    shows with the hold off (measured 2026-12-07, sensor seed 0, mu_hat at 30 s / sideslip RMSE
    after 10 s: both 0.303 / 0.064 deg; hold alone 0.303 / 0.083; balance alone 0.301 / 0.175;
    neither 0.331 / 0.429, the sideslip +0.04 against -0.57 deg at 30 s)."""
    scenario = make_scenario("paper_step", duration=30.0)
    late = {}
    for hold, std in ((True, YAW_BALANCE_STD), (True, math.inf), (False, YAW_BALANCE_STD), (False, math.inf)):
        estimator = make_estimator("joint", VehicleParams(), yaw_balance_std=std, steady_hold=hold)
        traj = simulate(scenario, estimator=estimator, seed=0)
        after = traj.t > 10.0
        late[(hold, std)] = (
            traj.estimate.mu[-1].mean(),
            math.degrees(rmse(traj.estimate.beta[after], traj.truth.beta[after])),
            math.degrees(traj.estimate.beta[-1] - traj.truth.beta[-1]),
        )
    for kept in ((True, YAW_BALANCE_STD), (True, math.inf), (False, YAW_BALANCE_STD)):
        assert abs(late[kept][0] - 0.3) < 0.05 and late[kept][1] < 0.25, kept
    assert late[(False, math.inf)][1] > 0.3 and late[(False, math.inf)][2] > 0.4
    for kwargs, named in (
        ({"yaw_balance_std": 0.0}, "yaw_balance_std must be > 0"),
        ({"yaw_balance_std": math.inf, "kind": "fkf"}, "applies to the joint estimator"),
    ):
        with pytest.raises(ValueError, match=named):
            StateEstimator(PARAMS, **kwargs)

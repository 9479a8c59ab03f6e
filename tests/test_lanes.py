"""The filter arithmetic in lanes of cars (estimation/lanes.py) equals the single-car building
blocks (estimation/ckf.py, estimation/federated.py) bit for bit, lane by lane, including lanes
whose Cholesky factor needs the jitter fallback or fails, invalid channels and Huber weights."""

import math

import numba
import numpy as np
import pytest

from fourwis.core.types import CH_AY, CH_OMEGA, SensorReading
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation import make_estimator
from fourwis.estimation.ckf import cubature_points, measurement_update, predicted_moments, spd_inverse
from fourwis.estimation.federated import fuse, sharing_coefficients
from fourwis.estimation.joint import NoiseParams, empty_estimate, step_vehicle, step_vehicles
from fourwis.estimation.lanes import (
    cubature_points_lanes,
    fuse_lanes,
    measurement_update_lanes,
    predicted_moments_lanes,
    sharing_coefficients_lanes,
    spd_inverse_lanes,
)
from fourwis.estimation.model import (
    LATERAL_DUGOFF_ELLIPSE,
    LATERAL_DUGOFF_SLIP,
    LATERAL_MAGIC_ELLIPSE,
    ModelParams,
    axle_tyre,
    body_forces,
    body_forces_lanes,
    lateral_law,
    shared_state_forces_lanes,
    steer_trig,
)

N, M = 6, 7  #: a state filter's sizes (sub-filter 1)


def lanes_of(a: np.ndarray) -> np.ndarray:
    """(B, ...) per car as (..., B) lanes."""
    return np.ascontiguousarray(np.moveaxis(a, 0, -1))


def cars_of(a: np.ndarray) -> np.ndarray:
    """(..., B) lanes as (B, ...) per car."""
    return np.moveaxis(a, -1, 0)


def covariances(rng, B: int, n: int) -> np.ndarray:
    """B covariances (B, n, n) of very different scales, two of them semi-definite (one needs the
    jitter, one is hopeless: not finite)."""
    A = rng.normal(size=(B, n, n)) * np.exp(rng.normal(scale=2.0, size=(B, 1, n)))
    P = A @ A.transpose(0, 2, 1) + 1e-3 * np.eye(n)
    if B > 2:
        v = rng.normal(size=n)
        P[1] = np.outer(v, v)  # rank one: the Cholesky factor fails, the jitter helps
        P[2, 0, 0] = math.nan  # no factor at all
    return P


@numba.njit
def _points_lanes(x, P, points, ok, n, lanes):
    cubature_points_lanes(x, P, points, ok, n, lanes)


@numba.njit
def _moments_lanes(moved, Q, x_out, P_out, n, lanes):
    predicted_moments_lanes(moved, Q, x_out, P_out, n, lanes)


@numba.njit
def _inverse_lanes(A, out, ok, n, lanes):
    spd_inverse_lanes(A, out, ok, n, lanes)


@numba.njit
def _sharing_lanes(confidence, beta, lanes):
    sharing_coefficients_lanes(confidence, beta, lanes)


@numba.njit
def _scalar_points(x, P, points, ok):
    for b in range(x.shape[0]):
        ok[b] = cubature_points(x[b], P[b], points[b])


@pytest.mark.parametrize("lanes", [1, 5, 32])
def test_cubature_points_and_moments_in_lanes_equal_the_single_car_ones(lanes):
    rng = np.random.default_rng(lanes)
    x, P = rng.normal(size=(lanes, N)), covariances(rng, lanes, N)
    points, ok = np.empty((lanes, 2 * N, N)), np.empty(lanes, np.bool_)
    _scalar_points(x, P, points, ok)
    points_l, ok_l = np.empty((2 * N, N, lanes)), np.empty(lanes, np.bool_)
    _points_lanes(lanes_of(x), lanes_of(P), points_l, ok_l, N, lanes)
    np.testing.assert_array_equal(ok_l, ok)
    assert ok.sum() == lanes - (1 if lanes > 2 else 0)
    np.testing.assert_array_equal(cars_of(points_l)[ok], points[ok])
    Q = covariances(rng, lanes, N)[:, ::-1, ::-1].copy()  # (asymmetric rounding: symmetrised alike)
    moved = points + 0.01 * np.sin(points)
    x_out, P_out = np.empty((lanes, N)), np.empty((lanes, N, N))
    for b in range(lanes):
        predicted_moments(moved[b], Q[b], x_out[b], P_out[b])
    x_l, P_l = np.empty((N, lanes)), np.empty((N, N, lanes))
    _moments_lanes(lanes_of(moved), lanes_of(Q), x_l, P_l, N, lanes)
    np.testing.assert_array_equal(cars_of(x_l), x_out)
    np.testing.assert_array_equal(cars_of(P_l), P_out)


@numba.njit
def _update_lanes(x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nll, ok, n, m, lanes, nu, S, z_centre):
    if z_centre.shape[0] == 0:
        measurement_update_lanes(x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nll, ok, n, m, lanes, nu, S)
    else:
        measurement_update_lanes(x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nll, ok, n, m, lanes, nu, S,
                                 z_centre)  # fmt: skip


@pytest.mark.parametrize("centred", [False, True])
@pytest.mark.parametrize("huber_c", [math.inf, 1.5])
@pytest.mark.parametrize("lanes", [1, 5, 32])
def test_the_measurement_update_in_lanes_equals_the_single_car_one(lanes, huber_c, centred):
    rng = np.random.default_rng(10 + lanes)
    x, P = rng.normal(size=(lanes, N)), covariances(rng, lanes, N)
    P[np.isnan(P)] = 1.0
    points, ok = np.empty((lanes, 2 * N, N)), np.empty(lanes, np.bool_)
    _scalar_points(x, P, points, ok)
    mix = rng.normal(size=(N, M))
    Z = np.tanh(points @ mix) + 0.1 * points[..., :1]
    z = Z.mean(axis=1) + rng.normal(scale=3.0, size=(lanes, M))  # outliers for the Huber weights
    valid = rng.random((lanes, M)) > 0.2
    R = np.broadcast_to(np.diag(rng.uniform(0.01, 0.5, M)), (lanes, M, M)).copy()
    if lanes > 3:
        R[3] = -np.eye(M)  # an innovation covariance that is not positive definite
    x_out, P_out, nll = np.full((lanes, N), np.nan), np.full((lanes, N, N), np.nan), np.empty(lanes)
    nu, S = np.empty((lanes, M)), np.empty((lanes, M, M))
    z_centre = np.tanh(x @ mix) + 0.1 * x[:, :1] if centred else np.empty((0, M))
    for b in range(lanes):
        nll[b] = measurement_update(
            x[b], P[b], points[b], Z[b], z[b], valid[b], R[b], huber_c, x_out[b], P_out[b], nu[b], S[b], np.empty(M),
            *((z_centre[b],) if centred else ()),
        )  # fmt: skip
    x_l, P_l, nll_l, ok_l = np.empty((N, lanes)), np.empty((N, N, lanes)), np.empty(lanes), np.empty(lanes, np.bool_)
    nu_l, S_l = np.empty((M, lanes)), np.empty((M, M, lanes))
    _update_lanes(
        lanes_of(x), lanes_of(P), lanes_of(points), lanes_of(Z), lanes_of(z), lanes_of(valid), lanes_of(R),
        huber_c, x_l, P_l, nll_l, ok_l, N, M, lanes, nu_l, S_l, lanes_of(z_centre) if centred else z_centre,
    )  # fmt: skip
    good = np.isfinite(nll)
    np.testing.assert_array_equal(ok_l, good)
    assert good.sum() == lanes - (1 if lanes > 3 else 0)
    np.testing.assert_array_equal(nll_l, nll)  # (NaN where it failed)
    np.testing.assert_array_equal(cars_of(x_l)[good], x_out[good])
    np.testing.assert_array_equal(cars_of(P_l)[good], P_out[good])
    np.testing.assert_array_equal(cars_of(nu_l)[good], nu[good])
    np.testing.assert_array_equal(cars_of(S_l)[good], S[good])


@numba.njit
def _fuse_lanes(xs, Ps, x_out, P_out, confidence, ok, n, lanes):
    fuse_lanes(xs, Ps, x_out, P_out, confidence, ok, n, lanes)


@pytest.mark.parametrize("n", [4, 6])
@pytest.mark.parametrize("lanes", [1, 5, 32])
def test_the_fusion_inverse_and_sharing_in_lanes_equal_the_single_car_ones(lanes, n):
    rng = np.random.default_rng(20 + lanes + n)
    Ps = np.stack([covariances(rng, lanes, n), covariances(rng, lanes, n)], axis=1)  # (B, 2, n, n)
    Ps[:, 1][np.isnan(Ps[:, 1])] = 0.5
    xs = rng.normal(size=(lanes, 2, n))
    inverse, ok = np.empty((lanes, n, n)), np.empty(lanes, np.bool_)
    for b in range(lanes):
        ok[b] = spd_inverse(Ps[b, 0], inverse[b])
    inverse_l, ok_l = np.empty((n, n, lanes)), np.empty(lanes, np.bool_)
    _inverse_lanes(lanes_of(Ps[:, 0]), inverse_l, ok_l, n, lanes)
    np.testing.assert_array_equal(ok_l, ok)
    np.testing.assert_array_equal(cars_of(inverse_l)[ok], inverse[ok])
    x_g, P_g = np.empty((lanes, n)), np.empty((lanes, n, n))
    confidence, beta = np.empty((lanes, 2)), np.empty((lanes, 2))
    for b in range(lanes):
        ok[b] = fuse(xs[b], Ps[b], x_g[b], P_g[b], confidence[b])
        if ok[b]:
            sharing_coefficients(confidence[b], beta[b])
    x_l, P_l = np.empty((n, lanes)), np.empty((n, n, lanes))
    confidence_l, beta_l = np.empty((2, lanes)), np.empty((2, lanes))
    _fuse_lanes(lanes_of(xs), lanes_of(Ps), x_l, P_l, confidence_l, ok_l, n, lanes)
    _sharing_lanes(confidence_l, beta_l, lanes)
    np.testing.assert_array_equal(ok_l, ok)
    assert ok.sum() == lanes - (1 if lanes > 2 else 0)
    for got, want in ((x_l, x_g), (P_l, P_g), (confidence_l, confidence), (beta_l, beta)):
        np.testing.assert_array_equal(cars_of(got)[ok], want[ok])


# ---- the joint estimator's step in lanes (estimation/joint.py: _step_block) ------------------------
@numba.njit
def _steps_in_lanes(f, rows, reading, out, status):
    step_vehicles(f, rows, rows.shape[0], reading, out, rows, status)


@numba.njit
def _steps_car_by_car(f, rows, reading, out, status):
    for j in range(rows.shape[0]):
        status[j] = step_vehicle(f, rows[j], reading, out, rows[j])


def _drive_logs(duration: float) -> list:
    """Sensor logs (values, valid, t) of closed-loop runs that excite the friction filter, the
    slide detection and the yaw balance differently."""
    runs = []
    for name, seed in (("paper_sine", 1), ("paper_step", 2), ("mu_jump", 3), ("paper_dlc", 4)):
        traj = simulate(make_scenario(name, duration=duration), estimator="oracle", seed=seed)
        runs.append((traj.sensors, traj.sensor_valid, traj.t))
    return runs


@pytest.mark.parametrize("kind", ["joint", "alo-fkf"])
def test_the_estimator_stepped_in_lanes_equals_it_car_by_car(kind):
    """84 cars (a block of 64 and one of 20, padded) on four logs at different offsets: each car's
    estimate, status and whole filter state after every step equal bit for bit its single-car
    step's, with a clock gap (substeps), dropouts, a car below the friction filter's speed, a
    car whose reading is refused and per-car noise."""
    steps, B = 400, 84
    logs = _drive_logs(2.0 + steps * 0.002)
    rng = np.random.default_rng(0)
    which, offset = np.arange(B) % len(logs), rng.integers(0, 500, B)
    noise = NoiseParams().scaled(rng.normal(scale=0.3, size=(B, 4)))
    estimators = [make_estimator(kind, VehicleParams(), 0.002, noise=noise) for _ in range(2)]
    params = estimators[0].params

    def reading(k: int) -> SensorReading:
        values = np.stack([logs[which[b]][0][offset[b] + k] for b in range(B)])
        valid = np.stack([logs[which[b]][1][offset[b] + k] for b in range(B)])
        t = np.array([logs[which[b]][2][offset[b] + k] for b in range(B)])
        t[5] += 0.004 if k >= 50 else 0.0  # (a gap: three substeps in one step, then steps of dt again)
        valid[7:70:9, CH_AY] = (k // 20) % 2 == 0  # (dropouts, on and off)
        if k == 30:
            values[11, CH_OMEGA] = math.nan  # (refused: the car's state stays as it was)
        return SensorReading(values, valid, t)

    initial_speed = np.array([logs[which[b]][0][offset[b], CH_OMEGA] * params.wheel_radius for b in range(B)])
    initial_speed[9] = 1.0  # (below MU_MIN_SPEED at first: the friction filter waits)
    for estimator in estimators:
        estimator.reset(reading(0), initial_speed)
    rows = np.arange(B)
    ran_friction = np.zeros((B, 4), bool)
    for k in range(1, steps):
        r = reading(k)
        outs, statuses = [], []
        for estimator, step in zip(estimators, (_steps_in_lanes, _steps_car_by_car)):
            out, status = empty_estimate(B), np.empty(B, np.int64)
            mu_before = estimator.state.mu.copy()
            step(estimator.kernel(), rows, r, out, status)
            outs.append(out)
            statuses.append(status)
        ran_friction |= estimators[1].state.mu != mu_before
        np.testing.assert_array_equal(statuses[0], statuses[1])
        good = statuses[1] == 0
        for a, b in zip(outs[0], outs[1]):
            np.testing.assert_array_equal(a[good], b[good])
        for a, b in zip(estimators[0].state, estimators[1].state):
            np.testing.assert_array_equal(a, b)
        committed = estimators[0].state  # (each stepped car's state moved on to this reading)
        np.testing.assert_array_equal(committed.t_prev[good], r.t[good])
        np.testing.assert_array_equal(committed.omega_prev[good], r.values[good, CH_OMEGA : CH_OMEGA + 4])
    assert (statuses[1] != 0).sum() == 0  # (the refused car stepped on after its refused reading)
    if kind == "joint":
        moved = ran_friction.any(axis=1)  # (the friction filters moved mu in both blocks: their updates are compared)
        assert moved[:64].any() and moved[64:].any()


@numba.njit
def _forces_lanes(state, mu, steer, omega, torque, omega_dot, pk, out, lanes):
    if state.shape[1] == 1:
        shared_state_forces_lanes(state, mu, steer, omega, torque, omega_dot, pk, out, lanes)
    else:
        body_forces_lanes(state, mu, steer, omega, torque, omega_dot, pk, out, lanes)


@numba.njit
def _law(pk, w):
    return lateral_law(pk, axle_tyre(pk, w))


@pytest.mark.parametrize(
    ("force_ellipse", "shape", "law"),
    [
        (False, "dugoff", LATERAL_DUGOFF_SLIP),
        (True, "dugoff", LATERAL_DUGOFF_ELLIPSE),
        (True, "magic", LATERAL_MAGIC_ELLIPSE),
    ],
)
@pytest.mark.parametrize("shared", [False, True])
def test_the_body_forces_in_lanes_equal_the_single_cars_for_each_lateral_law(force_ellipse, shape, law, shared):
    """body_forces_lanes (the Magic Formula's law chosen outside its loops) and
    shared_state_forces_lanes (one state for a car's evaluations, the friction filter's points:
    each wheel's operating point taken once) equal body_forces car by car bit for bit, on states
    from near rest to past the grip limit, some wheels braking and some driving."""
    pk = ModelParams.from_vehicle(VehicleParams(), force_ellipse=force_ellipse, shape=shape).kernel
    assert [_law(pk, w) for w in range(4)] == [law] * 4
    rng = np.random.default_rng(4)
    B, K = 9, 5
    states = np.empty((B, 5, 1 if shared else K))
    states[:, 0] = rng.uniform(0.0, 40.0, states[:, 0].shape)  # u [m/s], from rest
    states[:, 1] = rng.normal(0.0, 2.0, states[:, 1].shape)  # v: sideslip up to ~30 deg at low speed
    states[:, 2] = rng.normal(0.0, 0.6, states[:, 2].shape)  # r [rad/s]
    states[:, 3:] = rng.normal(0.0, 6.0, states[:, 3:].shape)  # ax, ay [m/s^2]: beyond the grip
    mu = rng.uniform(0.1, 1.2, (B, 4, K))
    steer = np.stack([steer_trig(rng.normal(0.0, 0.2, 4)) for _ in range(B)])
    omega = states[:, 0, :1] / pk.wheel_radius * (1.0 + rng.normal(0.0, 0.2, (B, 4)))  # slips of ~20%
    torque, omega_dot = rng.normal(0.0, 400.0, (B, 4)), rng.normal(0.0, 50.0, (B, 4))
    expected = np.empty((B, 3, K))
    for b in range(B):
        per_evaluation = np.ascontiguousarray(np.broadcast_to(states[b], (5, K)))
        body_forces(per_evaluation, mu[b], steer[b], omega[b], torque[b], omega_dot[b], pk, expected[b])
    out = np.empty((3, K, B))
    _forces_lanes(
        lanes_of(states), lanes_of(mu), lanes_of(steer), lanes_of(omega), lanes_of(torque), lanes_of(omega_dot), pk,
        out, B,
    )  # fmt: skip
    assert np.all(np.isfinite(expected))
    np.testing.assert_array_equal(cars_of(out), expected)

"""Online noise re-tuning: bounded work per step, results at run ends, SPD covariance,
determinism, a non-degenerate criterion, bad input."""

import numpy as np
import pytest

from fourwis.core.types import SensorReading
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation import make_estimator
from fourwis.estimation.joint import FilterState
from fourwis.estimation.online import OnlineTuner, WindowReplay

RUN = simulate(make_scenario("paper_sine", duration=3.0), seed=0)  # truth + sensor readings, 1501 samples


def _feed(tuner, check=None):
    for k in range(len(RUN.t)):
        reading = SensorReading(RUN.sensors[k][None], RUN.sensor_valid[k][None], np.array([RUN.t[k]]))
        if k == 0:
            tuner.reset(reading, np.array([RUN.scenario.speed]))
        tuner.step(reading)
        if check is not None:
            check(k)


@pytest.mark.parametrize("replay_per_step", [1, 3])
def test_work_per_step_is_bounded_and_results_arrive_when_runs_finish(replay_per_step):
    """Each filter step replays at most ``replay_per_step`` population steps; a run started at
    a window boundary ends (iterations + 1) * ceil(window / replay_per_step) steps later, and
    only then does the live filter's noise change: to the base noise scaled by the run's result
    (the paper's rule: until a run finishes the filter keeps the noise it has)."""
    window, iterations = 100, 2
    tuner = OnlineTuner(
        make_estimator("alo-fkf", VehicleParams()),
        window=window,
        n_agents=4,
        iterations=iterations,
        replay_per_step=replay_per_step,
    )
    eigen_min, completed, factors, stds = [], [], [], []

    def live_stds():
        """The standard deviations the filter computes with (process, then accel, gyro, wheel)."""
        est = tuner.estimator
        return np.sqrt(
            np.concatenate([est.noise_variances.process_var.ravel(), est.noise_variances.sensor_var.ravel()])
        )

    def noise_stds(noise):
        return np.concatenate(
            [
                np.ravel(noise.process_std),
                [noise.ax_std, noise.ay_std, noise.gyro_std, noise.wheel_speed_std, noise.speed_std],
            ]
        )

    def check(k):
        eigen_min.append(np.linalg.eigvalsh(tuner.estimator.state.P).min())
        completed.append(tuner.runs_completed)
        factors.append(None if tuner.factors is None else np.array(tuner.factors))
        stds.append(live_stds())
        np.testing.assert_array_equal(
            noise_stds(tuner.estimator.noise),
            noise_stds(tuner.base_noise if tuner.factors is None else tuner.base_noise.scaled(tuner.factors)),
        )

    _feed(tuner, check)
    assert tuner.max_replay_steps_in_a_step == replay_per_step
    run_length = (iterations + 1) * -(-window // replay_per_step)  # filter steps per optimizer run
    # a run replays during the run_length steps after its start and the next one starts at the
    # first window boundary at or after its end
    starts, k = [], window
    while k + run_length <= len(RUN.t):
        starts.append(k)
        k = -(-(k + run_length) // window) * window
    assert tuner.runs_completed == len(starts) >= 1
    assert tuner.factors is not None and np.all(np.abs(tuner.factors) <= 1.0)
    # the run started when step index k - 1 filled a window finishes in step k - 1 + run_length
    ends = [k - 1 + run_length for k in starts]
    assert [k for k in range(1, len(RUN.t)) if completed[k] != completed[k - 1]] == ends
    assert completed[ends[0] - 1] == 0 and all(completed[e] == i + 1 for i, e in enumerate(ends))
    changed = [k for k in range(1, len(RUN.t)) if not np.array_equal(stds[k], stds[k - 1])]
    assert changed == ends  # the noise changes exactly when a run completes, at every completion
    np.testing.assert_allclose(stds[0], noise_stds(tuner.base_noise), rtol=1e-12)  # base noise until then
    assert all(f is None for f in factors[: ends[0]])
    for e in ends:  # ... and then the base noise scaled by that run's factors
        np.testing.assert_allclose(stds[e], noise_stds(tuner.base_noise.scaled(factors[e])), rtol=1e-12)
    assert min(eigen_min) > 0  # the live covariance stayed positive definite throughout


def test_online_tuning_is_deterministic():
    def factors():
        tuner = OnlineTuner(
            make_estimator("joint", VehicleParams()), window=100, n_agents=4, iterations=2, replay_per_step=3
        )
        _feed(tuner)
        assert tuner.runs_completed >= 1 and tuner.factors is not None  # something was tuned
        return tuner.factors

    np.testing.assert_array_equal(factors(), factors())


def test_the_likelihood_criterion_is_not_invariant_to_scaling_q_and_r_together():
    """Scaling Q and R together by c leaves the gain, hence the innovations, nearly unchanged (a
    fixed-weight sum of squared innovations cannot tell the candidates apart), but moves the
    NLL by ~m log c per step through log det S: over 300 steps the candidates x0.1, x1 and x10
    differ by hundreds of nats."""
    est = make_estimator("alo-fkf", VehicleParams())
    reading = SensorReading(RUN.sensors[:1], RUN.sensor_valid[:1], RUN.t[:1])
    est.reset(reading, np.array([RUN.scenario.speed]))
    snapshot = FilterState(*(np.array(value) for value in est.state))
    factors = np.array([[0.0] * 4, [1.0] * 4, [-1.0] * 4])
    replay = WindowReplay(est, est.noise, snapshot, RUN.sensors[1:301], RUN.sensor_valid[1:301], factors)
    replay.advance(10_000)
    assert replay.done and np.all(np.isfinite(replay.cost))
    assert np.min(np.abs(np.diff(np.sort(replay.cost)))) > 300


def test_a_candidate_whose_filter_fails_costs_inf_and_the_others_replay_on():
    """Process noise x1e60 overflows one member's covariance: that member's cost is inf, and the
    others' costs equal their replay without it (before, one failure made every cost inf)."""
    import warnings

    est = make_estimator("alo-fkf", VehicleParams())
    est.reset(SensorReading(RUN.sensors[:1], RUN.sensor_valid[:1], RUN.t[:1]), np.array([RUN.scenario.speed]))
    snapshot = FilterState(*(np.array(value) for value in est.state))
    window = RUN.sensors[1:201], RUN.sensor_valid[1:201]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the overflow itself
        mixed = WindowReplay(est, est.noise, snapshot, *window, np.array([[0.0] * 4, [60.0, 0, 0, 0], [0.5] * 4]))
        mixed.advance(10_000)
    alone = WindowReplay(est, est.noise, snapshot, *window, np.array([[0.0] * 4, [0.5] * 4]))
    alone.advance(10_000)
    assert mixed.done and alone.done and mixed.cost[1] == np.inf
    np.testing.assert_allclose(mixed.cost[[0, 2]], alone.cost, rtol=1e-12)


def test_bad_arguments():
    with pytest.raises(ValueError, match="'joint'"):
        OnlineTuner("joint")
    with pytest.raises(ValueError, match="window"):
        OnlineTuner(make_estimator("joint", VehicleParams()), window=0)
    tuner = OnlineTuner(make_estimator("joint", VehicleParams()))
    two = SensorReading(np.repeat(RUN.sensors[:1], 2, 0), np.repeat(RUN.sensor_valid[:1], 2, 0), np.zeros(2))
    with pytest.raises(ValueError, match="one vehicle"):
        tuner.reset(two, np.full(2, 10.0))

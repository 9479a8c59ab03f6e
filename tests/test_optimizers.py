"""CMA-ES and random search behind estimation.optimizers.minimize, and the batched tuning objective."""

import json
import math

import numpy as np
import pytest

from fourwis.estimation import NoiseParams
from fourwis.estimation.optimizers import minimize


def sphere(X):
    return np.sum((np.asarray(X) - 0.3) ** 2, axis=1)


def test_cmaes_finds_the_sphere_minimum_and_beats_random_search_on_the_same_budget():
    bounds = [(-2.0, 2.0)] * 5
    cma = minimize(sphere, bounds, "cmaes", n_agents=20, iterations=60, seed=1)
    rnd = minimize(sphere, bounds, "random", n_agents=20, iterations=60, seed=1)
    assert cma.n_evaluations == rnd.n_evaluations == 20 * 61
    np.testing.assert_allclose(cma.x, 0.3, atol=1e-3)
    assert cma.fun < 1e-6
    # random search: 1,220 uniform samples in a 5-D box of side 4 get within ~1 of the centre
    # (a single sample averages 7.1), far from CMA-ES
    assert rnd.fun < 1.5 and rnd.fun > 1e3 * cma.fun
    assert np.all(np.diff(cma.history) <= 0) and np.all(np.diff(rnd.history) <= 0)


@pytest.mark.parametrize("method", ["cmaes", "random"])
def test_reproducible_and_batched_equals_one_by_one(method):
    bounds = [(-2.0, 2.0)] * 5

    def one_by_one(X):
        return np.array([sphere(x[None])[0] for x in X])

    a = minimize(sphere, bounds, method, n_agents=8, iterations=10, seed=3)
    b = minimize(sphere, bounds, method, n_agents=8, iterations=10, seed=3)
    c = minimize(one_by_one, bounds, method, n_agents=8, iterations=10, seed=3)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.x, c.x)
    assert a.fun == c.fun


def test_unknown_optimizer_and_a_bad_budget_or_seed_are_named():
    with pytest.raises(ValueError, match="simplex"):
        minimize(sphere, [(-1, 1)], "simplex")
    for method in ("alo", "cmaes", "random"):
        with pytest.raises(ValueError, match="seed must be an integer >= 0, got -1"):  # cma took -1 + 1 = 0 as random
            minimize(sphere, [(-1, 1)], method, n_agents=4, iterations=2, seed=-1)
        with pytest.raises(ValueError, match=r"integers n_agents >= 2 and iterations >= 1, got 2.5, 2"):
            minimize(sphere, [(-1, 1)], method, n_agents=2.5, iterations=2)


def test_batched_tuning_objective_equals_single_replays_and_tune_writes_its_result(tmp_path):
    from fourwis.training.tune import calibration_run, replay_cost, tune

    traj = calibration_run(duration=0.6)
    X = np.array([[0.0, 0.0, 0.0, 0.0], [0.5, -0.5, 0.2, -0.2], [-1.0, 1.0, -0.5, 0.5]])
    batched = replay_cost(X, traj)
    single = np.concatenate([replay_cost(x[None], traj) for x in X])
    np.testing.assert_allclose(batched, single, rtol=1e-12)
    assert np.all(np.isfinite(batched)) and len(set(np.round(batched, 9))) == 3
    data = tune(4, 2, seed=0, out=tmp_path / "tuned.json", optimizer="cmaes", duration=0.6, progress=False)
    saved = json.loads((tmp_path / "tuned.json").read_text())
    assert saved == json.loads(json.dumps(data))
    assert saved["optimizer"] == "cmaes" and saved["evaluations"] == 12
    # what reproduces it: the seed and budget (the shipped file of an earlier version had neither)
    assert (saved["seed"], saved["n_agents"], saved["iterations"], saved["duration"]) == (0, 4, 2, 0.6)
    # the file keeps the better of the optimizer's best and the hand-set noise, and says which
    assert np.isfinite(saved["cost"]) and saved["cost"] == min(saved["optimizer_best"]["cost"], saved["default_cost"])
    assert saved["improved"] == (saved["optimizer_best"]["cost"] < saved["default_cost"])
    assert saved["optimizer_best"]["cost"] == saved["history"][-1]
    assert saved["cost"] == pytest.approx(replay_cost(np.array(saved["log10_factors"])[None], traj)[0], rel=1e-12)


def test_tune_keeps_the_hand_set_noise_when_the_optimizer_finds_nothing_better(tmp_path, monkeypatch):
    """A tuning whose best candidate is worse than the hand-set noise writes factors 0 (flagged),
    never the worse noise."""
    import fourwis.training.tune as tune_module
    from fourwis.estimation.optimizers import OptimizeResult

    worse = np.array([1.0, 1.0, 1.0, 1.0])  # every noise 10x: far above the default's cost
    monkeypatch.setattr(
        tune_module,
        "minimize",
        lambda objective, *args, **kwargs: OptimizeResult(
            worse, float(objective(worse[None])[0]), [float(objective(worse[None])[0])], 1
        ),
    )
    data = tune_module.tune(2, 1, out=tmp_path / "tuned.json", duration=0.6, progress=False)
    assert not data["improved"] and data["log10_factors"] == [0.0] * 4
    assert data["cost"] == data["default_cost"] < data["optimizer_best"]["cost"]
    assert json.loads((tmp_path / "tuned.json").read_text())["log10_factors"] == [0.0] * 4


def test_tuning_file_missing_means_hand_set_noise_a_named_one_missing_or_corrupted_raises(tmp_path, monkeypatch):
    from fourwis.estimation import joint as estimation_joint
    from fourwis.estimation.joint import tuned_noise

    for absent in (tmp_path / "absent.json", str(tmp_path / "absent.json"), tmp_path):  # a typo, a directory
        with pytest.raises(FileNotFoundError, match="absent.json|no tuning file"):
            tuned_noise(absent)
    with monkeypatch.context() as patch:  # a package without the shipped file: the hand-set noise
        patch.setattr(estimation_joint, "TUNED_NOISE_FILE", "data/absent.json")
        assert tuned_noise() is None
    shipped = tuned_noise()
    assert shipped is not None and shipped.ax_std != NoiseParams().ax_std
    for text in ("{not json", '{"cost": 1.0}', '{"log10_factors": [1, 2]}'):
        bad = tmp_path / "tuned.json"
        bad.write_text(text)
        with pytest.raises(ValueError, match="corrupted tuning file"):
            tuned_noise(bad)


def _shipped_and_hand_set(scenario_name, seeds):
    """alo-fkf with the shipped noise (column 0) and the hand-set noise (column 1) on the open-loop
    ``scenario_name``, one row per sensor seed: sideslip RMSE [rad] and mean innovation NLL per
    step. One batched run: cars 2i and 2i + 1 get generators seeded alike, hence identical
    readings (a car's readings depend only on its generator, envs.sensors.SensorModel), and
    each filter member its own noise, as in training.tune.replay (for seed 5 this reproduces
    ``replay(..., simulate(scenario_name, seed=5))``, the README's table, to the last digit)."""
    from fourwis.envs.scenarios import make_scenario
    from fourwis.envs.simulation import ClosedLoop
    from fourwis.estimation import make_estimator
    from fourwis.training.tune import SHIPPED

    scenario = make_scenario(scenario_name)
    shipped = json.loads(SHIPPED.read_text())["log10_factors"]
    factors = np.array([f for _ in seeds for f in (shipped, [0.0] * 4)])
    est = make_estimator("alo-fkf", scenario.vehicle_params, noise=NoiseParams().scaled(factors))
    loop = ClosedLoop([scenario] * len(factors), None, est, [np.random.default_rng(s) for s in seeds for _ in "ab"])
    n = int(np.ceil(scenario.duration / loop.dt - 1e-9))
    squared_error, nll = np.zeros(len(factors)), np.zeros(len(factors))
    for k in range(n + 1):
        record = loop.advance(integrate=k < n)
        squared_error += (record.estimate.beta - record.truth.beta) ** 2
        nll += est.state.last_nll
    return np.sqrt(squared_error / (n + 1)).reshape(-1, 2), (nll / (n + 1)).reshape(-1, 2)


def test_shipped_alo_noise_beats_the_hand_set_noise_on_unseen_scenarios():
    """The shipped factors were fitted by innovation likelihood on a randomised calibration run;
    on two of the paper's conditions (never used for tuning) they lower alo-fkf's mean innovation
    NLL per step, the tuning criterion, by > 5 nats on every sensor seed (measured 9.9-10.5 on
    seeds 1-8 of both: half of that is a wide margin).

    Sideslip RMSE, shipped / hand-set, measured on seeds 1-8:
    - paper_split_dlc: 0.81-0.96, every seed below 1, mean 0.884 (sd 0.051). Asserted on seeds
      1-4 (0.885, 0.910, 0.835, 0.860; e.g. 0.0051 -> 0.0045 deg): each below 1 and the mean below
      0.935, the 8-seed mean plus two standard errors of a 4-seed mean (2 x 0.051 / 2).
    - paper_dlc: 0.82-1.22 (seed 4: 1.01, seed 6: 1.22), mean 0.956, so no reliable sideslip
      gain there (the README's table shows seed 5: 0.0089 -> 0.0079 deg): only the NLL is asserted."""
    seeds = (1, 2, 3, 4)
    beta_rmse, nll = _shipped_and_hand_set("paper_split_dlc", seeds)
    ratio = beta_rmse[:, 0] / beta_rmse[:, 1]
    assert np.all(ratio < 1.0) and ratio.mean() < 0.935, ratio
    assert np.all(nll[:, 0] < nll[:, 1] - 5.0), nll
    _, nll = _shipped_and_hand_set("paper_dlc", seeds)
    assert np.all(nll[:, 0] < nll[:, 1] - 5.0), nll


def test_cmaes_leaves_numpys_global_generator_alone():
    np.random.seed(123)
    expected = np.random.random(3)
    np.random.seed(123)
    minimize(sphere, [(-1.0, 1.0)] * 2, "cmaes", n_agents=4, iterations=2, seed=0)
    np.testing.assert_array_equal(np.random.random(3), expected)
    calls = []

    def failing(X):  # an objective that raises on its second call: the generator still comes back
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("objective failed")
        return sphere(X)

    np.random.seed(123)
    with pytest.raises(RuntimeError, match="objective failed"):
        minimize(failing, [(-1.0, 1.0)] * 2, "cmaes", n_agents=4, iterations=2, seed=0)
    np.testing.assert_array_equal(np.random.random(3), expected)


def test_tuning_criteria_likelihood_and_truth_and_a_bad_name():
    """The likelihood criterion rewards a filter whose noise matches the data: shrinking R
    100-fold (overconfident) or inflating everything 100-fold (underconfident) both raise the
    mean innovation NLL above the hand-set noise's; the truth criterion is the documented sum of
    RMSEs, each over its scale; an unknown criterion is named."""
    from fourwis.envs.metrics import rmse
    from fourwis.training.tune import calibration_run, replay, replay_cost

    traj = calibration_run(duration=0.6)
    X = np.array([[0.0, 0.0, 0.0, 0.0], [0.0, -2.0, -2.0, -2.0], [2.0, 2.0, 2.0, 2.0]])
    nll = replay_cost(X, traj, criterion="nll")
    assert nll[1] > nll[0] and nll[2] > nll[0]
    truth = replay_cost(X[:1], traj, criterion="truth")
    run = replay(X[:1], traj)
    by_hand = (
        rmse(run.beta[:, 0], traj.truth.beta) / math.radians(0.1)
        + rmse(run.r[:, 0], traj.truth.r) / 0.01
        + rmse(run.u[:, 0], traj.truth.u) / 0.05
    )
    assert truth[0] == pytest.approx(by_hand, rel=1e-12) and by_hand > 0
    with pytest.raises(ValueError, match="likelihood9"):
        replay_cost(X[:1], traj, criterion="likelihood9")


def test_mu_noise_scan_rejects_a_bad_candidate_by_value():
    from fourwis.training.tune import mu_noise_scan

    with pytest.raises(ValueError, match="-0.5"):
        mu_noise_scan(grid=(0.3, -0.5), seeds=(2000,), progress=False)
    for seeds in ((), (2000, 2000), (-1,)):  # () returned NaN for every candidate
        with pytest.raises(ValueError, match="seeds must be distinct integers >= 0"):
            mu_noise_scan(grid=(0.3,), seeds=seeds, progress=False)

"""A user's own estimator and controller plug in by ``module:factory`` name wherever a name
goes (simulate, the comparison's worker processes, the Gymnasium env), and what they return is
checked, naming them (tests/custom_models.py defines them)."""

import numpy as np
import pytest

from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.training.compare import run_matrix

BIASED, DAMPER = "custom_models:biased_friction", "custom_models:yaw_damper"


def test_a_named_factory_runs_as_its_object_does_and_changes_what_the_controller_sees():
    from custom_models import BiasedFriction, YawDamper

    scenario = make_scenario("paper_step", duration=2.0)
    params = scenario.vehicle_params
    by_name = simulate(scenario, DAMPER, BIASED, seed=2)
    by_object = simulate(scenario, YawDamper(params, 0.002), BiasedFriction(params, 0.002), seed=2)
    np.testing.assert_array_equal(by_name.controls, by_object.controls)
    plain = simulate(scenario, DAMPER, "ckf", seed=2)
    np.testing.assert_allclose(by_name.estimate.mu, plain.estimate.mu + 0.1)
    assert np.any(by_name.controls != simulate(scenario, None, BIASED, seed=2).controls)  # the damper acts


def test_the_comparison_runs_them_in_its_worker_processes():
    scenario = "paper_step:duration=2.0,step_time=0.5"
    results, trajectories = run_matrix(
        [scenario], ["ckf", BIASED], ["dyc-lqr", DAMPER], seeds=1, jobs=2, progress=False
    )
    rows = {(spec.estimator, spec.controller): metrics for spec, metrics in results}
    assert set(rows) == {(e, c) for e in ("ckf", BIASED) for c in ("dyc-lqr", DAMPER)}
    # ckf holds its nominal 0.8; the user's estimator reports it 0.1 higher, and the DYC sees that
    np.testing.assert_allclose(trajectories[(scenario, "ckf", "dyc-lqr")].estimate.mu, 0.8)
    np.testing.assert_allclose(trajectories[(scenario, BIASED, "dyc-lqr")].estimate.mu, 0.9)
    assert not np.array_equal(
        trajectories[(scenario, BIASED, "dyc-lqr")].controls, trajectories[(scenario, "ckf", "dyc-lqr")].controls
    )
    assert rows[("ckf", DAMPER)]["yaw_tracking_rms"] != rows[("ckf", "dyc-lqr")]["yaw_tracking_rms"]


def test_the_env_runs_a_named_estimator():
    import gymnasium as gym

    infos = []
    for estimator in ("ckf", BIASED):
        env = gym.make("fourwis:FourWIS/YawStability-v0", scenario="paper_step", estimator=estimator)
        env.reset(seed=0)
        infos.append(env.step(np.zeros(2, dtype=np.float32))[4])
    np.testing.assert_allclose(infos[1]["estimate"].mu, infos[0]["estimate"].mu + 0.1)
    np.testing.assert_array_equal(infos[1]["truth"].mu, infos[0]["truth"].mu)


def test_bad_names_objects_and_outputs_are_named():
    from fourwis.estimation import make_estimator

    scenario = make_scenario("paper_step", duration=0.1)
    for name, match in (
        ("custom_models:nothing", "cannot import 'nothing'"),
        ("no_such_module:f", "no_such_module"),
        ("custom_models:BIASED_", "cannot import"),
    ):
        with pytest.raises(ValueError, match=match):
            make_estimator(name, scenario.vehicle_params)
    with pytest.raises(ValueError, match="given by name"):
        run_matrix(["paper_step"], [object()], ["none"], seeds=1, jobs=1, progress=False)
    with pytest.raises(ValueError, match="given by name"):
        run_matrix(["paper_step"], ["ckf"], [object()], seeds=1, jobs=1, progress=False)
    with pytest.raises(ValueError, match="cannot import 'nothing'"):
        run_matrix(["paper_step"], ["ckf"], ["custom_models:nothing"], seeds=1, jobs=1, progress=False)
    with pytest.raises(ValueError, match=r"returned mu of shape \(1,\), expected \(1, 4\)"):
        simulate(scenario, None, "custom_models:WrongShape")
    with pytest.raises(ValueError, match="Diverging.*returned a non-finite r"):
        simulate(scenario, "dyc-lqr", "custom_models:Diverging")
    with pytest.raises(ValueError, match=r"reset\(\) and step\(\)"):
        simulate(scenario, None, make_estimator)  # a factory, not an estimator
    with pytest.raises(ValueError, match="NegativeLoads.*returned fz -.*: it must be >= 0 N"):
        simulate(scenario, "dyc-lqr", "custom_models:NegativeLoads")
    with pytest.raises(
        ValueError,
        match=r"run paper_step:duration=0.1 x custom_models:NegativeLoads x dyc-lqr, seed 0: "
        "estimator .* returned fz",
    ):  # the comparison names the failing run
        run_matrix(
            ["paper_step:duration=0.1"],
            ["oracle", "custom_models:NegativeLoads"],
            ["dyc-lqr"],
            seeds=1,
            jobs=1,
            progress=False,
        )


def test_the_command_line_finds_a_module_in_the_working_directory(tmp_path, monkeypatch):
    """The `fourwis` script's sys.path holds its own folder, not the user's: main adds the latter."""
    import shutil
    import sys
    from pathlib import Path

    from fourwis.training.cli import main

    shutil.copy(Path(__file__).with_name("custom_models.py"), tmp_path / "my_filters.py")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(tmp_path))])
    main(
        [
            "compare",
            "--scenarios",
            "paper_step:duration=0.5",
            "--estimators",
            "my_filters:biased_friction",
            "--controllers",
            "none",
            "--seeds",
            "1",
            "--jobs",
            "1",
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert "my_filters:biased_friction" in (tmp_path / "out" / "runs.csv").read_text()


def test_a_users_controller_and_broken_modules_are_named():
    from fourwis.core.types import Command

    class NaNTorques:
        def reset(self):
            pass

        def __call__(self, t, estimate, front_steer, base_torques):
            return Command(np.full_like(base_torques, np.nan), np.zeros(len(base_torques)))

    scenario = make_scenario("paper_step", duration=0.1)
    with pytest.raises(ValueError, match="NaNTorques.*returned torques"):
        simulate(scenario, NaNTorques())
    with pytest.raises(ValueError, match="returned NoneType, not a fourwis.Command"):
        simulate(scenario, type("Silent", (NaNTorques,), {"__call__": lambda self, *a: None})())
    with pytest.raises(ValueError, match="custom_models:WrongShape' returned mu"):  # named as given
        simulate(scenario, None, "custom_models:WrongShape")
    with pytest.raises(ValueError, match=r"cannot import .*\(TypeError"):
        simulate(scenario, None, "..x:y")


def test_an_estimator_reusing_its_arrays_keeps_its_history_and_can_be_partly_oracled():
    """simulate keeps every step's estimate though the estimator writes into the same arrays;
    a +true-<group> wrapper works without the optional needs_truth."""
    from fourwis.training.estimate import run_metrics

    scenario = make_scenario("paper_sine", duration=1.0)
    traj = simulate(scenario, None, "custom_models:ReusesArrays", seed=0)
    np.testing.assert_allclose(traj.estimate.r, traj.sensors[:, 2])  # step by step, not the last value repeated
    assert len(np.unique(traj.estimate.r)) > 100
    partly = simulate(scenario, None, "custom_models:ReusesArrays+true-mu", seed=0)
    np.testing.assert_array_equal(partly.estimate.mu, partly.truth.mu)
    np.testing.assert_array_equal(partly.estimate.r, traj.estimate.r)
    assert run_metrics(traj)["mu_estimated"] == 0.0  # a constant mu_hat is a nominal mu
    joint = simulate(make_scenario("paper_step", duration=6.0), None, "joint", seed=0)  # (steps at 5 s)
    joint = joint._replace(estimate=joint.estimate._replace(mu_std=np.zeros_like(joint.estimate.mu_std)))
    assert run_metrics(joint)["mu_estimated"] == 1.0  # a moving mu_hat is estimated, covariance or not


def test_a_factory_that_cannot_take_params_and_dt_is_named():
    from fourwis.estimation import make_estimator

    with pytest.raises(
        ValueError, match=r"'custom_models:takes_params_only' cannot be called as factory\(params, dt\)"
    ):
        make_estimator("custom_models:takes_params_only", make_scenario("paper_step").vehicle_params, 0.002)

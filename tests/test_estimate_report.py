"""The open-loop estimation report (paper Table 2 form): convergence time on known answers, the
files of one short run, sane metrics, the paper's numbers in the Markdown, argument checks."""

import csv
import math

import numpy as np
import pytest
from scipy.stats import chi2

from fourwis.envs.metrics import mae, rmse
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.training.cli import main
from fourwis.training.estimate import (
    METRIC_UNITS,
    METRICS,
    convergence_time,
    estimate_report,
    filter_consistency,
    markdown_report,
)

T = np.arange(0.0, 5.0, 0.5)  # 0.0 .. 4.5 s


def test_convergence_time_is_the_first_time_the_error_stays_below_tolerance():
    error = np.array([0.5, 0.05, 0.3, 0.2, 0.09, 0.08, 0.05, 0.02, 0.01, 0.0])  # dips early, settles at 2.0 s
    assert convergence_time(T, error, 0.1) == 2.0
    assert convergence_time(T, np.full(T.size, 0.01), 0.1) == 0.0
    assert math.isnan(convergence_time(T, np.r_[np.zeros(T.size - 1), 0.2], 0.1))  # above at the end: never
    assert math.isnan(convergence_time(T, np.r_[np.zeros(T.size - 1), np.nan], 0.1))


def _metrics_of(traj):
    """The report's metrics of one run, from envs.metrics and the definitions in training/estimate.py's
    docstring: MAE/RMSE of u, v, beta; mean |mu error| over the wheels, averaged over the last
    half of the samples; its convergence time (NaN for an estimator with a nominal mu)."""
    truth, est = traj.truth, traj.estimate
    out = {}
    for q in ("u", "v", "beta"):
        estimate, true = getattr(est, q), getattr(truth, q)
        out[f"mae_{q}"], out[f"rmse_{q}"] = mae(estimate, true), rmse(estimate, true)
    mu_error = np.abs(est.mu - truth.mu).mean(axis=1)
    out["mu_error_last_half"] = mu_error[len(mu_error) // 2 :].mean()
    estimated = bool(np.any(est.mu_std > 0) or np.any(est.mu != est.mu[0]))
    out["mu_convergence_time"] = convergence_time(traj.t, mu_error) if estimated else math.nan
    out["mu_estimated"] = float(estimated)
    # the sigmas' consistency: RMS of error / sigma where a sigma is reported, and the share of
    # (error / sigma)^2 inside the two-sided 95% chi-square band of one degree of freedom
    for q, error, sigma in (("beta", est.beta - truth.beta, est.beta_std), ("mu", est.mu - truth.mu, est.mu_std)):
        z2 = (error[sigma > 0] / sigma[sigma > 0]) ** 2
        out[f"{q}_z_rms"] = math.sqrt(z2.mean()) if z2.size else math.nan
        inside = (z2 >= chi2.ppf(0.025, 1)) & (z2 <= chi2.ppf(0.975, 1))
        out[f"{q}_nees_in_band"] = inside.mean() if z2.size else math.nan
    return out


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("estimate")
    scenario = make_scenario("paper_sine", duration=1.5)
    return estimate_report(out, scenarios=[scenario], estimators=("ckf", "joint"), seeds=1, jobs=1)


def test_report_writes_csv_markdown_and_plot(report):
    out = report.parent
    assert report.name == "estimate.md"
    assert (out / "paper_sine.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "tyre_curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the paper's Figures 2-3
    assert "tyre_curves.png" in report.read_text()
    with open(out / "estimate.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["scenario"], r["estimator"], r["seed"]) for r in rows] == [
        ("paper_sine", "ckf", "0"),
        ("paper_sine", "joint", "0"),
    ]
    # each metric's column headed with its unit (SI: beta in rad, the convergence time in s)
    assert len(set(METRICS)) == len(METRICS)  # (a name twice: one run dict key overwrote the other)
    header = [f"{m} [{METRIC_UNITS[m]}]" for m in METRICS]
    assert list(rows[0]) == ["scenario", "estimator", "seed", *header]
    assert "mae_beta [rad]" in header and "mu_convergence_time [s]" in header and "rmse_u [m/s]" in header
    rows = [{**r, **{m: r[h] for m, h in zip(METRICS, header)}} for r in rows]
    for r in rows:  # the CSV holds the metrics of that run, recomputed here from a fresh simulation
        traj = simulate(make_scenario("paper_sine", duration=1.5), estimator=r["estimator"], seed=0)
        expected = _metrics_of(traj) | filter_consistency(traj, r["estimator"])  # (its NEES / NIS: 0045)
        # 6 significant digits; NaN (a convergence that never came) as the one missing value, an empty field
        assert {m: r[m] for m in METRICS} == {m: "" if math.isnan(v) else f"{v:.6g}" for m, v in expected.items()}
    ckf, joint = rows
    assert ckf["rmse_beta"] != joint["rmse_beta"]  # two different filters, not one run written twice
    assert float(ckf["mu_estimated"]) == 0.0 and ckf["mu_convergence_time"] == ""
    assert "nan" not in (out / "estimate.csv").read_text().lower()
    assert float(joint["mu_estimated"]) == 1.0
    assert abs(float(ckf["mu_error_last_half"]) - 0.0) < 1e-9  # paper_sine: mu 0.8 = ckf's nominal mu


def test_markdown_has_our_table_and_the_papers_numbers(report):
    text = report.read_text()
    assert "## paper_sine" in text and "| ckf |" in text and "| joint |" in text
    for number in (  # u and v [m/s] as printed; the sideslip read as rad, in degrees
        "0.0050",
        "0.0274",
        "0.1432",  # 0.0025 rad
        "0.0008",
        "0.0024",
        "0.0115",  # 0.0002 rad
        "0.0063",
        "0.0572",
        "0.2979",  # 0.0052 rad
        "0.0010",
        "0.0040",
        "0.0172",  # 0.0003 rad
    ):
        assert number in text
    assert "not run" in text  # paper_dlc was not in this run
    assert "no sensor noise" in text


@pytest.mark.parametrize(
    "kwargs, named",
    [
        ({"scenarios": ["no_such_road"]}, "no_such_road"),
        ({"scenarios": ["paper_step:mu=-1"]}, "-1"),
        ({"scenarios": ["paper_step+faults"]}, r"\+faults"),
        ({"estimators": ["kalman9"]}, "kalman9"),
        ({"seeds": 0}, "seeds must be .*, got 0"),
        ({"jobs": 0}, "jobs must be >= 1, got 0"),
    ],
)
def test_bad_arguments_raise_value_error_naming_the_value(tmp_path, kwargs, named):
    with pytest.raises(ValueError, match=named):
        estimate_report(tmp_path, **kwargs)
    assert not any(tmp_path.iterdir())


def test_cli_turns_a_bad_argument_into_a_clean_exit(tmp_path):
    with pytest.raises(SystemExit, match="fourwis estimate: unknown estimator.*kalman9"):
        main(["estimate", "--estimators", "kalman9", "--out", str(tmp_path)])


def test_ratio_section_divides_each_sideslip_rmse_by_fkfs():
    scenarios = [make_scenario("paper_dlc"), make_scenario("paper_step")]
    table = {}
    for s, fkf_rmse in zip(scenarios, (0.004, 0.010)):
        for e, factor in (("fkf", 1.0), ("alo-fkf", 0.5), ("joint", 1.25)):
            table[(s.name, e)] = {**dict.fromkeys(METRICS, 0.1), "rmse_beta": fkf_rmse * factor}
    text = markdown_report(table, scenarios, ("fkf", "alo-fkf", "joint"), 1)
    assert "| scenario | alo-fkf / fkf | joint / fkf |" in text
    assert "| paper_dlc | 0.500 | 1.250 |" in text and "| paper_step | 0.500 | 1.250 |" in text
    assert "0.058 (0.0003 / 0.0052)" in text  # the paper's ALO-FKF / FKF on its DLC
    assert "relative to fkf" not in markdown_report(table, scenarios, ("alo-fkf", "joint"), 1)


def test_the_convergence_column_tells_a_true_mu_from_a_nominal_one():
    """An estimator that reports the truth's mu (oracle, +true-mu) is labelled so, not as holding
    a nominal mu (ckf on paper_sine even holds the road's 0.8)."""
    from fourwis.training.estimate import _convergence

    held = {"mu_estimated": 0.0, "mu_convergence_time": math.nan}
    assert _convergence(held, "joint+true-mu") == _convergence(held, "oracle") == "n/a (true mu)"
    assert _convergence(held, "joint+true-beta") == _convergence(held, "ckf") == "n/a (nominal mu)"
    assert _convergence({"mu_estimated": 1.0, "mu_convergence_time": 1.25}, "joint") == "1.25"


def test_a_true_mu_is_not_counted_as_estimated_where_the_road_changes(tmp_path):
    from fourwis.training.estimate import run_all

    results, _ = run_all([make_scenario("mu_jump", duration=2.5)], ["oracle", "ckf+true-mu"], 1, jobs=1, progress=False)
    for spec, metrics in results:
        assert metrics["mu_estimated"] == 0.0 and math.isnan(metrics["mu_convergence_time"]), spec.estimator


def test_scenarios_take_the_comparisons_overrides_and_are_named_by_them():
    from fourwis.training.estimate import _scenarios

    wet, dry, swd = _scenarios(["paper_step:mu=0.5", "paper_step", "swd_wet"])
    assert (wet.name, dry.name, swd.name) == ("paper_step:mu=0.5", "paper_step", "swd_wet")
    assert wet.road.mu_at(np.array([50.0]), np.array([0.0]))[0] == 0.5
    assert wet.road != dry.road and swd.road.mu_at(np.array([0.0]), np.array([0.0]))[0] == 0.5


def test_road_mu_gives_the_fixed_mu_filters_the_roads_friction_and_leaves_joint_alone():
    """The paper's reading of its section-3 filters: they know the road's friction. On the
    step's 0.3 road the fixed-mu filter then holds 0.3 (no mu error) and its sideslip error
    falls (0.92 -> 0.67 deg over 5 seeds, README); the joint estimator runs as ever."""
    from fourwis.training.estimate import road_friction, run_all

    scenario = make_scenario("paper_step", duration=7.0)
    assert road_friction(scenario) == pytest.approx(0.3)
    assert road_friction(make_scenario("paper_split_dlc")) == pytest.approx(0.4)  # two wheels on each side
    runs = {}
    for road_mu in (False, True):
        results, _ = run_all([scenario], ["fkf", "joint"], 1, jobs=1, progress=False, road_mu=road_mu)
        runs.update({(spec.estimator, road_mu): metrics for spec, metrics in results})
    assert runs[("fkf", True)]["mu_error_last_half"] < 1e-12 < runs[("fkf", False)]["mu_error_last_half"]
    assert runs[("fkf", True)]["rmse_beta"] < 0.9 * runs[("fkf", False)]["rmse_beta"]
    assert runs[("joint", True)] == runs[("joint", False)]


def test_the_report_says_who_wrote_it_and_gives_the_sideslip_in_degrees(report):
    text = report.read_text()
    head = text.split("Runs:")[0]
    for field in ("- command: `", "- commit: ", "- date: ", "- host: "):
        assert field in head
    tables = [line for line in text.splitlines() if line.startswith("|")]
    assert any("MAE beta [deg]" in line for line in tables) and not any("rad" in line for line in tables)


def test_the_scenario_plot_names_its_seed_and_draws_degrees(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from fourwis.training.estimate import plot_scenario, run_all

    seen = {}
    close = plt.close

    def keep(fig=None):
        seen["title"] = fig._suptitle.get_text()
        seen["panels"] = [ax.get_title() for ax in fig.axes]
        close(fig)

    _, series = run_all(["paper_sine:duration=1"], ["ckf"], 1, 1, progress=False)
    monkeypatch.setattr(plt, "close", keep)
    plot_scenario("paper_sine:duration=1", series, ["ckf"], tmp_path / "p.png")
    assert seen["title"] == "paper_sine:duration=1: estimates vs truth (open loop, seed 0)"
    assert "sideslip beta [deg]" in seen["panels"]

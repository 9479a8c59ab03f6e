"""The comparison's scenario syntax and a small matrix run."""

import math

import pytest

from fourwis.control.reference import STABLE_SIDESLIP, rear_steer_gain, sideslip_bound_of
from fourwis.envs.vehicle import VehicleParams
from fourwis.training.compare import SWD_MU, SWD_MULTIPLE, build_scenario, entry_A, parse_scenario, run_matrix


def test_scenario_entries_parse_into_name_and_overrides():
    assert parse_scenario("iso3888_2") == ("iso3888_2", {})
    assert parse_scenario("iso3888_2:mu=0.5,speed_kph=50") == ("iso3888_2", {"mu": 0.5, "speed_kph": 50.0})
    assert parse_scenario("swd_wet") == ("sine_with_dwell", {"mu": SWD_MU, "amplitude_A": SWD_MULTIPLE})
    # a split road as a JSON list; swd_wet takes overrides on top of its own
    assert parse_scenario("iso3888_2:mu=[0.5, 0.3],speed_kph=40") == ("iso3888_2", {"mu": [0.5, 0.3], "speed_kph": 40})
    assert parse_scenario("swd_wet:mu=0.3+faults") == ("sine_with_dwell", {"mu": 0.3, "amplitude_A": SWD_MULTIPLE})
    for bad, word in (
        ("iso9999", "iso9999"),
        ("iso3888_2:mu=wet", "mu=wet"),
        ("paper_dlc:amplitude_A=3", "only"),
        ("paper_dlc:warp=3", "warp"),
        ("paper_dlc:mu=-1", "mu"),
        ("iso3888_2:mu=[0.5,true]", "true"),
        ("iso3888_2:mu=[0.5,0.3,0.2]", r"0\.2"),
        ("swd_wet:warp=1", "warp"),
        ("sine_with_dwell:amplitude_A=6.5,amplitude_deg=50", "not both"),
        ("sine_with_dwell:amplitude_A=-1", "amplitude_A must be"),
    ):
        with pytest.raises(ValueError, match=word):
            parse_scenario(bad)


def test_sine_with_dwell_steers_multiples_of_the_driven_cars_A():
    """The paper's 4WS (eq. 20, in phase at 80 km/h: gain k) lowers the neutral car's steady yaw
    gain by (1 - k) and takes away the lag of its sideslip build-up, so its A lies between the
    2WS car's and 1/(1 - k) times it; swd_wet on that car steers 5.5 of its own A."""
    A_2ws, A_4ws = entry_A("swd_wet"), entry_A("swd_wet:rear_steer_feedforward=1")
    k = float(rear_steer_gain(80 / 3.6, VehicleParams()))
    assert A_2ws < A_4ws < A_2ws / (1 - k)
    scenario = build_scenario("swd_wet:rear_steer_feedforward=1", A_4ws)
    assert scenario.vehicle_params.rear_steer_feedforward
    assert scenario.steering.amplitude == pytest.approx(SWD_MULTIPLE * A_4ws, rel=1e-12)
    assert math.isnan(entry_A("paper_step"))


def test_a_matrix_axis_with_a_repeated_entry_is_refused():
    for axes, word in (
        ((["paper_step", "paper_step"], ["oracle"], ["none"]), "scenarios"),
        ((["paper_step"], ["oracle", "oracle"], ["none"]), "estimators"),
        ((["paper_step"], ["oracle"], ["none", "none"]), "controllers"),
    ):
        with pytest.raises(ValueError, match=f"{word} must be distinct"):
            run_matrix(*axes, seeds=1, jobs=1, progress=False)


def test_overrides_reach_the_runs():
    """A slower, shorter paper_sine on a lower mu: metrics finite and the open-loop truth
    carries the overridden friction."""
    results, trajectories = run_matrix(
        ["paper_sine:mu=0.4,duration=1.0"], ["oracle"], ["none"], seeds=1, jobs=1, progress=False
    )
    ((spec, metrics),) = results
    traj = trajectories[(spec.scenario, "oracle", "none")]
    assert traj.t[-1] == pytest.approx(1.0)
    assert traj.truth.mu[0] == pytest.approx([0.4] * 4)
    assert all(math.isfinite(v) for v in metrics.values())


def test_cli_names_bad_scenarios_and_controllers():
    from fourwis.training.cli import main

    with pytest.raises(SystemExit, match="iso9999"):
        main(["compare", "--scenarios", "iso9999", "--out", "unused"])
    with pytest.raises(SystemExit, match="nowhere"):
        main(["swd", "--mu", "1.0", "--A", "16.6", "--controller", "rl:nowhere"])
    with pytest.raises(SystemExit, match="warp"):
        main(["swd", "--mu", "1.0", "--A", "16.6", "--controller", "warp"])
    for args, match in (
        (["--mu", "0"], r"--mu must be a friction coefficient in \(0, 2.0\], got 0.0"),
        (["--estimator", "nope"], "nope"),
        (["--A", "-5"], "-5.0"),
        (["--seed", "-2"], "-2"),
    ):
        with pytest.raises(SystemExit, match=match):  # before the characterisation runs
            main(["swd", *args])
    with pytest.raises(SystemExit, match="kalman"):
        main(["simulate", "paper_step", "--estimator", "kalman"])


def test_integer_overrides_stay_integers():
    """A seed override reaches the scenario as an int (a float seed is refused by numpy)."""
    from fourwis.training.compare import parse_scenario

    assert parse_scenario("random:seed=3,speed_kph=50.5") == ("random", {"seed": 3, "speed_kph": 50.5})
    assert parse_scenario("paper_step:rear_steer_feedforward=1") == ("paper_step", {"rear_steer_feedforward": True})
    with pytest.raises(ValueError, match="rear_steer_feedforward must be True or False, got 2"):
        parse_scenario("paper_step:rear_steer_feedforward=2")


def test_report_is_reproducible_byte_for_byte_in_one_or_two_processes_and_the_fault_variant_bites(tmp_path):
    """Two seeds run in one worker process and then spread over two (as `make compare` does):
    runs.csv is byte-identical. Gyro spikes and a stuck gyro raise ckf's yaw-rate error."""
    from fourwis.training.compare import compare

    scenarios = ["paper_sine:duration=1.0", "paper_sine:duration=1.0+faults"]
    reports = [
        compare(tmp_path / name, scenarios, ["ckf"], ["none", "dyc-lqr"], seeds=2, jobs=jobs)
        for name, jobs in (("a", 1), ("b", 2))
    ]
    csv_a = (tmp_path / "a" / "runs.csv").read_bytes()
    assert csv_a == (tmp_path / "b" / "runs.csv").read_bytes()
    for name in ("report.md", "runs.csv", "peak_sideslip.png", "pass_rate.png"):
        assert (tmp_path / "a" / name).stat().st_size > 0
    text = reports[0].read_text()
    assert "paper_sine:duration=1.0+faults" in text
    header, *lines = csv_a.decode().splitlines()
    header = header.split(",")
    rows = {(r[0], r[2], r[3]): r for r in (line.split(",") for line in lines)}
    assert len(rows) == len(lines) == 2 * 2 * 2  # scenarios x controllers x seeds, each once
    assert rows[("paper_sine:duration=1.0", "none", "0")][5:] != rows[("paper_sine:duration=1.0", "none", "1")][5:]
    col = header.index("rmse_r [rad/s]")
    for seed in ("0", "1"):  # measured: 0.0019 -> 0.0081 and 0.0019 -> 0.0119 rad/s
        clean = float(rows[("paper_sine:duration=1.0", "none", seed)][col])
        faulty = float(rows[("paper_sine:duration=1.0+faults", "none", seed)][col])
        assert faulty > 1.5 * clean  # gyro spikes and a stuck gyro degrade the yaw-rate estimate


def test_control_effort_is_zero_without_control_and_reflects_the_dyc_moment_and_rear_steer():
    """The step on mu 0.3 at 40 km/h: the uncontrolled car's equal drive torques make no yaw
    moment; DYC-LQR's differential torques do, and only the 4WS variant steers the rear."""
    results, _ = run_matrix(
        ["paper_step:duration=7.0"], ["oracle"], ["none", "dyc-lqr", "dyc-lqr-4ws"], seeds=1, jobs=1, progress=False
    )
    effort = {spec.controller: (m["yaw_moment_rms"], m["rear_steer_rms"]) for spec, m in results}
    assert effort["none"][0] < 1.0 and effort["none"][1] == 0.0
    assert effort["dyc-lqr"][0] > 50.0 and effort["dyc-lqr"][1] == 0.0
    assert effort["dyc-lqr-4ws"][1] > 1e-3


def test_partial_oracles_attribute_the_joint_estimators_closed_loop_loss_to_its_friction():
    """DYC-LQR on the step (mu 0.3, sensor seed 0): the joint estimator's peak sideslip exceeds the
    oracle's; the road's true friction with everything else estimated closes the larger part of that
    gap, the true sideslip next to none, and the true friction and yaw rate together nearly all of
    it: the stable region's yaw-rate rules (0042) read r_hat. Measured 2026-12-07: oracle 0.288,
    joint 0.387, joint+true-mu 0.324 (0.64 of the gap), joint+true-beta 0.386, joint+true-mu-r
    0.292 deg (0.96); before 0042, 0.408, 0.479, 0.404 (all of it), 0.479."""
    results, _ = run_matrix(
        ["paper_step"],
        ["oracle", "joint", "joint+true-mu", "joint+true-beta", "joint+true-mu-r"],
        ["dyc-lqr"],
        seeds=1,
        jobs=1,
        progress=False,
    )
    peak = {spec.estimator: m["peak_beta"] for spec, m in results}
    gap = peak["joint"] - peak["oracle"]
    assert gap > 0.05 * peak["oracle"]  # a loss to attribute
    assert peak["joint"] - peak["joint+true-mu"] > 0.5 * gap
    assert abs(peak["joint"] - peak["joint+true-beta"]) <= 0.25 * gap
    assert peak["joint"] - peak["joint+true-mu-r"] >= 0.9 * gap


def test_the_phase_plane_peak_tells_a_spin_and_a_fixed_mu_slide_from_a_held_car():
    """The wet sine with dwell (mu 0.5): the uncontrolled car spins far outside the sideslip
    phase-plane region (index > 5), DYC with the oracle stays inside it (< 1) with its sideslip short
    of where the sideslip moment acts (0.6 of the bound), DYC with the dry-road ckf leaves it though
    its sideslip stays under the 20 deg spin-out threshold. Measured 2026-12-07: 10.21, 0.742 (peak
    sideslip 2.0 deg of a 3.4 deg threshold), 1.72; 0.49 and 1.54 before 0042: the yaw reference
    bounded after its lag flips at the steer reversal within ~0.15 s, the car overshoots it (-0.29
    against -0.19 rad/s at 1.95 s, the index's peak) and is braked back."""
    results, _ = run_matrix(["swd_wet"], ["oracle", "ckf"], ["none", "dyc-lqr"], seeds=1, jobs=1, progress=False)
    peak = {(spec.estimator, spec.controller): m["phase_plane_peak"] for spec, m in results}
    spun = {(spec.estimator, spec.controller): m["spin_out"] for spec, m in results}
    held = {(spec.estimator, spec.controller): m["peak_beta"] for spec, m in results}
    assert peak[("oracle", "none")] > 5.0 and spun[("oracle", "none")] == 1.0
    assert peak[("oracle", "dyc-lqr")] < 1.0 and spun[("oracle", "dyc-lqr")] == 0.0
    assert held[("oracle", "dyc-lqr")] < STABLE_SIDESLIP * sideslip_bound_of(SWD_MU)
    assert peak[("ckf", "dyc-lqr")] > 1.0 and spun[("ckf", "dyc-lqr")] == 0.0


def test_a_car_that_stops_short_of_the_course_end_has_not_passed_it():
    """ISO 3888-2 at 10 km/h: the coasting car stops at X ~ 31 m of a course whose last cones
    stand at X = 61 m, with no cone touched; at 60 km/h it drives through, and it has also
    when the run ends 7 s in, past the last cones (X ~ 72 m) but short of the end of the
    driver's line, which runs on to X = 91 m (a car slowed by its controller ends there)."""
    results, _ = run_matrix(
        ["iso3888_2:speed_kph=10", "iso3888_2", "iso3888_2:duration=7"],
        ["oracle"],
        ["none"],
        seeds=1,
        jobs=2,
        progress=False,
    )
    verdict = {spec.scenario: (m["course_completed"], m["passed"], m["cone_hits"]) for spec, m in results}
    assert verdict == {
        "iso3888_2:speed_kph=10": (0.0, 0.0, 0.0),
        "iso3888_2": (1.0, 1.0, 0.0),
        "iso3888_2:duration=7": (1.0, 1.0, 0.0),
    }


def test_spellings_of_one_scenario_and_a_key_given_twice_are_refused():
    with pytest.raises(ValueError, match=r"\['paper_step: duration=0.2', 'paper_step:duration=0.20'\] run the same"):
        run_matrix(
            ["paper_step: duration=0.2", "paper_step:duration=0.20"],
            ["oracle"],
            ["none"],
            seeds=1,
            jobs=1,
            progress=False,
        )
    for pair in (
        ["paper_step:mu=0.3,duration=0.2", "paper_step:duration=0.2,mu=0.3"],  # (these two ran twice)
        ["paper_step:duration=1", "paper_step:duration=1.0"],
    ):
        with pytest.raises(ValueError, match="run the same"):
            run_matrix(pair, ["oracle"], ["none"], seeds=1, jobs=1, progress=False)
    for jobs in (2.5, "2", True):  # refused before any run, not as a TypeError at the first result
        with pytest.raises(ValueError, match=f"jobs must be an integer .*, got {jobs!r}"):
            run_matrix(["paper_step:duration=0.2"], ["oracle"], ["none"], seeds=1, jobs=jobs, progress=False)
    with pytest.raises(ValueError, match="mu is given twice"):
        parse_scenario("iso3888_2:mu=0.5,mu=0.3")


def test_a_failing_run_is_named_and_keeps_its_error_type():
    """A plain ValueError gets the run in its message (the command line prints that); an error
    type built from more than a message keeps itself and gets the run as a note."""
    from types import SimpleNamespace

    from fourwis.training.compare import naming_the_run

    spec = SimpleNamespace(scenario="paper_step", estimator="joint", controller="dyc-lqr", seed=3)

    def failing(error):
        return naming_the_run(lambda spec: (_ for _ in ()).throw(error))

    with pytest.raises(ValueError, match="^run paper_step x joint x dyc-lqr, seed 3: loads must be >= 0$"):
        failing(ValueError("loads must be >= 0"))(spec)
    with pytest.raises(UnicodeDecodeError) as raised:
        failing(UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte"))(spec)
    assert raised.value.__notes__ == ["in run paper_step x joint x dyc-lqr, seed 3"]


def test_output_folders_must_be_named():
    from fourwis.training.io import check_writable

    for empty in ("", "  "):
        with pytest.raises(ValueError, match="--out must not be empty"):
            check_writable(empty)


def test_the_report_shows_each_estimator_against_the_oracle():
    """Ratios of the seed means to the oracle's under the same controller, bold above 1.10, none
    where the oracle's value is at the noise floor; no section without the oracle or a controller."""
    from fourwis.training.compare import RunSpec, markdown_report

    metrics = (
        "peak_beta",
        "phase_plane_peak",
        "yaw_tracking_rms",
        "spin_out",
        "yaw_moment_rms",
        "rmse_u",
        "rmse_v",
        "rmse_beta",
        "mae_beta",
        "rmse_r",
        "rmse_mu",
        "final_mu_error",
    )

    def run(peak_beta: float, yaw: float) -> dict:
        return {m: 0.0 for m in metrics} | {"peak_beta": peak_beta, "yaw_tracking_rms": yaw}

    table = {
        ("paper_step", "oracle", "dyc-lqr"): run(0.010, 0.020),
        ("paper_step", "joint", "dyc-lqr"): run(0.0122, 0.021),
        ("paper_step", "ckf", "dyc-lqr"): run(0.031, 0.0219),
    }
    table |= {("paper_dlc", e, "dyc-lqr"): run(0.0004, 0.020) for e in ("oracle", "joint", "ckf")}
    table |= {(s, e, "none"): run(0.02, 0.03) for s in ("paper_step", "paper_dlc") for e in ("oracle", "joint", "ckf")}

    def runs(table: dict) -> list:  # one seed per cell
        return [(RunSpec(s, e, c, 0, math.nan), m) for (s, e, c), m in table.items()]

    text = markdown_report(runs(table), ["paper_step", "paper_dlc"], ["oracle", "joint", "ckf"], ["none", "dyc-lqr"], 1)
    section = text.split("## Against the oracle")[1].split("##")[0]
    assert "| scenario | controller | joint | ckf |" in section and "| none |" not in section
    assert "| paper_step | dyc-lqr | **1.22** / 1.05 | **3.10** / 1.09 |" in section
    assert "| paper_dlc | dyc-lqr | — / 1.00 | — / 1.00 |" in section  # (0.0004 rad: below the floor)
    for estimators, controllers in ((["joint", "ckf"], ["none", "dyc-lqr"]), (["oracle", "joint", "ckf"], ["none"])):
        sub = {key: value for key, value in table.items() if key[1] in estimators and key[2] in controllers}
        text = markdown_report(runs(sub), ["paper_step", "paper_dlc"], estimators, controllers, 1)
        assert "Against the oracle" not in text


#: a report's header as a test gives it (the real one: training.provenance.provenance())
HEADER_FIELDS = dict(command="fourwis compare --seeds 2", commit="0123456789ab", date="2026-12-01T00:00:00+00:00")


def _metrics(**given) -> dict:
    """One run's metrics (run_metrics' keys) with ``given`` values over zeros."""
    from fourwis.training.compare import METRIC_UNITS

    course = ("path_rms", "path_max", "cone_hits", "course_completed")
    swd = ("swd_ratio_1000", "swd_ratio_1750", "swd_displacement", "swd_passed", "swd_responsive")
    braking = ("stop_distance", "stop_ratio", "longest_lock")
    base = {m: 0.0 for m in METRIC_UNITS if m not in course + swd + braking}
    return base | {"passed": 1.0} | given


def test_the_report_gives_each_cell_a_verdict_naming_the_failed_criteria_and_counts_spin_outs():
    from fourwis.training.compare import RunSpec, failed_criteria, markdown_report
    from fourwis.training.provenance import Provenance

    swd_ok = dict(swd_ratio_1000=0.1, swd_ratio_1750=0.05, swd_displacement=2.0, swd_passed=1.0, swd_responsive=1.0)
    course_ok = dict(path_rms=0.1, path_max=0.3, cone_hits=0.0, course_completed=1.0)
    runs = {
        ("swd_wet", "oracle", "dyc-lqr"): [
            _metrics(**swd_ok | dict(swd_displacement=1.5, swd_responsive=0.0, swd_passed=0.0, passed=0.0)),
            _metrics(**swd_ok),
        ],
        ("swd_wet", "oracle", "none"): [
            _metrics(**swd_ok | dict(swd_ratio_1000=1.0, swd_ratio_1750=0.9, swd_passed=0.0), spin_out=1.0, passed=0.0)
        ]
        * 2,
        ("iso3888_2", "oracle", "dyc-lqr"): [
            _metrics(**course_ok | dict(cone_hits=2.0), passed=0.0),
            _metrics(**course_ok),
        ],
        ("iso3888_2", "oracle", "none"): [
            _metrics(**course_ok | dict(course_completed=0.0), spin_out=1.0, passed=0.0),
            _metrics(**course_ok),
        ],
    }
    results = [(RunSpec(s, e, c, k, math.nan), m) for (s, e, c), cell in runs.items() for k, m in enumerate(cell)]
    for _, m in results:  # the verdict judges as `passed` does (a cone displaced: not a valid pass)
        assert (not failed_criteria(m)) == (m["passed"] == 1.0)
    header = Provenance(**HEADER_FIELDS, host="testhost (2 CPUs)")
    text = markdown_report(results, ["swd_wet", "iso3888_2"], ["oracle"], ["none", "dyc-lqr"], 2, header)
    for line in ("- command: `fourwis compare --seeds 2`", "- commit: 0123456789ab", "- host: testhost (2 CPUs)"):
        assert line in text
    assert "- date: 2026-12-01T00:00:00+00:00" in text and "seeds 0-1" in text
    rows = {
        tuple(cell.strip() for cell in line.split("|")[1:4]): line for line in text.splitlines() if "| oracle |" in line
    }

    def cells(key):
        return [cell.strip() for cell in rows[key].split("|")[4:-1]]

    assert "| verdict |" in text and "| spin-outs |" in text
    assert cells(("swd_wet", "dyc-lqr", "oracle"))[0] == "FAIL 1/2: FMVSS responsiveness 1"
    assert cells(("swd_wet", "none", "oracle"))[0] == "FAIL 2/2: spin-out 2, FMVSS yaw 1.0 s 2, FMVSS yaw 1.75 s 2"
    assert cells(("iso3888_2", "dyc-lqr", "oracle"))[0] == "FAIL 1/2: cones 1"
    assert cells(("iso3888_2", "none", "oracle"))[0] == "FAIL 1/2: spin-out 1, course 1"
    spins = {key: cells(key)[4] for key in rows}  # counts of seeds, not means
    assert spins[("swd_wet", "none", "oracle")] == "2/2" and spins[("iso3888_2", "none", "oracle")] == "1/2"
    assert spins[("swd_wet", "dyc-lqr", "oracle")] == "0/2"
    assert "## Estimation accuracy" not in text  # the oracle alone: no rows of zeros
    # passes per criterion over the runs each applies to (responsiveness: the runs from 5A)
    assert "| dyc-lqr | oracle | 4/4 | 2/2 | 1/2 | 2/2 | 2/2 | 1/2 |" in text
    assert "| none | oracle | 1/4 | 1/2 | 2/2 | 0/2 | 0/2 | 2/2 |" in text
    for criterion in ("spin-out", "course", "cones", "FMVSS yaw 1.0 s", "FMVSS yaw 1.75 s", "FMVSS responsiveness"):
        assert f"*{criterion}*:" in text  # each criterion explained in the report itself
    assert "[rad" not in text  # degrees in every table


def test_runs_csv_heads_each_metric_with_its_unit_and_has_one_missing_value(tmp_path):
    import csv

    from fourwis.training.compare import METRIC_UNITS, RunSpec, write_csv

    results = [
        (RunSpec("paper_step", "joint", "none", 0, math.nan), _metrics(peak_beta=0.01, rmse_mu=math.nan)),
        (
            RunSpec("iso3888_2", "joint", "none", 0, math.nan),
            _metrics(path_rms=0.1, path_max=0.2, cone_hits=3.0, course_completed=1.0, spin_out=1.0, passed=0.0),
        ),
    ]
    path = write_csv(results, tmp_path / "runs.csv")
    with open(path, newline="") as f:
        header, *rows = list(csv.reader(f))
    assert header[:5] == ["scenario", "estimator", "controller", "seed", "verdict"]
    assert all(h.endswith(f" [{METRIC_UNITS[h.split(' [')[0]]}]") for h in header[5:])
    assert {"peak_beta [rad]", "yaw_tracking_rms [rad/s]", "cone_hits [count]", "spin_out [0/1]"} <= set(header)
    column = {h.split(" [")[0]: i for i, h in enumerate(header)}
    step, iso = rows
    assert step[4] == "pass" and iso[4] == "fail: spin-out; cones"
    assert step[column["rmse_mu"]] == "" and step[column["path_rms"]] == ""  # NaN and "does not apply" alike
    assert iso[column["cone_hits"]] == "3" and "nan" not in path.read_text().lower()


def test_the_plots_draw_the_reference_yaw_rate_and_name_their_seeds(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt
    import numpy as np

    from fourwis.training.compare import compare, run_matrix
    from fourwis.training.trajectory_io import reference_yaw_rate_of

    figures = {}
    close = plt.close

    def keep(fig=None):  # the figures' contents, taken as the report closes them
        if fig is not None and fig.axes:
            title = fig._suptitle.get_text() if fig._suptitle else fig.axes[0].get_title()
            figures[title] = [[(line.get_label(), line.get_ydata()) for line in ax.get_lines()] for ax in fig.axes]
        close(fig)

    monkeypatch.setattr(plt, "close", keep)
    compare(tmp_path, ["paper_step:duration=6"], ["oracle"], ["none", "dyc-lqr"], seeds=2, jobs=1)
    titles = sorted(figures)
    assert any("peak sideslip" in t.lower() and "mean over seeds 0-1" in t for t in titles), titles
    assert any(t.startswith("pass rate over seeds 0-1") for t in titles), titles
    yaw_panel = figures["paper_step:duration=6 (seed 0)"][0]
    labels = [label for label, _ in yaw_panel]
    assert "dotted: its reference (2-DOF, true mu)" in labels
    _, trajectories = run_matrix(["paper_step:duration=6"], ["oracle"], ["dyc-lqr"], 1, 1, progress=False)
    reference = np.degrees(reference_yaw_rate_of(trajectories[("paper_step:duration=6", "oracle", "dyc-lqr")]))
    assert any(np.allclose(ydata, reference) for _, ydata in yaw_panel)  # the controlled run's own reference
    assert np.max(np.abs(reference)) > 5.0  # (the step turns the car: a reference worth drawing)


def test_real_runs_are_judged_as_their_pass_flag_says_and_the_report_names_what_failed(tmp_path):
    """On the wet sine with dwell and ISO 3888-2 at 70 km/h the uncontrolled car spins: its
    verdict says so in runs.csv and in the report; every run's verdict agrees with its `passed`
    flag, the cones included."""
    import csv

    from fourwis.training.compare import compare

    report = compare(tmp_path, ["swd_wet", "iso3888_2:speed_kph=70"], ["oracle"], ["none", "dyc-lqr"], 1, 1)
    with open(tmp_path / "runs.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4
    for row in rows:
        failed = set(row["verdict"].removeprefix("fail: ").split("; ")) if row["verdict"] != "pass" else set()
        assert (not failed) == (row["passed [0/1]"] == "1"), row
        assert ("spin-out" in failed) == (row["spin_out [0/1]"] == "1")
        assert ("cones" in failed) == (row["cone_hits [count]"] not in ("", "0"))
    uncontrolled = {row["scenario"]: row["verdict"] for row in rows if row["controller"] == "none"}
    assert all("spin-out" in verdict for verdict in uncontrolled.values()), uncontrolled
    text = report.read_text()
    assert "| swd_wet | none | oracle | FAIL 1/1: spin-out 1" in text


def test_the_report_tables_straight_line_braking_for_its_scenarios_only():
    """Constructed runs: a straight_braking cell's stopping distance, its ratio to the ideal stop and
    the longest lock appear in their own table, as means over seeds; a report without the scenario
    has no such table."""
    from fourwis.training.compare import RunSpec, markdown_report
    from fourwis.training.provenance import Provenance

    stops = [dict(stop_distance=40.0, stop_ratio=1.02, longest_lock=0.0), dict(stop_distance=42.0, stop_ratio=1.06,
                                                                                longest_lock=0.1)]  # fmt: skip
    results = [(RunSpec("straight_braking:mu=1.0", "oracle", "none", k, math.nan), _metrics(**m)) for k, m in
               enumerate(stops)]  # fmt: skip
    header = Provenance(**HEADER_FIELDS, host="testhost (2 CPUs)")
    text = markdown_report(results, ["straight_braking:mu=1.0"], ["oracle"], ["none"], 2, header)
    assert "## Straight-line braking" in text
    assert "| straight_braking:mu=1.0 | none | oracle | 41.0 | 1.040 | 0.050 |" in text
    other = [(RunSpec("paper_sine", "oracle", "none", 0, math.nan), _metrics())]
    assert "Straight-line braking" not in markdown_report(other, ["paper_sine"], ["oracle"], ["none"], 1, header)

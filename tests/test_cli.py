"""The command line's contract: truthful step counts, no silent overwrite, bad options refused
before any work (naming the option), the same --jobs rule everywhere, help for every option."""

import argparse
import json
import math
import os
import shutil

import numpy as np
import pytest

from fourwis.training.cli import build_parser, main

#: a PPO run of 4 cars: whole rollouts of 256 x 4 = 1024 env steps, so 1500 requested -> 2048 trained
TRAIN = [
    "train",
    "--n-envs",
    "4",
    "--env-kwargs",
    '{"estimator": "oracle"}',
    "--eval-every",
    "100000",
    "--checkpoint-every",
    "1024",
]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A finished run trained with --timesteps 1500 (read-only: tests that change it copy it)."""
    out = tmp_path_factory.mktemp("cli") / "run"
    main([*TRAIN, "--timesteps", "1500", "--out", str(out)])
    return out


def _copy(run, tmp_path):
    return shutil.copytree(run, tmp_path / "run")


def _files(out):
    return {p.relative_to(out): p.stat().st_mtime_ns for p in out.rglob("*")}


def test_config_records_the_timesteps_trained_beside_the_requested(run):
    from stable_baselines3 import PPO

    config = json.loads((run / "config.json").read_text())
    assert config["requested_timesteps"] == 1500
    assert config["timesteps"] == 2048 == PPO.load(run / "model.zip", device="cpu").num_timesteps
    help_text = build_parser()._subparsers._group_actions[0].choices["train"].format_help()
    assert "rounded up to whole rollouts" in " ".join(help_text.split())


def test_train_prints_the_steps_it_trained(tmp_path, capsys):
    main([*TRAIN, "--timesteps", "100", "--out", str(tmp_path / "run")])
    assert "trained 1,024 env steps" in capsys.readouterr().out
    assert not (tmp_path / "run" / "evaluations.npz").exists()  # shorter than --eval-every: as the help says
    help_text = " ".join(build_parser()._subparsers._group_actions[0].choices["train"].format_help().split())
    assert "evaluations.npz and learning_curve.png once it passes --eval-every" in help_text


def test_resume_to_fewer_timesteps_than_the_run_has_is_refused_and_changes_nothing(run, tmp_path):
    out = _copy(run, tmp_path)
    before = _files(out)
    with pytest.raises(SystemExit, match="already has 2048 timesteps and --timesteps is the total to reach"):
        main([*TRAIN, "--resume", str(out), "--timesteps", "1500", "--out", str(out)])
    with pytest.raises(SystemExit, match="already has 2048"):  # reaching exactly what it has trains nothing either
        main([*TRAIN, "--resume", str(out), "--timesteps", "2048", "--out", str(out)])
    assert _files(out) == before


def test_a_run_resumed_into_a_new_folder_logs_there_and_leaves_the_old_one_alone(run, tmp_path):
    before = _files(run)
    main([*TRAIN, "--resume", str(run), "--timesteps", "3000", "--out", str(tmp_path / "next")])
    assert _files(run) == before  # TensorBoard wrote into the resumed run's tb/ before
    assert any((tmp_path / "next" / "tb").rglob("events.out.tfevents.*"))


def test_train_refuses_to_overwrite_a_run_unless_told(run, tmp_path, capsys):
    from fourwis.training.rl import train

    out = _copy(run, tmp_path)
    before = _files(out)
    with pytest.raises(SystemExit, match=f"{out} already holds a run: continue it with --resume .*--overwrite"):
        main([*TRAIN, "--timesteps", "1500", "--out", str(out)])
    with pytest.raises(ValueError, match="already holds a run"):  # the Python API too
        train("ppo", out, 1500, n_envs=4, env_kwargs={"estimator": "oracle"}, progress=False)
    other = shutil.copytree(run, tmp_path / "other")
    with pytest.raises(SystemExit, match=f"{out} already holds a run"):  # resumed into another run's directory
        main([*TRAIN, "--resume", str(other), "--timesteps", "4096", "--out", str(out)])
    assert _files(out) == before
    stale = out / "checkpoints" / "step_000002048.zip"
    assert stale.exists()
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    main([*TRAIN, "--timesteps", "100", "--seed", "1", "--overwrite", "--out", str(out)])
    wrote = capsys.readouterr().out.strip().splitlines()[-1]  # lists the run's files, not the folder's others
    assert wrote.endswith(f"(+ checkpoints/, config.json, tb/, vecnormalize.pkl in {out})"), wrote
    config = json.loads((out / "config.json").read_text())
    assert (config["seed"], config["timesteps"]) == (1, 1024)
    assert not stale.exists()  # the replaced run's checkpoints do not pass for the new run's
    assert (out / "notes.txt").read_text() == "mine"  # what is not a run's file stays


def test_negative_seed_is_refused_before_anything_is_written(tmp_path, monkeypatch):
    from fourwis.training import tune as training_tune
    from fourwis.training.rl import train
    from fourwis.training.tune import tune

    out = tmp_path / "run"
    with pytest.raises(SystemExit, match="fourwis train: --seed must be >= 0, got -1"):
        main(["train", "--seed", "-1", "--out", str(out)])
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -1"):
        train("ppo", out, 100, seed=-1)
    assert not out.exists()
    monkeypatch.setattr(training_tune, "calibration_run", lambda **kwargs: pytest.fail("tuning started"))
    with pytest.raises(SystemExit, match="fourwis tune: --seed must be >= 0, got -1"):
        main(["tune", "--seed", "-1", "--out", str(tmp_path / "tuned.json")])
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -1"):
        tune(seed=-1, out=tmp_path / "tuned.json")
    assert not any(tmp_path.iterdir())


def test_tune_mu_noise_refuses_the_options_it_would_ignore(tmp_path, monkeypatch):
    from fourwis.training import tune as training_tune

    monkeypatch.setattr(training_tune, "mu_noise_scan", lambda: pytest.fail("scan started"))
    with pytest.raises(SystemExit, match=r"--mu-noise takes no other option, got \['--out', '--seed'\]"):
        main(["tune", "--mu-noise", "--out", str(tmp_path / "mn.json"), "--seed", "-5"])
    monkeypatch.setattr(training_tune, "mu_noise_scan", lambda **sweep: {0.3: 0.05})
    assert main(["tune", "--mu-noise"]) == 0


def test_tune_checks_its_output_file_before_any_work(tmp_path, monkeypatch):
    from fourwis.training import tune as training_tune

    monkeypatch.setattr(training_tune, "calibration_run", lambda **kwargs: pytest.fail("tuning started"))
    with pytest.raises(SystemExit, match=f"fourwis tune: --out must be a file, but {tmp_path} is a directory"):
        main(["tune", "--out", str(tmp_path)])
    (tmp_path / "notes.txt").write_text("a file")
    with pytest.raises(SystemExit, match="notes.txt is not a writable directory"):
        main(["tune", "--out", str(tmp_path / "notes.txt" / "tuned.json")])
    monkeypatch.undo()
    nested = tmp_path / "new" / "dir" / "tuned.json"  # a parent that can be created is fine
    training_tune.tune(2, 1, out=nested, optimizer="random", duration=0.6, progress=False)
    assert json.loads(nested.read_text())["optimizer"] == "random"


@pytest.mark.parametrize(
    "command",
    [["compare"], ["estimate"], ["estimate", "--grid"], ["simulate", "paper_step"], ["swd", "--A", "20"], ["train"]],
)
def test_every_command_checks_its_output_folder_before_any_work(command, tmp_path, monkeypatch):
    from fourwis.envs import simulation as envs_simulation

    monkeypatch.setattr(envs_simulation.ClosedLoop, "__init__", lambda *a, **k: pytest.fail("a run started"))
    (tmp_path / "notes.txt").write_text("a file")
    for out, named in (
        (tmp_path / "notes.txt", "must be a directory, but .*notes.txt is a file"),
        (tmp_path / "notes.txt" / "sub", "notes.txt is not a writable directory"),
    ):
        with pytest.raises(SystemExit, match=f"fourwis {command[0]}: --out .*{named}"):
            main([*command, "--out", str(out)])


def test_simulate_takes_the_comparisons_overrides_and_swd_an_a_with_a_series(tmp_path):
    main(["simulate", "paper_step:duration=0.2,mu=0.5", "--speed-kph", "30", "--out", str(tmp_path)])
    header, first, *rows = (tmp_path / "paper_step_duration_0.2_mu_0.5.csv").read_text().splitlines()
    assert len(rows) == 100  # 0.2 s at 2 ms
    # the columns (training.trajectory_io.trajectory_columns) carry the run: SI units, overrides;
    # each header names its unit
    headers = header.split(",")
    assert headers[:4] == ["t [s]", "x [m]", "y [m]", "psi [rad]"] and len(set(headers)) == len(headers)
    units = dict(h.removesuffix("]").split(" [", 1) for h in headers)
    assert units["r"] == units["est_r"] == "rad/s" and units["torque_fl"] == "N m" and units["est_mu_std_rr"] == "-"
    names = list(units)
    table = np.array([line.split(",") for line in [first, *rows]], dtype=float)
    column = dict(zip(names, table.T))
    np.testing.assert_allclose(np.diff(column["t"]), 0.002, atol=1e-12)
    np.testing.assert_allclose(column["u"], 30 / 3.6, rtol=0.01)  # m/s, not km/h
    for w in ("fl", "fr", "rl", "rr"):
        np.testing.assert_array_equal(column[f"mu_{w}"], 0.5)
        assert np.all(column[f"fz_{w}"] > 1000.0) and np.all(np.isfinite(column[f"est_mu_{w}"]))
    np.testing.assert_allclose(column["est_r"], column["r"], atol=0.01)  # (the default joint estimator)
    with pytest.raises(SystemExit, match=r"fourwis swd: --A must be a steering-wheel angle in \(0, 200\] deg"):
        main(["swd", "--A", "201"])  # 1.5A above 300 deg: no run in the series


@pytest.mark.parametrize("jobs", ["0", "-1"])
@pytest.mark.parametrize("command", [["compare"], ["estimate"], ["evaluate", "some_run"], ["swd"], ["tune"]])
def test_every_command_refuses_fewer_than_one_job_naming_the_option(command, jobs, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([*command, "--jobs", jobs, "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2
    assert f"argument --jobs: must be >= 1, got {jobs}" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("threads", ["0", "3000"])
def test_a_thread_count_outside_the_cores_is_refused_before_any_work(threads, tmp_path, monkeypatch):
    monkeypatch.delenv("FOURWIS_THREADS", raising=False)
    with pytest.raises(SystemExit, match=rf"fourwis compare: --threads must be an integer from 1 to \d+ .*{threads}"):
        main(["compare", "--threads", threads, "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


def test_the_thread_count_reaches_the_kernels_and_the_workers(tmp_path, monkeypatch):
    """``--threads 1`` sets this process's count and exports it to the worker processes."""
    from fourwis.core import kernels

    monkeypatch.setenv("FOURWIS_THREADS", "1")
    monkeypatch.delenv("FOURWIS_THREADS")  # (recorded: restored as unset after the test)
    monkeypatch.setattr(kernels, "_threads", None)
    main(["list", "scenarios"])  # (no --threads there: nothing set)
    assert "FOURWIS_THREADS" not in os.environ
    main(["estimate", "--threads", "1", "--scenarios", "paper_dlc", "--estimators", "ekf", "--seeds", "1",
          "--out", str(tmp_path / "est")])  # fmt: skip
    assert kernels.kernel_threads() == 1 and os.environ["FOURWIS_THREADS"] == "1"


def _sigint_handler(_):
    import signal

    return signal.getsignal(signal.SIGINT)


def test_local_workers_leave_ctrl_c_to_the_parent():
    """A terminal's Ctrl-C reaches every process of the group; the local pool's workers ignore
    it, so the parent alone unwinds (tests/test_output_sets.py: the interrupted sets)."""
    import signal

    from fourwis.training.pool import parallel_map

    assert list(parallel_map(_sigint_handler, [0, 1], 2, "test", progress=False)) == [signal.SIG_IGN] * 2
    assert signal.getsignal(signal.SIGINT) is not signal.SIG_IGN  # (the parent keeps its handler)


@pytest.mark.parametrize("jobs", [0, -1])
def test_parallel_map_refuses_fewer_than_one_job_before_iterating(jobs, tmp_path):
    from fourwis.training.compare import compare
    from fourwis.training.pool import parallel_map

    with pytest.raises(ValueError, match=f"jobs must be >= 1, got {jobs}"):
        parallel_map(abs, [1, 2], jobs, "test")  # at the call, not at the first result
    with pytest.raises(ValueError, match=f"jobs must be >= 1, got {jobs}"):
        compare(tmp_path / "out", ["paper_sine"], ["oracle"], ["none"], 1, jobs)
    assert list(parallel_map(abs, [-1, -2], 1, "test", progress=False)) == [1, 2]


@pytest.mark.parametrize(
    "given, header, other",
    [(True, "A = 10.0 deg (given)", "0.3 g at 80 km/h"), (False, "A = 16.6 deg (0.3 g at 80 km/h, dry road)", "given")],
)
def test_swd_header_says_whether_a_was_given_or_measured(given, header, other, monkeypatch, capsys):
    from fourwis.envs import fmvss126 as envs_fmvss126

    monkeypatch.setattr(envs_fmvss126, "run_series", lambda *args, **kwargs: [])
    monkeypatch.setattr(
        envs_fmvss126, "characterise", lambda: pytest.fail("measured a given A") if given else math.radians(16.6)
    )
    main(["swd", "--mu", "1.0", "0.5", *(["--A", "10"] if given else [])])
    text = capsys.readouterr().out
    assert text.count(header) == 2 and other not in text  # one table per mu


def test_every_option_has_help_and_shows_its_default(monkeypatch):
    monkeypatch.setenv("COLUMNS", "1000")  # no wrapping inside the texts compared
    commands = build_parser()._subparsers._group_actions[0].choices
    assert set(commands) >= {"simulate", "compare", "estimate", "tune", "swd", "train", "evaluate", "bench"}
    for name, parser in commands.items():
        text = parser.format_help()
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"{name} {action.dest} has no help"
            if action.default is not None and action.default is not False:
                shown = " ".join(map(str, action.default)) if isinstance(action.default, list) else action.default
                assert f"(default: {shown})" in text, f"{name} {action.dest}: default not shown"
    compare_help = commands["compare"].format_help()
    assert "dyc-smc-4ws" in compare_help and "rl:<run dir>" in compare_help
    assert "(default: None)" not in "".join(p.format_help() for p in commands.values())


def test_tune_writes_results_tune_and_replaces_the_shipped_tuning_only_when_told(tmp_path, monkeypatch, capsys):
    from fourwis.training import tune as training_tune

    shipped = training_tune.SHIPPED.read_bytes()
    monkeypatch.chdir(tmp_path)
    smoke = ["tune", "--agents", "2", "--iterations", "1", "--duration", "0.6", "--optimizer", "random"]
    assert main(smoke) == 0
    written = tmp_path / "results" / "tune" / "tuned_noise.json"
    data = json.loads(written.read_text())
    assert data["optimizer"] == "random" and data["written_by"]["command"] == " ".join(["fourwis", *smoke])
    assert training_tune.SHIPPED.read_bytes() == shipped  # a smoke run leaves alo-fkf and joint alone
    assert "the shipped tuning is unchanged" in capsys.readouterr().out
    stand_in = tmp_path / "package" / "tuned_noise.json"  # the shipped file's place, for this test
    monkeypatch.setattr(training_tune, "SHIPPED", stand_in)
    assert main([*smoke, "--out", str(tmp_path / "mine.json"), "--replace-shipped"]) == 0
    assert json.loads(stand_in.read_text()) == json.loads((tmp_path / "mine.json").read_text())
    assert f"replaced the shipped tuning {stand_in}" in capsys.readouterr().out
    monkeypatch.setattr(training_tune, "calibration_run", lambda **kwargs: pytest.fail("tuning started"))
    monkeypatch.setattr(training_tune, "SHIPPED", tmp_path / "notes.txt" / "tuned_noise.json")
    (tmp_path / "notes.txt").write_text("a file")
    with pytest.raises(SystemExit, match="fourwis tune: the shipped tuning .*notes.txt is not a writable directory"):
        main([*smoke, "--replace-shipped"])
    with pytest.raises(SystemExit, match=r"--mu-noise takes no other option, got \['--replace-shipped'\]"):
        main(["tune", "--mu-noise", "--replace-shipped"])


def _damage(path, content: bytes):
    path.write_bytes(content)
    return path


@pytest.mark.parametrize(
    "name, content, reason",
    [
        ("config.json", b'{"algo": "ppo",\n', "not the JSON run config"),  # (JSON's own: 'Expecting ...')
        ("config.json", b'{"algo": "ppo", "env_kwargs": {}, "seed": "0"}', "it lacks a valid seed"),
        ("vecnormalize.pkl", b"I12x\n.", "not a VecNormalize file"),  # (pickle's own: 'invalid literal for int()')
        ("model.zip", b"PK\x03\x04 cut short", "not a ppo model"),
    ],
)
def test_a_damaged_file_in_a_run_directory_is_named_before_any_run(name, content, reason, run, tmp_path, monkeypatch):
    from fourwis.envs import simulation as envs_simulation

    out = _copy(run, tmp_path)
    damaged = _damage(out / name, content)
    monkeypatch.setattr(envs_simulation.ClosedLoop, "__init__", lambda *a, **k: pytest.fail("a run started"))
    named = f"{damaged} is damaged: {reason}"
    with pytest.raises(SystemExit, match=f"fourwis evaluate: .*{named}"):
        main(["evaluate", str(out), "--scenarios", "paper_sine", "--out", str(tmp_path / "eval")])
    with pytest.raises(SystemExit, match=f"fourwis compare: controller 'rl:{out}': {named}"):
        main(["compare", "--controllers", f"rl:{out}", "--out", str(tmp_path / "cmp")])
    if name != "model.zip":  # (a resume reads the config and the normaliser before the model's weights)
        with pytest.raises(SystemExit, match=f"fourwis train: .*{named}"):
            main([*TRAIN, "--resume", str(out), "--timesteps", "4096", "--out", str(out)])


def test_the_simulate_plot_names_controller_estimator_and_seed_and_draws_the_reference(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    seen = {}
    close = plt.close

    def keep(fig=None):
        seen["title"] = fig._suptitle.get_text()
        seen["yaw"] = [line.get_label() for line in fig.axes[2].get_lines()]
        close(fig)

    monkeypatch.setattr(plt, "close", keep)
    run = ["simulate", "paper_step:duration=0.2", "--controller", "dyc-lqr", "--estimator", "ckf", "--seed", "3"]
    main([*run, "--out", str(tmp_path)])
    assert seen["title"] == "paper_step:duration=0.2: 40 km/h, controller dyc-lqr, estimator ckf, seed 3"
    assert seen["yaw"] == ["truth", "estimate", "reference (2-DOF, true mu)"]


def test_the_swd_report_says_who_wrote_it(tmp_path, monkeypatch):
    from fourwis.envs import fmvss126 as envs_fmvss126

    monkeypatch.setattr(envs_fmvss126, "run_series", lambda *args, **kwargs: [])
    main(["swd", "--mu", "0.5", "--A", "10", "--out", str(tmp_path)])
    text = (tmp_path / "sine_with_dwell.md").read_text()
    assert f"- command: `fourwis swd --mu 0.5 --A 10 --out {tmp_path}`" in text
    assert all(f"- {field}: " in text for field in ("commit", "date", "host")) and "A = 10.0 deg (given)" in text

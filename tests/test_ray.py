"""Sweeps on Ray (training.pool): the same tables as the local pool, a killed worker's run
retried, a run's own error raised as itself. One local Ray instance for the session
(tests/conftest.py: ray_instance); the tests share one xdist worker (group "ray")."""

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from fourwis.training.pool import MAX_RETRIES, Backend, parallel_map

pytestmark = pytest.mark.xdist_group("ray")

SCENARIOS = ["paper_sine:duration=1.0", "paper_step:duration=1.0"]
CONTROLLERS = ["none", "dyc-lqr"]  #: (both runs name them: the CLI's default list is longer)


def _compare(out: Path, backend, **kwargs) -> bytes:
    from fourwis.training.compare import compare

    compare(out, SCENARIOS, ["ckf"], CONTROLLERS, seeds=2, backend=backend, **kwargs)
    return (out / "runs.csv").read_bytes()


@pytest.fixture(scope="module")
def local_runs_csv(tmp_path_factory) -> bytes:
    """runs.csv of the small comparison on the local pool (the reference)."""
    return _compare(tmp_path_factory.mktemp("local"), "local", jobs=2)


def test_compare_on_ray_writes_the_local_pools_runs_csv_byte_for_byte(ray_instance, local_runs_csv, tmp_path):
    from fourwis.training.cli import main

    out = tmp_path / "ray"
    argv = ["compare", "--backend", "ray", "--scenarios", *SCENARIOS, "--estimators", "ckf"]
    argv += ["--controllers", *CONTROLLERS, "--out", str(out)]
    assert main(argv) == 0
    assert (out / "runs.csv").read_bytes() == local_runs_csv
    assert len(local_runs_csv.decode().splitlines()) == 1 + 2 * 2 * 2  # header + scenarios x controllers x seeds


def _ray_task_workers() -> list[int]:
    """Pids of the Ray workers running a sweep's task now (process title ``ray::_apply``)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / "cmdline").read_bytes()
            except OSError:  # (ended meanwhile)
                continue
            if cmdline.startswith(b"ray::_apply"):
                pids.append(int(entry.name))
    return pids


def test_a_worker_killed_mid_sweep_has_its_run_retried_and_the_runs_csv_is_complete(
    ray_instance, local_runs_csv, tmp_path
):
    """SIGKILL a Ray worker while it runs one of the sweep's simulations: Ray retries the task
    (up to MAX_RETRIES) and runs.csv is the undisturbed local pool's, every run in it."""
    assert MAX_RETRIES >= 1
    killed: list[int] = []
    stop = threading.Event()

    def kill_one() -> None:
        deadline = time.monotonic() + 120
        while not stop.is_set() and time.monotonic() < deadline:
            pids = _ray_task_workers()
            if pids:
                time.sleep(0.3)  # (inside its run, not at its first line)
                try:
                    os.kill(pids[0], signal.SIGKILL)
                except ProcessLookupError:
                    continue
                killed.append(pids[0])
                return
            time.sleep(0.02)

    killer = threading.Thread(target=kill_one, daemon=True)
    killer.start()
    try:
        runs_csv = _compare(tmp_path / "killed", Backend("ray"))
    finally:
        stop.set()
        killer.join()
    assert killed, "no Ray worker was found running a task to kill"
    assert runs_csv == local_runs_csv


def test_a_runs_own_error_fails_the_ray_sweep_as_itself_not_as_a_ray_traceback(ray_instance, tmp_path):
    """A controller that rejects its input in the worker: the sweep raises that ValueError
    (naming the run), not a RayTaskError with Ray's traceback in its message; the CLI prints
    one line."""
    from fourwis.training.cli import main
    from fourwis.training.compare import run_matrix

    with pytest.raises(ValueError) as caught:
        run_matrix(
            ["paper_sine:duration=0.2"], ["oracle"], ["custom_models:bad_gain"], 1, progress=False, backend="ray"
        )
    assert type(caught.value) is ValueError
    message = str(caught.value)
    assert message.startswith("run paper_sine:duration=0.2 x oracle x custom_models:bad_gain, seed 0: ")
    assert "gain must be > 0, got -1.0" in message
    assert "Traceback" not in message and "Ray" not in message
    with pytest.raises(SystemExit) as exited:
        main(
            ["compare", "--backend", "ray", "--scenarios", "paper_sine:duration=0.2", "--estimators", "oracle"]
            + ["--controllers", "custom_models:bad_gain", "--seeds", "1", "--out", str(tmp_path / "bad")]
        )
    assert str(exited.value).startswith("fourwis compare: run paper_sine:duration=0.2 x oracle x custom_models")
    assert "\n" not in str(exited.value)


def test_a_local_worker_that_dies_stops_the_sweep_with_one_line():
    """The local pool cannot retry: a worker that exits mid-run is a WorkerLostError saying so."""
    from fourwis.training.pool import WorkerLostError

    with pytest.raises(WorkerLostError, match="a worker process died .* the local pool does not retry"):
        list(parallel_map(os._exit, [3], 1, "test", progress=False))


def test_parallel_map_on_ray_keeps_the_items_order(ray_instance):
    assert list(parallel_map(abs, [-3, 2, -1, 0], None, "test", progress=False, backend="ray")) == [3, 2, 1, 0]
    assert list(parallel_map(abs, [-3, 2, -1], 1, "test", progress=False, backend="ray")) == [3, 2, 1]


def test_estimate_on_ray_writes_the_local_pools_estimate_csv(ray_instance, tmp_path):
    from fourwis.training.estimate import estimate_report

    csvs = []
    for backend in ("local", "ray"):
        estimate_report(tmp_path / backend, ["paper_sine:duration=1.0"], ["ckf", "joint"], seeds=2, backend=backend)
        csvs.append((tmp_path / backend / "estimate.csv").read_bytes())
    assert csvs[0] == csvs[1]


def test_swd_series_on_ray_is_the_in_process_series(ray_instance):
    """The sine-with-dwell runs of a series as Ray tasks score as they do one after the other here."""
    import functools
    import math

    import numpy as np

    from fourwis.control import make_controller
    from fourwis.envs.fmvss126 import run_series
    from fourwis.envs.vehicle import VehicleParams

    A = math.radians(16.5)
    factory = functools.partial(make_controller, "dyc-lqr", VehicleParams())
    kwargs = dict(mu=0.5, controller_factory=factory, amplitude_list=np.array([5.5 * A]), estimator="oracle")
    here = run_series(A, **kwargs)
    on_ray = run_series(A, **kwargs, map_runs=lambda fn, jobs, desc: parallel_map(fn, jobs, None, desc, False, "ray"))
    assert repr(on_ray) == repr(here) and len(here) == 2  # (repr: NaN fields compare equal)


def test_tune_on_ray_splits_the_population_and_finds_the_same_noise(ray_instance, tmp_path):
    """The optimiser's populations replayed as Ray tasks (parts of it each): the same costs, so
    the same tuning, as one batched replay in this process."""
    from fourwis.training.tune import tune

    kwargs = dict(n_agents=4, iterations=2, duration=1.0, progress=False, optimizer="random")
    here = tune(out=tmp_path / "here.json", **kwargs)
    on_ray = tune(out=tmp_path / "ray.json", backend="ray", **kwargs)
    for result in (here, on_ray):  # (who wrote it and when: a second apart, not the tuning)
        result.pop("written_by")
    assert on_ray == here


def test_backend_refuses_bad_names_and_addresses_and_names_the_extra(monkeypatch):
    import importlib.util

    with pytest.raises(ValueError, match=r"unknown backend 'dask'; known: \['local', 'ray'\]"):
        Backend("dask")
    with pytest.raises(ValueError, match=r"an address \('auto'\) needs the ray backend \(--backend ray\)"):
        Backend("local", "auto")
    with pytest.raises(ValueError, match="address must be a non-empty string"):
        Backend("ray", " ")
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else find_spec(name, *a))
    with pytest.raises(ModuleNotFoundError, match=r"pip install 'fourwis\[ray\]'"):
        Backend("ray")


@pytest.mark.parametrize("command", [["compare"], ["estimate"], ["swd"], ["tune"], ["evaluate", "run"]])
def test_every_sweep_command_takes_backend_and_address_and_refuses_an_address_without_ray(command, tmp_path):
    from fourwis.training.cli import build_parser, main

    args = build_parser().parse_args([*command, "--backend", "ray", "--address", "auto"])
    assert (args.backend, args.address) == ("ray", "auto")
    assert build_parser().parse_args(command).backend == "local"
    with pytest.raises(SystemExit, match=r"needs the ray backend \(--backend ray\)"):
        main([*command, "--address", "auto", "--out", str(tmp_path / "out.json" if command == ["tune"] else "out")])

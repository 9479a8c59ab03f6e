"""The fourwis command line: one console script, one subcommand per job.

The main job: fourwis compare (README's first command). Extras: plots (PNGs, rendering), rl
(train, evaluate, rl: controllers), ray (--backend ray sweeps, train --framework rllib); a
command names a missing one before it runs."""

from __future__ import annotations

import argparse
import functools
import json
import os
import runpy
import sys
from collections.abc import Callable
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def _bench(args: argparse.Namespace) -> int:
    if not BENCHMARKS.is_dir():
        raise SystemExit(f"benchmarks need the source tree: {BENCHMARKS} not found (install with pip install -e .)")
    names = args.only or sorted(p.stem.removeprefix("bench_") for p in BENCHMARKS.glob("bench_*.py"))
    if str(BENCHMARKS) not in sys.path:  # the scripts share benchmarks/_common.py, as when run directly
        sys.path.insert(0, str(BENCHMARKS))
    for name in names:
        path = BENCHMARKS / f"bench_{name}.py"
        if not path.exists():
            raise SystemExit(
                f"unknown benchmark {name!r}; available: "
                f"{sorted(p.stem.removeprefix('bench_') for p in BENCHMARKS.glob('bench_*.py'))}"
            )
        print(f"== {name}")
        runpy.run_path(str(path), run_name="__main__")
    return 0


def _scenario_overrides(args: argparse.Namespace) -> dict:
    overrides = {}
    if args.speed_kph is not None:
        overrides["speed_kph"] = args.speed_kph
    if args.mu is not None:
        overrides["mu"] = args.mu[0] if len(args.mu) == 1 else tuple(args.mu)
    if args.duration is not None:
        overrides["duration"] = args.duration
    if args.rear_steer:
        overrides["rear_steer_feedforward"] = True
    return overrides


def _check_seed(args: argparse.Namespace) -> None:
    """ValueError naming a negative --seed (numpy refuses it, late and without the option's name)."""
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")


def _check_estimator_and_seed(args: argparse.Namespace) -> None:
    """ValueError naming a bad --estimator or a negative --seed (the jobs that take them)."""
    from fourwis.estimation import check_estimator_name

    check_estimator_name(args.estimator)
    _check_seed(args)


def _simulate(args: argparse.Namespace) -> int:
    import math

    from fourwis.envs.scenarios import make_scenario
    from fourwis.envs.simulation import simulate
    from fourwis.training.compare import (
        FAULT_SUFFIX,
        build_controller,
        build_scenario,
        entry_A,
        file_stem,
        parse_scenario,
    )
    from fourwis.training.io import atomic_write_text, check_writable, pyplot, staged_output
    from fourwis.training.trajectory_io import plot_trajectory, write_trajectory_csv

    try:
        name, overrides = parse_scenario(args.scenario)
        if args.scenario.endswith(FAULT_SUFFIX):
            raise ValueError(f"scenario {args.scenario!r}: the {FAULT_SUFFIX} variant is the comparison's")
        extra = _scenario_overrides(args)
        needs_A = overrides.pop("amplitude_A", None) is not None  # swd_wet, or sine_with_dwell:amplitude_A=k
        if needs_A:  # the cheap checks before A's characterisation (a run of its own)
            make_scenario(name, **overrides | extra)
        _check_estimator_and_seed(args)
        out = check_writable(args.out)
        pyplot()  # (the plot needs matplotlib: say so before the run, not after it)
        scenario = build_scenario(args.scenario, entry_A(args.scenario, extra) if needs_A else math.nan, extra)
        controller = build_controller(args.controller, scenario.vehicle_params)
        traj = simulate(scenario, controller, args.estimator, seed=args.seed, progress=True)
    except (ValueError, FileNotFoundError) as err:  # a bad argument or run, a user's estimator returning garbage
        raise SystemExit(f"fourwis simulate: {err}") from None
    from fourwis.training.logs import simulated_log, write_log
    from fourwis.training.vehicle_file import fourwis_vehicle, vehicle_toml

    stem = file_stem(args.scenario)
    with staged_output(out) as stage:  # the CSVs, the vehicle file and the plot as one set
        write_trajectory_csv(traj, stage / f"{stem}.csv")
        write_log(stage / f"{stem}.log.csv", *simulated_log(traj, stem, f"{stem}.vehicle.toml"))
        atomic_write_text(stage / f"{stem}.vehicle.toml", vehicle_toml(fourwis_vehicle(scenario.vehicle_params)))
        plot_trajectory(
            traj,
            stage / f"{stem}.png",
            controller=args.controller,
            estimator=args.estimator,
            seed=args.seed,
            name=args.scenario,
        )
    print(
        f"wrote {out / f'{stem}.csv'}, {out / f'{stem}.png'} and the run as a log, {out / f'{stem}.log.csv'} "
        f"(with {stem}.vehicle.toml: fourwis estimate --log {out / f'{stem}.log.csv'})"
    )
    return 0


def _sine_with_dwell(args: argparse.Namespace) -> int:
    import math

    from fourwis.envs.fmvss126 import MAX_A_DEG, MEASURED_A, characterise, format_table, run_series
    from fourwis.envs.road import check_mu
    from fourwis.envs.vehicle import VehicleParams
    from fourwis.training.compare import build_controller
    from fourwis.training.io import atomic_write_text, check_writable
    from fourwis.training.provenance import provenance

    try:  # fail early, before the characterisation, on every argument
        if args.A is not None and not (math.isfinite(args.A) and 0 < args.A <= MAX_A_DEG):
            raise ValueError(
                f"--A must be a steering-wheel angle in (0, {MAX_A_DEG:g}] deg (the series starts at "
                f"1.5A, at most 300 deg), got {args.A!r}"
            )
        if args.out:
            check_writable(args.out)
        for mu in args.mu:
            check_mu("--mu", mu)
        _check_estimator_and_seed(args)
        if args.controller != "none":
            build_controller(args.controller, VehicleParams())  # a bad name or path
        backend = _backend(args)
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"fourwis swd: {err}") from None
    A = math.radians(args.A) if args.A is not None else characterise()
    factory = None
    if args.controller != "none":
        factory = functools.partial(build_controller, args.controller, VehicleParams())
    tables = []
    for mu in args.mu:
        try:
            runs = run_series(
                A,
                mu=mu,
                controller_factory=factory,
                estimator=args.estimator,
                seed=args.seed,
                map_runs=functools.partial(_map_runs, jobs=args.jobs, backend=backend),
            )
        except ValueError as err:  # a user's estimator or controller returning garbage
            raise SystemExit(f"fourwis swd: {err}") from None
        passed = sum(run.result.passed for run in runs)
        tables.append(
            f"controller {args.controller}, estimator {args.estimator}: {passed} of {len(runs)} runs "
            f"pass\n\n" + format_table(runs, A, MEASURED_A if args.A is None else "given")
        )
    text = "\n\n".join(tables)
    print(text)
    if args.out:
        report = "\n".join(["# FMVSS 126 sine with dwell", "", *provenance(args.command_line).markdown(), "", text, ""])
        print(f"wrote {atomic_write_text(Path(args.out) / 'sine_with_dwell.md', report)}")
    return 0


def _backend(args: argparse.Namespace):
    """The --backend and --address of a sweep as a training.pool.Backend (ValueError naming a
    bad one; ModuleNotFoundError naming the extra if Ray is missing)."""
    from fourwis.training.pool import Backend

    return Backend(args.backend, args.address)


def _map_runs(fn, items, desc: str, jobs: int | None, backend):
    """A series' runs on the sweep backend, with a progress bar (envs.fmvss126.run_series's map_runs)."""
    from fourwis.training.pool import parallel_map

    return parallel_map(fn, items, jobs, desc, True, backend)


def _report(
    command: str,
    make_report: Callable[[], Path],
    table: str,
    errors: tuple[type[Exception], ...] = (ValueError,),
    plots: bool = True,
) -> int:
    """Run a report job, print the report; bad input exits with the command's name."""
    try:
        report = make_report()
    except errors as err:
        raise SystemExit(f"fourwis {command}: {err}") from None
    print(report.read_text())
    print(f"wrote {report} (+ {table}{' and PNG plots' if plots else ''} in {report.parent})")
    return 0


def _compare(args: argparse.Namespace) -> int:
    from fourwis.training.compare import compare

    return _report(
        "compare",
        lambda: compare(
            args.out,
            args.scenarios,
            args.estimators,
            args.controllers,
            args.seeds,
            args.jobs,
            args.command_line,
            _backend(args),
        ),
        "runs.csv",
    )


def _given(args: argparse.Namespace, command: str, names: tuple[str, ...]) -> list[str]:
    """The options of ``names`` given on the command line (not at their defaults), as --names."""
    defaults = vars(build_parser().parse_args([command]))
    return ["--" + k.replace("_", "-") for k in names if getattr(args, k) != defaults[k]]


def _estimate_log(args: argparse.Namespace) -> int:
    from fourwis.training.log_report import LOG_ESTIMATORS, estimate_log_report

    others = _given(args, "estimate", ("scenarios", "seeds", "road_mu", "jobs", "backend", "address"))
    if others:
        raise SystemExit(f"fourwis estimate: --log runs the estimators on the log; {others} are for scenarios")
    estimators = args.estimators if _given(args, "estimate", ("estimators",)) else list(LOG_ESTIMATORS)
    return _report(
        "estimate",
        lambda: estimate_log_report(
            args.out, args.log, args.vehicle, estimators, command=args.command_line, progress=True
        ),
        "scores.csv",
        (ValueError, FileNotFoundError),
    )


def _estimate_grid(args: argparse.Namespace) -> int:
    from fourwis.training.grid import DEFAULT_ESTIMATORS, grid_report

    others = _given(args, "estimate", ("scenarios", "road_mu", "log", "vehicle"))
    if others:
        raise SystemExit(f"fourwis estimate: --grid sets its own scenarios; {others} are for the named scenarios")
    estimators = args.estimators if _given(args, "estimate", ("estimators",)) else list(DEFAULT_ESTIMATORS)
    out = args.out if _given(args, "estimate", ("out",)) else "results/grid"
    return _report(
        "estimate",
        lambda: grid_report(
            out,
            args.half,
            estimators,
            args.quick,
            args.seeds,
            args.jobs,
            command=args.command_line,
            backend=_backend(args),
        ),
        "runs.csv",
    )


def _estimate(args: argparse.Namespace) -> int:
    from fourwis.training.estimate import estimate_report

    if args.grid:
        return _estimate_grid(args)
    others = _given(args, "estimate", ("half", "quick"))
    if others:
        raise SystemExit(f"fourwis estimate: {others} apply to --grid only")
    if args.log is not None:
        return _estimate_log(args)
    if args.vehicle is not None:
        raise SystemExit("fourwis estimate: --vehicle is the car of a --log")
    return _report(
        "estimate",
        lambda: estimate_report(
            args.out,
            args.scenarios,
            args.estimators,
            args.seeds,
            args.jobs,
            road_mu=args.road_mu,
            command=args.command_line,
            backend=_backend(args),
        ),
        "estimate.csv",
    )


def _tune_log(args: argparse.Namespace) -> int:
    from fourwis.training.log_report import tune_log_report

    others = _given(
        args, "tune", ("duration", "criterion", "replace_shipped", "mu_noise", "jobs", "backend", "address")
    )
    if others:
        raise SystemExit(f"fourwis tune: --log tunes on the log's first part; {others} are for the calibration run")
    given = _given(args, "tune", ("agents", "iterations", "out"))
    return _report(
        "tune",
        lambda: tune_log_report(
            args.out if "--out" in given else "results/tune_log",
            args.log,
            args.vehicle,
            args.estimator,
            args.split,
            args.agents if "--agents" in given else 12,
            args.iterations if "--iterations" in given else 20,
            args.seed,
            args.optimizer,
            command=args.command_line,
        ),
        "scores.csv and tuned_noise.json",
        (ValueError, FileNotFoundError),
        plots=False,
    )


def _tune(args: argparse.Namespace) -> int:
    from fourwis.training.tune import SHIPPED, mu_noise_scan, tune

    if args.log is not None:
        return _tune_log(args)
    unused = _given(args, "tune", ("vehicle", "estimator", "split"))
    if unused:
        raise SystemExit(f"fourwis tune: {unused} are for --log")
    if args.mu_noise:
        defaults = vars(build_parser().parse_args(["tune"]))
        sweep = ("jobs", "backend", "address")
        ignored = ("mu_noise", "func", "command_line", *sweep)
        given = sorted(k for k, v in vars(args).items() if k not in ignored and v != defaults[k])
        if given:  # (they were accepted and ignored)
            options = ["--" + k.replace("_", "-") for k in given]
            raise SystemExit(
                f"fourwis tune: --mu-noise takes no other option, got {options} (but --jobs, --backend and --address)"
            )
        try:
            backend = _backend(args)
        except ValueError as err:
            raise SystemExit(f"fourwis tune: {err}") from None
        errors = mu_noise_scan(jobs=args.jobs, backend=backend)
        print("| mu_accel_std [m/s^2] | mean abs mu error, last half |\n|---:|---:|")
        print("\n".join(f"| {g:g} | {e:.3f} |" for g, e in errors.items()))
        return 0
    out = Path(args.out)
    try:
        _check_seed(args)
        data = tune(
            args.agents,
            args.iterations,
            args.seed,
            out,
            args.optimizer,
            args.duration,
            criterion=args.criterion,
            replace_shipped=args.replace_shipped,
            command=args.command_line,
            jobs=args.jobs,
            backend=_backend(args),
        )
    except ValueError as err:
        raise SystemExit(f"fourwis tune: {err}") from None
    if args.replace_shipped:
        print(f"wrote {out} and replaced the shipped tuning {SHIPPED}: alo-fkf and joint use it from now on")
    else:
        print(
            f"wrote {out} (the shipped tuning is unchanged: --replace-shipped installs a result; "
            f"make_estimator(..., noise=tuned_noise({str(out)!r})) uses this file)"
        )
    if data["improved"]:
        print(
            f"{args.optimizer} tuning: cost {data['default_cost']:.3f} (default noise) -> {data['cost']:.3f}, "
            f"log10 factors {data['log10_factors']}"
        )
    else:
        print(
            f"{args.optimizer} tuning found no noise better than the hand-set one (cost {data['default_cost']:.3f}; "
            f"its best {data['optimizer_best']['cost']:.3f}): kept the hand-set noise (log10 factors 0)"
        )
    return 0


def _json_object(text: str) -> dict:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as err:
        raise argparse.ArgumentTypeError(f"not JSON: {text!r} ({err})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return value


def _train(args: argparse.Namespace) -> int:
    from fourwis.training.rl import train
    from fourwis.training.runs import RUN_FILES

    try:
        if args.seed is not None:
            _check_seed(args)
        if args.framework == "rllib":
            path = _train_rllib(args)
        else:
            if args.env_runners is not None or args.address is not None:
                raise ValueError("--env-runners and --address are for --framework rllib")
            path = train(
                args.algo,
                args.out,
                args.timesteps,
                args.seed,
                args.env_kwargs,
                args.n_envs,
                eval_every=args.eval_every,
                checkpoint_every=args.checkpoint_every,
                resume=args.resume,
                overwrite=args.overwrite,
            )
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"fourwis train: {err}") from None
    except KeyboardInterrupt as err:  # train saved the model first (if it had started training)
        print(f"\nfourwis train: {str(err) or 'interrupted'}", file=sys.stderr)  # (an exception is always truthy)
        return 130
    trained = json.loads((path.parent / "config.json").read_text())["timesteps"]
    others = [
        p.name + "/" * p.is_dir()
        for p in sorted(path.parent.iterdir())  # the run's, not the folder's others
        if p != path and p.name in RUN_FILES and not p.name.startswith(".")
    ]
    print(f"wrote {path}, trained {trained:,} env steps (+ {', '.join(others)} in {path.parent})")
    return 0


def _train_rllib(args: argparse.Namespace):
    """``fourwis train --framework rllib``: RLlib PPO (training.rllib); returns the policy's path."""
    if args.algo != "ppo":
        raise ValueError(f"--framework rllib trains --algo ppo, not {args.algo} (sac and td3: --framework sb3)")
    from fourwis.training.rllib import train as train_rllib

    return train_rllib(
        args.out,
        args.timesteps,
        args.seed,
        args.env_kwargs,
        args.n_envs,
        1 if args.env_runners is None else args.env_runners,
        eval_every=args.eval_every,
        checkpoint_every=args.checkpoint_every,
        overwrite=args.overwrite,
        address=args.address,
        resume=args.resume,
    )


def _evaluate(args: argparse.Namespace) -> int:
    from fourwis.training.compare import evaluate

    return _report(
        "evaluate",
        lambda: evaluate(
            args.model,
            args.out,
            args.scenarios,
            args.estimator,
            args.seeds,
            args.jobs,
            args.command_line,
            _backend(args),
        ),  # fmt: skip
        "runs.csv",
        (ValueError, FileNotFoundError),
    )


def _list(args: argparse.Namespace) -> int:
    from fourwis.training.catalog import catalog

    print(catalog(args.what))
    return 0


def _positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (argparse's error names the option)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default (a list as typed on the command line), except None and False:
    such options say in their help what happens without them."""

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.default is None or action.default is False:
            return action.help
        if isinstance(action.default, list):
            return f"{action.help} (default: {' '.join(map(str, action.default))})".replace("%", "%%")
        return super()._get_help_string(action)


def _add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--speed-kph", type=float, help="initial / target speed [km/h] (default: the scenario's)")
    parser.add_argument(
        "--mu",
        type=float,
        nargs="+",
        help="road friction: one value (uniform) or two (left, right split) (default: the scenario's)",
    )
    parser.add_argument("--duration", type=float, help="simulated time [s] (default: the scenario's)")
    parser.add_argument("--rear-steer", action="store_true", help="switch on the paper's 4WS law (eq. 20)")


def _add_matrix_arguments(
    parser: argparse.ArgumentParser, scenarios, estimators, seeds: int, out: str, scenarios_help: str
) -> None:
    """The scenario x estimator x seed matrix arguments that compare and estimate share."""
    from fourwis.estimation import ESTIMATORS, TRUTH_GROUPS

    parser.add_argument("--scenarios", nargs="+", default=list(scenarios), help=scenarios_help)
    parser.add_argument(
        "--estimators",
        nargs="+",
        default=list(estimators),
        help=f"estimator names ({', '.join(ESTIMATORS)}, or module:factory for your own); "
        f"NAME+true-mu (groups {', '.join(TRUTH_GROUPS)}, joined by '-') reports those quantities "
        f"from the truth",
    )
    _add_run_arguments(parser, seeds, out)


def _add_run_arguments(parser: argparse.ArgumentParser, seeds: int, out: str) -> None:
    """--seeds, --jobs and --out of the jobs that run a matrix of simulations."""
    parser.add_argument("--seeds", type=int, default=seeds, help="sensor-noise seeds per cell")
    _add_backend_arguments(parser)
    parser.add_argument("--out", default=out, help="output directory")


def _add_backend_arguments(parser: argparse.ArgumentParser, jobs_help: str = "worker processes (default: up to 2)"):
    """--jobs, --backend and --address of the jobs that run sweeps (training.pool)."""
    parser.add_argument(
        "--jobs", type=_positive_int, help=f"{jobs_help}; with --backend ray: most tasks at once (default: all)"
    )
    parser.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="where the runs execute: worker processes here, or Ray tasks (the ray extra; docs/cluster.md)",
    )
    parser.add_argument(
        "--address",
        help="the Ray cluster to join with --backend ray: auto, HOST:6379 or ray://HOST:10001 "
        "(default: start a local Ray instance)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fourwis", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    def command(name: str, summary: str) -> argparse.ArgumentParser:
        parser = sub.add_parser(name, help=summary, description=summary, formatter_class=_HelpFormatter)
        if name not in ("list", "bench"):
            parser.add_argument(
                "--threads",
                type=int,
                help="threads of the batched kernels in this process and its workers, from 1 to the cores "
                "(default: FOURWIS_THREADS, else every core)",
            )
        return parser

    sim = command("simulate", "run one scenario (open loop, or with --controller); writes OUT/<scenario>.csv and .png")
    sim.add_argument(
        "scenario",
        help="scenario name (see envs.SCENARIOS), optionally with overrides as in compare "
        "(iso3888_2:mu=0.6,speed_kph=50; the options below apply on top)",
    )
    _add_scenario_arguments(sim)
    sim.add_argument("--estimator", default="oracle", help="estimator run alongside (a name or module:factory)")
    from fourwis.control import CONTROLLERS

    sim.add_argument(
        "--controller",
        default="none",
        help=f"stability controller ({', '.join(CONTROLLERS)}, or module:factory) or rl:<run dir>, fed "
        f"by the estimator",
    )
    sim.add_argument("--seed", type=int, default=0, help="sensor noise seed (>= 0)")
    sim.add_argument("--out", default="results/simulate", help="output directory")
    sim.set_defaults(func=_simulate)
    from fourwis.training.compare import DEFAULT_CONTROLLERS, DEFAULT_ESTIMATORS, HEADLINE

    cmp_ = command(
        "compare", "closed-loop matrix estimator x controller x scenario; writes OUT/report.md, runs.csv and PNG plots"
    )
    _add_matrix_arguments(
        cmp_,
        HEADLINE,
        DEFAULT_ESTIMATORS,
        2,
        "results/compare",
        "scenario names, optionally with overrides: iso3888_2:mu=0.5,speed_kph=50; "
        "sine_with_dwell:amplitude_A=6.5 ('swd_wet': SWD 5.5A, mu 0.5)",
    )
    cmp_.add_argument(
        "--controllers",
        nargs="+",
        default=list(DEFAULT_CONTROLLERS),
        help=f"stability controllers ({', '.join(CONTROLLERS)}, or module:factory for your own) or "
        "rl:<run dir> (or rl:<run dir>/checkpoints/step_N.zip) for a policy trained by fourwis "
        "train",
    )
    cmp_.set_defaults(func=_compare)
    from fourwis.envs.scenarios import PAPER_SCENARIOS
    from fourwis.training.estimate import DEFAULT_ESTIMATORS as ESTIMATE_ESTIMATORS

    est = command(
        "estimate",
        "open-loop estimator accuracy (paper Table 2 form); writes OUT/estimate.md, "
        "estimate.csv, a PNG per scenario and tyre_curves.png (paper Figs. 2-3)",
    )
    _add_matrix_arguments(
        est,
        PAPER_SCENARIOS,
        ESTIMATE_ESTIMATORS,
        1,
        "results/estimate",
        "scenario names, optionally with overrides as in compare (no +faults)",
    )
    est.add_argument(
        "--road-mu",
        action="store_true",
        help="the fixed-mu filters (ekf, ckf, fkf, alo-fkf) assume the road's friction at the start "
        "instead of 0.8 (the paper's section-3 reading)",
    )
    from fourwis.training.logs import shipped_logs

    est.add_argument(
        "--log",
        help="instead of scenarios: run the estimators and the baselines on a recorded log, a file (.csv, "
        f".csv.gz, .parquet, .mat; docs/logs.md) or a shipped log ({', '.join(shipped_logs()) or 'none'}); "
        "writes OUT/report.md, scores.csv, sideslip.png, friction.png, errors.png",
    )
    est.add_argument(
        "--vehicle",
        help="the car of --log: a vehicle file (TOML; docs/logs.md) (default: the one the log names, "
        "as a shipped log and fourwis simulate's logs do)",
    )
    from fourwis.training.grid import HALF_CHOICES

    est.add_argument(
        "--grid",
        action="store_true",
        help="instead of scenarios: the evaluation grid (friction x manoeuvre x speed x seed x model error, "
        "development and held-out halves, closed-loop cells); writes OUT/grid.md (default OUT: "
        "results/grid), runs.csv, checks.csv and heat maps",
    )
    est.add_argument("--half", choices=HALF_CHOICES, default="both", help="with --grid: which half to run")
    est.add_argument("--quick", action="store_true", help="with --grid: a few cells of each kind (about a minute)")
    est.set_defaults(func=_estimate)
    from fourwis.estimation.optimizers import METHODS
    from fourwis.training.tune import CRITERIA

    tune = command(
        "tune",
        "offline tuning of alo-fkf's noise on a calibration run; writes a JSON file (the shipped tuning, "
        "which alo-fkf and joint use, only with --replace-shipped)",
    )
    tune.add_argument("--agents", type=int, default=30, help="population size (ants, CMA-ES offspring, random draws)")
    tune.add_argument("--iterations", type=int, default=100, help="optimizer iterations")
    tune.add_argument("--duration", type=float, default=10.0, help="calibration run length [s]")
    tune.add_argument(
        "--criterion",
        choices=CRITERIA,
        default="nll",
        help="innovation negative log-likelihood (no truth needed) or error against the truth",
    )
    tune.add_argument("--seed", type=int, default=0, help="optimizer seed (>= 0)")
    tune.add_argument(
        "--optimizer",
        choices=METHODS,
        default="alo",
        help="alo: the paper's antlion optimizer; cmaes: CMA-ES; random: random search",
    )
    tune.add_argument("--out", default="results/tune/tuned_noise.json", help="output JSON file")
    tune.add_argument(
        "--replace-shipped",
        action="store_true",
        help="also write the result over the shipped estimation/data/tuned_noise.json, which alo-fkf and "
        "joint use from then on (in an installed package: inside site-packages)",
    )
    _add_backend_arguments(
        tune, "split each population over this many worker processes (default: one batched replay here)"
    )
    tune.add_argument(
        "--log",
        help="instead of a calibration run: tune on a recorded log's first part (--split) and score on the "
        "rest (a file or a shipped log's name); writes OUT (default results/tune_log)/tuned_noise.json, "
        "report.md and scores.csv; --agents and --iterations default to 12 and 20 there",
    )
    tune.add_argument("--vehicle", help="the car of --log: a vehicle file (default: the one the log names)")
    tune.add_argument("--estimator", default="alo-fkf", help="with --log: the filter whose noise is tuned")
    tune.add_argument("--split", type=float, default=0.3, help="with --log: the fraction of the log tuned on")
    tune.add_argument(
        "--mu-noise",
        action="store_true",
        help="instead: scan the joint estimator's mu_accel_std on held-out random scenarios (prints a table)",
    )
    tune.set_defaults(func=_tune)
    swd = command("swd", "FMVSS 126 sine-with-dwell series: the regulation's table")
    swd.add_argument("--mu", type=float, nargs="+", default=[1.0, 0.5, 0.3], help="road friction values")
    swd.add_argument("--A", type=float, help="characterisation angle [deg] (default: measured at 0.3 g)")
    swd.add_argument("--estimator", default="oracle", help="estimator run alongside (a name or module:factory)")
    swd.add_argument(
        "--controller",
        default="none",
        help=f"stability controller ({', '.join(CONTROLLERS)}, or module:factory) or rl:<run dir>, fed "
        f"by the estimator",
    )
    swd.add_argument("--seed", type=int, default=0, help="sensor noise seed (>= 0)")
    swd.add_argument("--out", help="directory for sine_with_dwell.md (default: print only)")
    _add_backend_arguments(swd)
    swd.set_defaults(func=_sine_with_dwell)
    from fourwis.training.rl_config import ALGO_CONFIGS, ALGOS, EVAL_SCENARIO

    train = command(
        "train",
        "train an RL stability controller (stable-baselines3) on the vector env; writes the "
        "run directory OUT (model.zip, vecnormalize.pkl, config.json, tb/; checkpoints/ once "
        "the run passes --checkpoint-every env steps, evaluations.npz and learning_curve.png "
        "once it passes --eval-every)",
    )
    train.add_argument(
        "--algo", choices=ALGOS, default="ppo", help="RL algorithm (settings: training.rl_config.ALGO_CONFIGS)"
    )
    train.add_argument(
        "--framework",
        choices=("sb3", "rllib"),
        default="sb3",
        help="stable-baselines3 in this process, or RLlib PPO on Ray (the ray extra; writes policy/, "
        "obs_filter.pkl, progress.csv and checkpoints/step_N/ instead of SB3's files)",
    )
    train.add_argument(
        "--env-runners",
        type=int,
        help="rllib: EnvRunner actors, each stepping --n-envs cars of one native vector env (default 1; "
        "0: sample in this process)",
    )
    train.add_argument(
        "--address",
        help="rllib: the Ray cluster to join (auto, HOST:6379, ray://HOST:10001; default: a local instance)",
    )
    train.add_argument(
        "--env-kwargs",
        type=_json_object,
        default={},
        help='env keyword arguments as JSON, e.g. \'{"estimator": "joint", "observation": "true"}\'',
    )
    train.add_argument(
        "--timesteps",
        type=int,
        default=400_000,
        help=f"total env steps to reach (a resumed run counts on from its own, so give more); rounded "
        f"up to whole rollouts: multiples of {ALGO_CONFIGS['ppo']['n_steps']} x --n-envs for "
        f"ppo, of --n-envs for sac and td3 (config.json records both)",
    )
    train.add_argument(
        "--seed",
        type=int,
        default=None,
        help="seed of the env draws and the network (>= 0; default 0, or the resumed run's)",
    )
    train.add_argument(
        "--n-envs", type=int, default=None, help="cars in the native vector env (default 16, or the resumed run's)"
    )
    train.add_argument(
        "--eval-every", type=int, default=40_000, help=f"env steps between evaluations on the held-out {EVAL_SCENARIO}"
    )
    train.add_argument("--checkpoint-every", type=int, default=50_000, help="env steps between checkpoints")
    train.add_argument(
        "--resume",
        help="run directory or checkpoint .zip to continue from (rllib: a run directory or checkpoints/step_N)",
    )
    train.add_argument("--out", default="results/train", help="run directory")
    train.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a run already in --out (its checkpoints, evaluations and logs are deleted)",
    )
    train.set_defaults(func=_train)
    evaluate = command(
        "evaluate",
        "closed-loop evaluation of a trained policy beside no control and the DYC-LQR baseline (as in "
        "compare); writes OUT/report.md, runs.csv and PNG plots",
    )
    evaluate.add_argument(
        "model", help="run directory of fourwis train, its model.zip, or a checkpoint's checkpoints/step_N.zip"
    )
    evaluate.add_argument(
        "--scenarios",
        nargs="+",
        default=["swd_wet", "iso3888_2", "mu_jump", "paper_dlc"],
        help="scenario names, with overrides as in compare",
    )
    evaluate.add_argument(
        "--estimator",
        default=None,
        help="estimator in the loop, for the policy and the uncontrolled and DYC-LQR cars beside it "
        "(default: the one the run was trained with)",
    )
    _add_run_arguments(evaluate, 2, "results/evaluate")
    evaluate.set_defaults(func=_evaluate)
    from fourwis.training.catalog import SECTIONS

    list_ = command("list", "list the scenarios, estimators, controllers or recorded logs: name, what it is, defaults")
    list_.add_argument("what", nargs="?", choices=SECTIONS, help="the section to list (default: all of them)")
    list_.set_defaults(func=_list)
    bench = command("bench", "run the performance benchmarks in benchmarks/")
    bench.add_argument("--only", nargs="*", help="benchmark names (default: all)")
    bench.set_defaults(func=_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    from fourwis.training.pool import WorkerLostError
    from fourwis.training.provenance import command_line

    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    args.command_line = command_line(argv, "fourwis")  # (what the reports' headers say wrote them)
    if "" not in sys.path and os.getcwd() not in sys.path:  # the `fourwis` script's path lacks it
        sys.path.insert(0, os.getcwd())  # your 'module:factory' estimators and controllers live here
    if getattr(args, "threads", None) is not None:
        from fourwis.core.kernels import THREADS_VARIABLE, set_threads

        try:
            set_threads(args.threads)
        except ValueError as err:
            raise SystemExit(f"fourwis {args.command}: --{err}") from None
        os.environ[THREADS_VARIABLE] = str(args.threads)  # (worker processes and Ray workers inherit it)
    try:
        return args.func(args)
    except ModuleNotFoundError as err:  # an optional dependency: its message names the extra
        if "fourwis[" not in str(err):
            raise
        raise SystemExit(f"fourwis {args.command}: {err}") from None
    except WorkerLostError as err:  # a worker died (on Ray: after its retries)
        raise SystemExit(f"fourwis {args.command}: {err}") from None
    except KeyboardInterrupt:  # (train saves its run first and exits the same way)
        print(f"fourwis {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""The closed-loop comparison (the main job): estimator x controller x scenario x seed.

Every run simulates the truth plant with noisy sensors; the estimator turns readings into an
estimate and the controller acts on that estimate only. Reported per run (and averaged
over seeds): peak |sideslip|, yaw-rate tracking RMS against the friction-bounded reference
of the *true* state, spin-out, path deviation and cone hits on course scenarios, FMVSS 126
ratios and displacement on sine-with-dwell, and the estimator's RMSE/MAE (paper Table 2)
of u, v, beta, r and mu.
"""

from __future__ import annotations

import functools
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fourwis.control import CONTROLLERS, make_controller
from fourwis.control.allocation import wheel_force_map
from fourwis.control.reference import PhasePlaneRegion
from fourwis.core.checks import import_factory, is_integer, is_number
from fourwis.core.constants import GRAVITY
from fourwis.envs.fmvss126 import characterise
from fourwis.envs.layout import A_AY, A_BRAKE_TORQUE, S_DELTA_F, S_DELTA_R, S_OMEGA, S_PSI, S_R, S_TORQUE, S_U, S_X, S_Y
from fourwis.envs.metrics import (
    DISPLACEMENT_LIMIT,
    YAW_RATIO_1000,
    YAW_RATIO_1750,
    alongside_path,
    braking_metrics,
    cone_hits,
    mae,
    path_deviation,
    peak_abs,
    rms,
    rmse,
    rolling_sideslip,
    sine_with_dwell_metrics,
    spin_out,
    yaw_rate_tracking_rms,
)
from fourwis.envs.scenarios import SCENARIOS, make_scenario
from fourwis.envs.sensors import Fault
from fourwis.envs.simulation import Trajectory, simulate
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation import check_estimator_name
from fourwis.training.io import atomic_write, atomic_write_text, check_writable, pyplot, staged_output
from fourwis.training.pool import Backend, as_backend, check_jobs, parallel_map
from fourwis.training.provenance import Provenance, provenance
from fourwis.training.tables import mean_over_seeds, require_distinct, write_runs_csv
from fourwis.training.trajectory_io import reference_yaw_rate_of

#: headline scenarios: the paper's five conditions, FMVSS 126 at 5.5A on a wet road, the mu jump,
#: and ISO 3888-2 at 70 km/h on mu 1.0 (where the uncontrolled car spins; it clears 60 km/h)
HEADLINE = (
    "paper_dlc",
    "paper_step",
    "paper_sine",
    "paper_split_dlc",
    "paper_serpentine",
    "swd_wet",
    "mu_jump",
    "iso3888_2:speed_kph=70",
)
DEFAULT_ESTIMATORS = ("oracle", "ckf", "joint")
DEFAULT_CONTROLLERS = ("none", "dyc-lqr", "esc")
RL_PREFIX = "rl:"  #: controller name prefix of a trained policy: ``rl:<run directory>`` (training.rl)
SWD_MULTIPLE = 5.5  #: sine-with-dwell amplitude in multiples of A for the comparison
SWD_MU = 0.5  #: road friction of the comparison's sine with dwell (wet asphalt)


@dataclass(frozen=True)
class RunSpec:
    scenario: str
    estimator: str
    controller: str
    seed: int
    swd_A: float


#: The sensor-fault variant (``<scenario>+faults``): gyro outliers of 0.2 rad/s at 5 per second
#: throughout, and the gyro stuck from 1.5 s to 2.5 s.
SENSOR_FAULTS = (Fault("yaw_rate", "spike", magnitude=0.2, rate=5.0), Fault("yaw_rate", "stuck", start=1.5, end=2.5))
FAULT_SUFFIX = "+faults"


def _run_key(parsed: tuple[str, dict], faults: bool) -> tuple:
    """What a parsed entry runs, whatever the spelling: overrides sorted by key, numbers as floats
    (``duration=1`` and ``duration=1.0``, ``mu=0.3,duration=2`` and ``duration=2,mu=0.3`` run alike)."""

    def value(v):
        return tuple(map(value, v)) if isinstance(v, list) else float(v)

    name, overrides = parsed
    return name, tuple(sorted((k, value(v)) for k, v in overrides.items())), faults


def parse_scenario(text: str) -> tuple[str, dict]:
    """Scenario name and overrides of a comparison entry ``name[:key=value,...][+faults]``,
    e.g. ``iso3888_2:mu=0.5,speed_kph=50``; a value is a number or a JSON list (a split road:
    ``mu=[0.5,0.3]``, left and right); ``amplitude_A=k`` gives sine with dwell k times A
    (:func:`entry_A`, the driven car's);
    ``swd_wet`` stands for ``sine_with_dwell:mu=0.5,amplitude_A=5.5`` (overrides apply on top);
    ``rear_steer_feedforward=1`` switches the paper's 4WS law on;
    a ``+faults`` suffix runs it with :data:`SENSOR_FAULTS`."""
    text = text.removesuffix(FAULT_SUFFIX)
    name, _, rest = text.partition(":")
    defaults = {"mu": SWD_MU, "amplitude_A": SWD_MULTIPLE} if name == "swd_wet" else {}
    name = "sine_with_dwell" if name == "swd_wet" else name
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r} in {text!r}; known: {sorted(SCENARIOS) + ['swd_wet']}")
    given = {}
    for item in filter(None, re.split(r",(?![^\[]*\])", rest)):  # commas outside [...]
        key, sep, value = item.partition("=")
        value = value.strip()
        try:  # an integer literal stays an int (a seed), anything else is a float; [...] a list of numbers
            value = (
                json.loads(value)
                if value.startswith("[")
                else int(value)
                if value.lstrip("+-").isdigit()
                else float(value)
            )
        except ValueError:
            sep = ""
        if not sep or (isinstance(value, list) and not all(is_number(v) for v in value)):
            raise ValueError(f"bad override {item!r} in scenario {text!r}: expected key=number or key=[numbers]")
        if key.strip() in given:
            raise ValueError(f"{key.strip()} is given twice in scenario {text!r}")
        given[key.strip()] = value
    if given.get("rear_steer_feedforward") in (0, 1):  # a switch written as a number
        given["rear_steer_feedforward"] = bool(given["rear_steer_feedforward"])
    overrides = {**defaults, **given}
    if "amplitude_A" in overrides:
        if name != "sine_with_dwell":
            raise ValueError(f"amplitude_A applies to sine_with_dwell only, not {name!r}")
        if "amplitude_deg" in overrides:
            raise ValueError(f"give amplitude_A or amplitude_deg, not both, in {text!r}")
        if not (is_number(overrides["amplitude_A"]) and 0 < overrides["amplitude_A"] < math.inf):
            raise ValueError(f"amplitude_A must be a finite number > 0, got {overrides['amplitude_A']!r} in {text!r}")
    make_scenario(name, **{k: v for k, v in overrides.items() if k != "amplitude_A"})  # validate now
    return name, overrides


def file_stem(entry: str) -> str:
    """A scenario entry as a portable file name stem (``iso3888_2:speed_kph=70`` ->
    ``iso3888_2_speed_kph_70``)."""
    return "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in entry)


def check_file_stems(entries: Sequence[str]) -> None:
    """ValueError unless the scenario entries' plots get distinct file names."""
    stems = [file_stem(e) for e in entries]
    clashing = [e for e, stem in zip(entries, stems) if stems.count(stem) > 1]
    if clashing:
        raise ValueError(f"scenarios {clashing} would write the same plot file {file_stem(clashing[0])}.png")


def build_scenario(text: str, swd_A: float, extra: dict | None = None):
    """The Scenario of a comparison entry (see :func:`parse_scenario`; its ``+faults`` suffix is
    the caller's), ``amplitude_A`` in units of ``swd_A`` [rad] (:func:`envs.fmvss126.characterise`),
    with ``extra`` overrides on top (the command line's)."""
    name, overrides = parse_scenario(text)
    overrides |= extra or {}
    if "amplitude_A" in overrides:
        multiple = overrides.pop("amplitude_A")
        overrides["amplitude_deg"] = math.degrees(multiple * swd_A)
        if not math.isfinite(overrides["amplitude_deg"]):
            raise ValueError(f"amplitude_A={multiple!r} in {text!r} gives no finite amplitude (A = {swd_A!r} rad)")
    return make_scenario(name, **overrides)


def entry_A(text: str, extra: dict | None = None) -> float:
    """FMVSS 126's A [rad] (:func:`envs.fmvss126.characterise`) of the car a sine-with-dwell entry
    of the comparison drives, with ``extra`` overrides (its vehicle parameters: the 4WS
    feed-forward, ``rear_steer_feedforward=1``, makes A 26.5 instead of 16.6 deg, and 5.5A must
    be that car's); NaN for the other scenarios."""
    name, overrides = parse_scenario(text)
    if name != "sine_with_dwell":
        return math.nan
    overrides.pop("amplitude_A", None)
    return characterise(make_scenario(name, **overrides | (extra or {})).vehicle_params)


def _scenario(spec: RunSpec):
    return build_scenario(spec.scenario, spec.swd_A)


def run_metrics(traj: Trajectory, swd_A: float | None = None) -> dict[str, float]:
    """The comparison's metrics of one trajectory (SI units; angles in rad)."""
    scenario = traj.scenario
    params = scenario.vehicle_params
    T, E = traj.truth, traj.estimate
    beta = T.beta
    r_ref = reference_yaw_rate_of(traj)
    out = {
        "peak_beta": peak_abs(beta),
        "yaw_tracking_rms": yaw_rate_tracking_rms(traj.state[:, S_R], r_ref),
        "spin_out": float(
            spin_out(
                beta,
                rolling=rolling_sideslip(
                    traj.state[:, S_U],
                    traj.state[:, S_DELTA_F],
                    traj.state[:, S_DELTA_R],
                    params.cg_to_front,
                    params.cg_to_rear,
                ),
                speed=np.hypot(T.u, T.v),
            )
        ),
    }
    # how far the car left the sideslip phase-plane region it recovers from by itself (> 1:
    # outside), over the samples at speeds the region is tabulated for
    region = PhasePlaneRegion.default()
    index = region.state_index(T)[np.abs(T.u) >= region.speeds[0]]
    out["phase_plane_peak"] = float(np.max(index)) if index.size else math.nan
    # control effort: the yaw moment the net wheel torques (motor less friction brake) make by
    # driving or braking left and right wheels differently (straight-wheel arms, so equal torques on
    # steered wheels count as no effort) [N m], and the rear steer [rad]
    net_torques = traj.state[:, S_TORQUE : S_TORQUE + 4] - traj.aux[:, A_BRAKE_TORQUE : A_BRAKE_TORQUE + 4]
    wheel_forces = net_torques / params.wheel_radius
    _, straight_levers = wheel_force_map(params, 0.0, 0.0)
    out.update(yaw_moment_rms=rms(wheel_forces @ straight_levers[0]), rear_steer_rms=rms(traj.state[:, S_DELTA_R]))
    if scenario.reference_path is not None:
        path = scenario.reference_path
        on_course = alongside_path(traj.state[:, S_X], path)
        rms_dev, max_dev = path_deviation(traj.state[on_course, S_X], traj.state[on_course, S_Y], path)
        out.update(path_rms=rms_dev, path_max=max_dev)
        cones = scenario.course.cones if scenario.course is not None else np.empty((0, 2))
        out["cone_hits"] = float(
            cone_hits(
                traj.state[:, S_X],
                traj.state[:, S_Y],
                traj.state[:, S_PSI],
                cones,
                params.width,
                params.front_extent,
                params.rear_extent,
            )
        )
        # a car that stopped short of the last cones (a coasting car at walking pace) has not
        # driven the course; the driver's line runs on beyond them, which a car slowed by its
        # controller need not reach within the scenario's time (no cones: the line's end). Where
        # the car passed them laterally is what cone_hits and path_* measure, not this.
        end = cones[:, 0].max() if len(cones) else path[-1, 0]
        out["course_completed"] = float(traj.state[-1, S_X] >= end)
    if scenario.name == "sine_with_dwell":
        res = sine_with_dwell_metrics(
            traj.t, traj.steering_wheel, traj.state[:, S_R], traj.aux[:, A_AY], sideslip=beta, A=swd_A
        )
        out.update(
            swd_ratio_1000=res.yaw_rate_ratio_1000,
            swd_ratio_1750=res.yaw_rate_ratio_1750,
            swd_displacement=res.lateral_displacement,
            swd_passed=float(res.passed),
            # FMVSS 126's responsiveness (displacement >= 1.83 m), which applies from 5A: NaN below
            swd_responsive=math.nan if res.passed_responsiveness is None else float(res.passed_responsiveness),
        )
    if scenario.name == "straight_braking":
        rims = traj.state[:, S_OMEGA : S_OMEGA + 4] * params.wheel_radius
        stop = braking_metrics(traj.t, traj.state[:, S_X], traj.state[:, S_U], rims, scenario.brake_after)
        # the ideal stop on the road's lowest friction, v^2 / (2 mu g) (a uniform road: its own; NaN
        # on a friction map without a table)
        table = scenario.road.table()
        lowest = math.nan if table is None else min([table[0], *table[1][:, 4]])
        ideal = stop.initial_speed**2 / (2.0 * lowest * GRAVITY)
        distance = math.nan if stop.stopping_distance is None else stop.stopping_distance
        out.update(stop_distance=distance, stop_ratio=distance / ideal, longest_lock=stop.longest_lock)
    # the pass-rate map's verdict (failed_criteria's): no spin-out, on a course its end reached and
    # no cone displaced (ISO 3888-2: such a run is not valid), and on sine with dwell FMVSS 126
    # passed (the yaw ratios and the responsiveness displacement: a stable car can still fail the latter)
    out["passed"] = float(not failed_criteria(out))
    for name in ("u", "v", "beta", "r"):
        out[f"rmse_{name}"] = rmse(getattr(E, name), getattr(T, name))
        out[f"mae_{name}"] = mae(getattr(E, name), getattr(T, name))
    out["rmse_mu"] = rmse(E.mu.ravel(), T.mu.ravel())
    out["mae_mu"] = mae(E.mu.ravel(), T.mu.ravel())
    out["final_mu_error"] = float(np.mean(np.abs(E.mu[-1] - T.mu[-1])))
    return out


#: the unit of every per-run metric of :func:`run_metrics`, as runs.csv heads its columns ("-":
#: dimensionless, "0/1": a flag, "count"); angles in rad (the report shows degrees)
METRIC_UNITS = {
    "peak_beta": "rad",
    "yaw_tracking_rms": "rad/s",
    "spin_out": "0/1",
    "phase_plane_peak": "-",
    "yaw_moment_rms": "N m",
    "rear_steer_rms": "rad",
    "path_rms": "m",
    "path_max": "m",
    "cone_hits": "count",
    "course_completed": "0/1",
    "swd_ratio_1000": "-",
    "swd_ratio_1750": "-",
    "swd_displacement": "m",
    "swd_passed": "0/1",
    "swd_responsive": "0/1",
    "stop_distance": "m",
    "stop_ratio": "-",
    "longest_lock": "s",
    "passed": "0/1",
    "rmse_u": "m/s",
    "mae_u": "m/s",
    "rmse_v": "m/s",
    "mae_v": "m/s",
    "rmse_beta": "rad",
    "mae_beta": "rad",
    "rmse_r": "rad/s",
    "mae_r": "rad/s",
    "rmse_mu": "-",
    "mae_mu": "-",
    "final_mu_error": "-",
}

#: the criteria a run's verdict judges, in the order the report names them
CRITERIA = {
    "spin-out": "the sideslip passed 20 deg (envs.metrics.spin_out)",
    "course": "the car stopped short of the course's last cones",
    "cones": "the car's body touched a cone (ISO 3888-2: such a run is not valid)",
    "FMVSS yaw 1.0 s": f"FMVSS 126 S5.2.1: yaw rate 1 s after the steering ends above {YAW_RATIO_1000:.0%} of its peak",
    "FMVSS yaw 1.75 s": f"FMVSS 126 S5.2.2: yaw rate 1.75 s after the steering ends above {YAW_RATIO_1750:.0%}",
    "FMVSS responsiveness": f"FMVSS 126 S5.2.3: lateral displacement under {DISPLACEMENT_LIMIT} m (from 5A)",
}


def failed_criteria(metrics: dict[str, float]) -> tuple[str, ...]:
    """The :data:`CRITERIA` one run of :func:`run_metrics` fails (empty: it passes; its ``passed``
    flag and the pass-rate map judge the same)."""
    swd = "swd_ratio_1000" in metrics
    failed = {
        "spin-out": bool(metrics["spin_out"]),
        "course": metrics.get("course_completed", 1.0) != 1.0,
        "cones": metrics.get("cone_hits", 0.0) > 0,
        # (magnitudes, as envs.metrics.SineWithDwellResult.passed_yaw; NaN or inf fails)
        "FMVSS yaw 1.0 s": swd and not abs(metrics["swd_ratio_1000"]) <= YAW_RATIO_1000,
        "FMVSS yaw 1.75 s": swd and not abs(metrics["swd_ratio_1750"]) <= YAW_RATIO_1750,
        "FMVSS responsiveness": metrics.get("swd_responsive") == 0.0,
    }
    return tuple(name for name in CRITERIA if failed[name])


def run_verdict(metrics: dict[str, float]) -> str:
    """runs.csv's verdict of one run: ``pass`` or ``fail: <criterion>; <criterion>``."""
    failed = failed_criteria(metrics)
    return "fail: " + "; ".join(failed) if failed else "pass"


def verdict_cell(runs: Sequence[dict[str, float]]) -> str:
    """The report's verdict over a cell's seeds: ``pass n/n``, or ``FAIL k/n:`` and each failed
    criterion with the number of runs that failed it."""
    failures = [failed_criteria(m) for m in runs]
    failing = sum(bool(f) for f in failures)
    if not failing:
        return f"pass {len(runs)}/{len(runs)}"
    counts = {name: sum(name in f for f in failures) for name in CRITERIA}
    return f"FAIL {failing}/{len(runs)}: " + ", ".join(f"{name} {k}" for name, k in counts.items() if k)


def criterion_pass_lines(runs: dict[tuple[str, str, str], list[dict]], scenarios, estimators, controllers) -> list[str]:
    """The report's table of pass counts per criterion: for each controller and estimator, over every
    scenario's runs to which a criterion applies, how many passed it (``k/n``; a dash where none applies)."""
    applies = {
        "spin-out": lambda m: True,
        "course": lambda m: "course_completed" in m,
        "cones": lambda m: "cone_hits" in m,
        "FMVSS yaw 1.0 s": lambda m: "swd_ratio_1000" in m,
        "FMVSS yaw 1.75 s": lambda m: "swd_ratio_1750" in m,
        "FMVSS responsiveness": lambda m: m.get("swd_responsive") in (0.0, 1.0),
    }
    lines = [
        "",
        "## Passes per criterion",
        "",
        "Runs that passed each criterion over all scenarios' runs it applies to (responsiveness: from 5A).",
        "",
        "| controller | estimator | " + " | ".join(CRITERIA) + " |",
        "|---|---|" + "---:|" * len(CRITERIA),
    ]
    for c in controllers:
        for e in estimators:
            cells = [m for s in scenarios for m in runs[(s, e, c)]]
            counts = []
            for name in CRITERIA:
                judged = [m for m in cells if applies[name](m)]
                passed = sum(name not in failed_criteria(m) for m in judged)
                counts.append(f"{passed}/{len(judged)}" if judged else "—")
            lines.append(f"| {c} | {e} | " + " | ".join(counts) + " |")
    return lines


def build_controller(name: str, params):
    """A fresh controller: a :data:`control.CONTROLLERS` name, ``module:factory`` for your own
    (:func:`control.make_controller`), or ``rl:<run dir>`` for a policy."""
    if name.startswith(RL_PREFIX):
        from fourwis.training.rl import PolicyController

        return PolicyController(name.removeprefix(RL_PREFIX), params)
    return make_controller(name, params)


def naming_the_run(run: Callable):
    """``run(spec)`` whose ValueError / FloatingPointError (a user's estimator or controller
    returning garbage, a diverging filter) names the run: scenario, estimator, controller, seed."""

    @functools.wraps(run)
    def named(spec):
        try:
            return run(spec)
        except (ValueError, FloatingPointError) as err:
            parts = [getattr(spec, f) for f in ("scenario", "estimator", "controller") if hasattr(spec, f)]
            where = " x ".join(str(getattr(part, "name", part)) for part in parts)  # (a Scenario by its name)
            if type(err) not in (ValueError, FloatingPointError):  # a subclass may need more to be built
                err.add_note(f"in run {where}, seed {spec.seed}")
                raise
            raise type(err)(f"run {where}, seed {spec.seed}: {err}") from err

    return named


@naming_the_run
def _run(spec: RunSpec) -> tuple[RunSpec, dict[str, float], Trajectory | None]:
    scenario = _scenario(spec)
    controller = build_controller(spec.controller, scenario.vehicle_params)
    faults = SENSOR_FAULTS if spec.scenario.endswith(FAULT_SUFFIX) else ()
    traj = simulate(scenario, controller=controller, estimator=spec.estimator, seed=spec.seed, faults=faults)
    keep = spec.seed == 0  # trajectories of the first seed feed the plots
    return spec, run_metrics(traj, spec.swd_A), (traj if keep else None)


def _check(kind: str, names: Sequence[str], known: Sequence[str]) -> None:
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"unknown {kind} {unknown}; known: {list(known)}")


def check_matrix(
    scenarios: Sequence[str], estimators: Sequence[str], controllers: Sequence[str], seeds: int, jobs: int | None
) -> None:
    """ValueError naming a bad entry of the matrix, before anything runs: an unknown or repeated
    scenario, estimator or controller, a bad override, seeds or jobs, a policy ``rl:<run>`` whose
    run directory lacks a file or holds a damaged one (its model is loaded to find out)."""
    if not (is_integer(seeds) and seeds >= 1):
        raise ValueError(f"seeds must be an integer >= 1, got {seeds!r}")
    check_jobs(jobs)
    parsed = [parse_scenario(s) for s in scenarios]
    for name in estimators:
        check_estimator_name(name)
    for name in controllers:
        if not isinstance(name, str):
            raise ValueError(
                f"a controller is given by name, got {name!r}: pass your own as 'module:factory' "
                "(factory(params, dt) -> controller), or the object itself to envs.simulate"
            )
    runs = [_run_key(run, s.endswith(FAULT_SUFFIX)) for s, run in zip(scenarios, parsed)]  # what each one runs
    repeated = [s for s, run in zip(scenarios, runs) if runs.count(run) > 1]
    if repeated:
        raise ValueError(f"scenarios must be distinct: {repeated} run the same scenario")
    check_file_stems(scenarios)
    for kind, entries in (("estimators", estimators), ("controllers", controllers)):
        require_distinct(kind, entries)
    user = [c for c in controllers if ":" in c and not c.startswith(RL_PREFIX)]
    for name in user:
        import_factory(name, "controller")
    _check("controller(s)", [c for c in controllers if not c.startswith(RL_PREFIX) and c not in user], CONTROLLERS)
    for name in controllers:
        if name.startswith(RL_PREFIX):
            try:
                build_controller(name, VehicleParams())  # the run's config, model and normaliser read
            except (FileNotFoundError, ValueError) as err:
                raise ValueError(f"controller {name!r}: {err}") from None


def run_matrix(
    scenarios: Sequence[str] = HEADLINE,
    estimators: Sequence[str] = DEFAULT_ESTIMATORS,
    controllers: Sequence[str] = DEFAULT_CONTROLLERS,
    seeds: int = 2,
    jobs: int | None = None,
    progress: bool = True,
    checked: bool = False,
    backend: Backend | str | None = None,
) -> tuple[list[tuple[RunSpec, dict]], dict]:
    """Run the matrix in parallel on ``backend`` (training.pool: local processes by default, or
    Ray); returns per-run (spec, metrics) and seed-0 trajectories, the same on either backend.
    ``checked``: :func:`check_matrix` has passed already (else it runs first)."""
    if not checked:
        check_matrix(scenarios, estimators, controllers, seeds, jobs)
    backend = as_backend(backend)
    A = {s: entry_A(s) for s in scenarios}
    specs = [
        RunSpec(s, e, c, k, A[s]) for s in scenarios for c in controllers for e in estimators for k in range(seeds)
    ]
    results, trajectories = [], {}
    for spec, metrics, traj in parallel_map(_run, specs, jobs, "closed-loop runs", progress, backend):
        results.append((spec, metrics))
        if traj is not None:
            trajectories[(spec.scenario, spec.estimator, spec.controller)] = traj
    return results, trajectories


def aggregate(results: list[tuple[RunSpec, dict]]) -> dict[tuple[str, str, str], dict[str, float]]:
    """Mean of every metric over seeds per (scenario, estimator, controller)."""
    return mean_over_seeds(results, lambda spec: (spec.scenario, spec.estimator, spec.controller))


def write_csv(results: list[tuple[RunSpec, dict]], path: Path) -> Path:
    """runs.csv: a run per row, its scenario, estimator, controller, seed and verdict
    (:func:`run_verdict`), then its metrics in alphabetical order, each headed ``name [unit]``
    (:data:`METRIC_UNITS`); a metric the run does not have (or NaN) is an empty field."""
    names = sorted({m for _, metrics in results for m in metrics})
    return write_runs_csv(
        results,
        ["scenario", "estimator", "controller", "seed", "verdict"],
        lambda spec, metrics: [spec.scenario, spec.estimator, spec.controller, spec.seed, run_verdict(metrics)],
        names,
        METRIC_UNITS,
        path,
    )


def _seed_range(seeds: int) -> str:
    """The sensor-noise seeds 0 .. seeds - 1 in words ("seed 0", "seeds 0-2")."""
    return "seed 0" if seeds == 1 else f"seeds 0-{seeds - 1}"


def _fmt(value: float | None, scale: float = 1.0, digits: int = 2) -> str:
    return "—" if value is None or not math.isfinite(value) else f"{value * scale:.{digits}f}"


def markdown_report(
    results: Sequence[tuple[RunSpec, dict[str, float]]],
    scenarios: Sequence[str],
    estimators: Sequence[str],
    controllers: Sequence[str],
    seeds: int,
    header: Provenance | None = None,
) -> str:
    """report.md of the runs ``results`` (every cell of the matrix, ``seeds`` runs each): who wrote
    it (``header``, default: :func:`training.provenance.provenance` of now), the stability table
    with each cell's verdict, the ratios to the oracle, the estimation accuracy. Angles in
    degrees, missing values as a dash."""
    deg = 180.0 / math.pi
    table = aggregate(list(results))
    runs: dict[tuple[str, str, str], list[dict]] = {}
    for spec, metrics in results:
        runs.setdefault((spec.scenario, spec.estimator, spec.controller), []).append(metrics)
    header = header or provenance()
    lines = [
        "# fourwis closed-loop comparison",
        "",
        *header.markdown(),
        "",
        f"Runs: {len(scenarios)} scenarios x {len(estimators)} estimators x {len(controllers)} controllers "
        f"x {seeds} seeds (sensor-noise {_seed_range(seeds)}; means over seeds). The controller sees only the "
        "estimate. Angles in degrees; — : the metric does not apply to the scenario (runs.csv: an empty field).",
        *(
            [
                f"`swd_wet`: FMVSS 126 sine with dwell at {SWD_MULTIPLE}A on mu {SWD_MU} from 80 km/h "
                "(overrides after its ':' replace these)."
            ]
            if any(s.startswith("swd_wet") for s in scenarios)
            else []
        ),
        "Phase-plane peak: the largest index of the car's sideslip phase-plane stability region "
        "(control.reference.PhasePlaneRegion: max(|beta_dot + c1 beta| / c2, |r| / (3 mu g / u))) at speeds "
        ">= 10 m/s; above 1 the car left the region it recovers from by itself with the steering straight.",
        "",
        "Verdict: `pass k/n` when all n seeds pass, else `FAIL k/n` (k seeds failed) and each failed "
        "criterion with the number of seeds that failed it: "
        + "; ".join(f"*{name}*: {text}" for name, text in CRITERIA.items())
        + ". The pass-rate map (pass_rate.png, runs.csv `passed`) judges the same.",
        "",
        "## Stability",
        "",
        "| scenario | controller | estimator | verdict | peak beta [deg] | phase-plane peak "
        "| yaw-rate RMS err [deg/s] | spin-outs | path RMS [m] | cone hits | SWD ratio @1.0 s "
        "| SWD ratio @1.75 s | SWD displ. [m] | yaw moment RMS [N m] |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s in scenarios:
        for c in controllers:
            for e in estimators:
                m, cell = table[(s, e, c)], runs[(s, e, c)]
                spins = sum(bool(r["spin_out"]) for r in cell)
                lines.append(
                    f"| {s} | {c} | {e} | {verdict_cell(cell)} | {_fmt(m['peak_beta'], deg, 1)} "
                    f"| {_fmt(m['phase_plane_peak'])} | {_fmt(m['yaw_tracking_rms'], deg)} "
                    f"| {spins}/{len(cell)} | {_fmt(m.get('path_rms'))} | {_fmt(m.get('cone_hits'), 1, 1)} "
                    f"| {_fmt(m.get('swd_ratio_1000'), 100, 0)}{'%' if 'swd_ratio_1000' in m else ''} "
                    f"| {_fmt(m.get('swd_ratio_1750'), 100, 0)}{'%' if 'swd_ratio_1750' in m else ''} "
                    f"| {_fmt(m.get('swd_displacement'))} | {_fmt(m['yaw_moment_rms'], 1, 0)} |"
                )
    lines += criterion_pass_lines(runs, scenarios, estimators, controllers)
    lines += braking_lines(table, scenarios, estimators, controllers)
    lines += oracle_ratio_lines(table, scenarios, estimators, controllers)
    estimated = [e for e in estimators if e != "oracle"]  # (the oracle's errors are zero by construction)
    c = "none" if "none" in controllers else controllers[0]
    if estimated:
        lines += [
            "",
            "## Estimation accuracy (paper Table 2 form, open loop: controller none)"
            if "none" in controllers
            else f"## Estimation accuracy (controller {c})",
            "",
            "Means over seeds; the oracle (the truth itself, zero error) is left out.",
            "",
            "| scenario | estimator | RMSE u [m/s] | RMSE v [m/s] | RMSE beta [deg] | MAE beta [deg] "
            "| RMSE r [deg/s] | RMSE mu | final mu error |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for s in scenarios:
            for e in estimated:
                m = table[(s, e, c)]
                lines.append(
                    f"| {s} | {e} | {_fmt(m['rmse_u'], 1, 3)} | {_fmt(m['rmse_v'], 1, 3)} "
                    f"| {_fmt(m['rmse_beta'], deg, 3)} | {_fmt(m['mae_beta'], deg, 3)} "
                    f"| {_fmt(m['rmse_r'], deg, 3)} | {_fmt(m['rmse_mu'], 1, 3)} | {_fmt(m['final_mu_error'], 1, 3)} |"
                )
    return "\n".join(lines) + "\n"


def braking_lines(
    table: dict, scenarios: Sequence[str], estimators: Sequence[str], controllers: Sequence[str]
) -> list[str]:
    """The report's straight-line braking table (means over seeds): stopping distance from the brake
    application and its ratio to the ideal v^2 / (2 mu g), and the longest time a wheel stayed locked
    above 15 km/h; none without a ``straight_braking`` scenario."""
    braking = [s for s in scenarios if s.split(":")[0] == "straight_braking"]
    if not braking:
        return []
    lines = [
        "",
        "## Straight-line braking",
        "",
        "Full pedal from the scenario's speed: distance to standstill from the brake application, over "
        "v^2 / (2 mu g) on the road's friction, and the longest wheel lock above 15 km/h "
        "(envs.metrics.braking_metrics).",
        "",
        "| scenario | controller | estimator | stopping distance [m] | over ideal | longest lock [s] |",
        "|---|---|---|---:|---:|---:|",
    ]
    for s in braking:
        for c in controllers:
            for e in estimators:
                m = table[(s, e, c)]
                lines.append(
                    f"| {s} | {c} | {e} | {_fmt(m['stop_distance'], 1, 1)} | {_fmt(m['stop_ratio'], 1, 3)} "
                    f"| {_fmt(m['longest_lock'], 1, 3)} |"
                )
    return lines


#: the issue's target: a stability controller on the joint estimator within 10% of it on the truth
ORACLE_TOLERANCE = 1.10
#: below this [rad, rad/s] in the oracle's run a ratio is not shown (both values at the noise floor)
RATIO_FLOOR = 1e-3


def oracle_ratio(value: float, oracle: float) -> float:
    """``value`` / ``oracle``; NaN where the oracle's value is below RATIO_FLOOR or not finite."""
    return value / oracle if math.isfinite(oracle) and oracle >= RATIO_FLOOR else math.nan


def oracle_ratio_lines(
    table: dict, scenarios: Sequence[str], estimators: Sequence[str], controllers: Sequence[str]
) -> list[str]:
    """The report's section of ratios to the oracle (peak sideslip / yaw-rate RMS, means over
    seeds) for every controlled (scenario, controller) and every other estimator; none without
    the oracle or a controller."""
    others = [e for e in estimators if e != "oracle"]
    controlled = [c for c in controllers if c != "none"]
    if "oracle" not in estimators or not others or not controlled:
        return []

    def cell(value: float) -> str:
        text = _fmt(value)
        return f"**{text}**" if math.isfinite(value) and value > ORACLE_TOLERANCE else text

    lines = [
        "",
        "## Against the oracle",
        "",
        "Each estimator's mean over seeds as a ratio to the oracle's, same scenario and controller: peak "
        f"sideslip / yaw-rate RMS error; bold above {ORACLE_TOLERANCE:.2f} (the target for the joint "
        f"estimator: within 10%); — where the oracle's value is below {RATIO_FLOOR:g} rad (rad/s).",
        "",
        "| scenario | controller | " + " | ".join(others) + " |",
        "|---|---|" + "---:|" * len(others),
    ]
    for s in scenarios:
        for c in controlled:
            oracle = table[(s, "oracle", c)]
            cells = [
                f"{cell(oracle_ratio(table[(s, e, c)]['peak_beta'], oracle['peak_beta']))} / "
                f"{cell(oracle_ratio(table[(s, e, c)]['yaw_tracking_rms'], oracle['yaw_tracking_rms']))}"
                for e in others
            ]
            lines.append(f"| {s} | {c} | " + " | ".join(cells) + " |")
    return lines


def plot_report(
    table: dict, trajectories: dict, scenarios, estimators, controllers, out: Path, seeds: int
) -> list[Path]:
    """The comparison's PNGs in ``out``: peak sideslip (means over the ``seeds``), the pass-rate
    map, and per scenario the time series of seed 0 (yaw rate with the reference it is judged
    against, sideslip, mean mu, the phase portrait); each title says which seeds it draws."""
    plt = pyplot()
    over = _seed_range(seeds)

    paths = []
    fig, ax = plt.subplots(figsize=(12, 5))
    combos = [(c, e) for c in controllers for e in estimators]
    width, largest = 0.8 / len(combos), 0.0
    for i, (c, e) in enumerate(combos):
        values = [math.degrees(table[(s, e, c)]["peak_beta"]) for s in scenarios]
        largest = max(largest, *values)
        bars = ax.bar(np.arange(len(scenarios)) + i * width, values, width, label=f"{c} / {e}")
        ax.bar_label(bars, fmt="%.1f", fontsize=6, rotation=90, padding=2)  # the log scale hides small gaps
    ax.set_xticks(np.arange(len(scenarios)) + 0.4 - width / 2, scenarios, rotation=20)
    if largest > 0:  # (every run straight: nothing to put on a log scale)
        ax.set_yscale("log")
    ax.set_ylabel("peak |sideslip| [deg]" + " (log scale)" * (largest > 0))
    ax.legend(fontsize=8, ncol=2)
    ax.set_title(f"Peak sideslip by scenario, controller and estimator (mean over {over})")
    fig.tight_layout()
    paths.append(atomic_write(out / "peak_sideslip.png", lambda p: fig.savefig(p, format="png", dpi=110)))
    plt.close(fig)

    # one heat map per controller, stacked, sharing the scenario axis
    fig, axes = plt.subplots(
        len(controllers),
        1,
        figsize=(max(6.0, 2.0 + 1.1 * len(scenarios)), 1.4 + len(controllers) * (0.6 + 0.3 * len(estimators))),
        squeeze=False,
        sharex=True,
        layout="constrained",
    )
    for ax, c in zip(axes[:, 0], controllers):
        rate = np.array([[table[(s, e, c)]["passed"] for s in scenarios] for e in estimators])
        ax.imshow(rate, vmin=0.0, vmax=1.0, cmap="RdYlGn", aspect="auto")
        for (i, j), value in np.ndenumerate(rate):
            ax.text(j, i, f"{100 * value:.0f}%", ha="center", va="center", fontsize=8)
        ax.set_yticks(range(len(estimators)), estimators, fontsize=8)
        ax.set_title(f"controller {c}", fontsize=9)
    axes[-1, 0].set_xticks(range(len(scenarios)), scenarios, rotation=30, ha="right", fontsize=8)
    fig.suptitle(
        f"pass rate over {over}: no spin-out, course completed, no cone hit, FMVSS 126 passed on sine with dwell",
        fontsize=9,
    )
    paths.append(atomic_write(out / "pass_rate.png", lambda p: fig.savefig(p, format="png", dpi=110)))
    plt.close(fig)

    for s in scenarios:
        fig, axes = plt.subplots(1, 4, figsize=(19, 4))
        referenced = False
        for c in controllers:
            for e in estimators:
                traj = trajectories.get((s, e, c))
                if traj is None:
                    continue
                color = None
                if not (c == "none" and e != estimators[0]):  # without a controller the estimate does not act
                    label = "no control" if c == "none" else f"{c} / {e}"
                    beta = np.degrees(traj.truth.beta)
                    color = axes[0].plot(traj.t, np.degrees(traj.state[:, S_R]), label=label)[0].get_color()
                    axes[0].plot(
                        traj.t,
                        np.degrees(reference_yaw_rate_of(traj)),
                        ":",
                        lw=1,
                        color=color,
                        label=None if referenced else "dotted: its reference (2-DOF, true mu)",
                    )
                    referenced = True
                    axes[1].plot(traj.t, beta, label=label, color=color)
                    axes[3].plot(beta, np.gradient(beta, traj.t), lw=0.8, label=label, color=color)
                if c == controllers[-1]:  # in the colour of that run
                    axes[2].plot(traj.t, traj.estimate.mu.mean(axis=1), label=f"{e} estimate", color=color)
        first = next((t for k, t in trajectories.items() if k[0] == s), None)
        if first is not None:
            axes[2].plot(first.t, first.truth.mu.mean(axis=1), "k--", label="truth")
            # the stable band at the run's median speed and lowest road friction
            lowest = int(np.argmin(first.truth.mu.mean(axis=1)))
            c1, c2 = PhasePlaneRegion.default().coefficients(
                np.median(first.truth.u)[None], first.truth.mu[lowest][None]
            )
            sideslip, rate = np.array(axes[3].get_xlim()), axes[3].get_ylim()
            for sign in (1.0, -1.0):
                axes[3].plot(
                    sideslip,
                    sign * math.degrees(c2[0]) - c1[0] * sideslip,
                    "k:",
                    lw=1,
                    label="stable band" if sign > 0 else None,
                )
            axes[3].set(xlim=sideslip, ylim=rate)
            axes[3].legend(fontsize=7)
        for a, title in zip(
            axes,
            (
                "yaw rate [deg/s]",
                "sideslip [deg]",
                "mean mu (last controller)",
                "phase portrait: sideslip rate [deg/s] vs sideslip [deg]",
            ),
        ):
            a.set_title(title, fontsize=9)
            a.set_xlabel("t [s]")
            a.grid(alpha=0.3)
        axes[3].set_xlabel("sideslip [deg]")
        axes[0].legend(fontsize=7)
        axes[2].legend(fontsize=7)
        fig.suptitle(f"{s} (seed 0)")
        fig.tight_layout()
        paths.append(
            atomic_write(out / f"{file_stem(s)}.png", lambda p, fig=fig: fig.savefig(p, format="png", dpi=100))
        )
        plt.close(fig)
    return paths


def compare(
    out: str | Path,
    scenarios: Sequence[str] = HEADLINE,
    estimators: Sequence[str] = DEFAULT_ESTIMATORS,
    controllers: Sequence[str] = DEFAULT_CONTROLLERS,
    seeds: int = 2,
    jobs: int | None = None,
    command: str | None = None,
    backend: Backend | str | None = None,
) -> Path:
    """Run the matrix and write report.md, runs.csv and PNG plots into ``out`` as one set
    (:func:`training.io.staged_output`: an interrupt leaves the folder's previous set); returns
    the report's path. ``command``: what the report's header says wrote it (default: this
    process's command line); ``backend``: where the runs go (:func:`run_matrix`). Bad arguments
    and an unwritable ``out`` raise ValueError before any run."""
    check_matrix(scenarios, estimators, controllers, seeds, jobs)
    out = check_writable(out)
    pyplot()  # (its plots need matplotlib: say so before the runs, not after them)
    results, trajectories = run_matrix(scenarios, estimators, controllers, seeds, jobs, checked=True, backend=backend)
    header = provenance(command)
    with staged_output(out) as stage:
        write_csv(results, stage / "runs.csv")
        plot_report(aggregate(results), trajectories, scenarios, estimators, controllers, stage, seeds)
        atomic_write_text(
            stage / "report.md", markdown_report(results, scenarios, estimators, controllers, seeds, header)
        )
    return out / "report.md"


BASELINES = ("none", "dyc-lqr")  #: the controllers ``fourwis evaluate`` runs beside a policy


def evaluate(
    run: str | Path,
    out: str | Path,
    scenarios,
    estimator: str | None = None,
    seeds: int = 2,
    jobs: int | None = None,
    command: str | None = None,
    backend=None,
) -> Path:
    """``fourwis evaluate``: the policy of ``run`` (its run directory, its model.zip or a
    checkpoint's .zip) as controller ``rl:<run>`` beside no control and the DYC-LQR baseline,
    through :func:`compare` on ``backend`` (training.pool), with ``estimator``
    in the loop for all three (None: the one the run was trained with, from its config.json);
    returns the report path."""
    from fourwis.envs.gym_env import EnvConfig
    from fourwis.training.runs import read_run_config, run_files

    config = run_files(run)[2]
    if estimator is None:
        trained_on = read_run_config(config)["env_kwargs"] if config.exists() else {}
        estimator = trained_on.get("estimator", EnvConfig.estimator)
    return compare(
        out, scenarios, [estimator], [*BASELINES, f"rl:{Path(run)}"], seeds, jobs, command=command, backend=backend
    )

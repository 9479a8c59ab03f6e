"""What fourwis offers by name (``fourwis list``): the scenarios, estimators, controllers and
recorded logs, one line each: the name, what it is, its defaults. The defaults are read from
the code that builds each one (the scenario builders' signatures and the scenarios they build,
the estimators' and controllers' fields), so the list cannot drift from what runs."""

from __future__ import annotations

import inspect
import json
from dataclasses import fields
from importlib import resources

from fourwis.control import CONTROLLERS, make_controller
from fourwis.control.esc import EXIT_SIDESLIP, EXIT_YAW_ERROR, BrakeESC
from fourwis.control.reference import STABLE_SIDESLIP, STABLE_YAW_ERROR
from fourwis.envs import scenarios as scenario_builders
from fourwis.envs.gym_env import EnvConfig
from fourwis.envs.scenarios import SCENARIOS
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation import ESTIMATORS, TRUTH_GROUPS, StateEstimator, tuned_noise
from fourwis.estimation.joint import FRICTION_KINDS, ROBUST_KINDS, TUNED_KINDS
from fourwis.training.compare import SWD_MU, SWD_MULTIPLE

SECTIONS = ("scenarios", "estimators", "controllers", "logs")

#: what each scenario is (its defaults come from its builder)
SCENARIO_SUMMARIES = {
    "paper_dlc": "paper 3.3.3 (1): double lane change on the ISO 3888-1 course, path-following driver",
    "paper_step": "paper 3.3.3 (2): steering-wheel step of `angle` rad at `step_time` (default 5 s)",
    "paper_sine": "paper 3.3.3 (3): sinusoidal steering wheel from 1 s",
    "paper_split_dlc": "paper 4.3.1: double lane change on a left/right split road",
    "paper_serpentine": "paper 4.3.2: slalom through `n_cones` cones `spacing` m apart",
    "sine_with_dwell": "FMVSS 126 sine with dwell (0.7 Hz, 500 ms dwell) from `start` (default 1 s), coasting",
    "slowly_increasing_steer": "FMVSS 126 characterisation: steering-wheel ramp at constant speed (finds A)",
    "iso3888_2": "ISO 3888-2 obstacle-avoidance lane change, coasting from the course entry",
    "mu_jump": "steady cornering at `lateral_g` onto a `mu_patch` surface from X = `patch_x` m",
    "straight_braking": "full braking in a straight line from `speed_kph` at `brake_at` s (ABS on unless switched off)",
    "random": "domain-randomised RL training scenario (speed, road and steering drawn from `seed`)",
}

#: what each estimator is (its defaults come from StateEstimator's fields and the shipped tuning)
ESTIMATOR_SUMMARIES = {
    "oracle": "the truth passed through: a perfect estimator, the reference the others are judged by",
    "ekf": "extended Kalman filter on the paper's 3-DOF + Dugoff model (a baseline)",
    "ckf": "cubature Kalman filter (third-degree spherical-radial rule) on the same model",
    "fkf": "federated CKF: sub-filters on [ax, ay, r] and [ay, r] fused by information sharing",
    "alo-fkf": "paper section 3: federated CKF with Huber-robust sub-filters and ALO-tuned noise",
    "joint-paper": "paper section 4, the full system: state FKF and per-wheel friction FKF exchanging estimates",
    "joint": "joint-paper with combined slip from the measured longitudinal force (docs/decisions/0034)",
}

#: what each controller is (its defaults come from the StabilityController make_controller builds)
CONTROLLER_SUMMARIES = {
    "none": "no stability controller: the driver alone",
    "dyc-lqr": "direct yaw-moment control, LQR law gain-scheduled on speed, torques allocated per wheel",
    "dyc-smc": "direct yaw-moment control, sliding-mode law, torques allocated per wheel",
    "dyc-lqr-4ws": "dyc-lqr plus the paper's eq. 20 rear steer",
    "dyc-smc-4ws": "dyc-smc plus the paper's eq. 20 rear steer",
    "esc": "brake-based ESC: single-wheel braking on yaw-rate and sideslip error, entry and exit thresholds",
}


#: the columns' widths: name, what it is
_NAME, _WHAT = 32, 92


def _line(name: str, what: str, defaults: str) -> str:
    return f"{name:<{_NAME}} {what:<{_WHAT}} {defaults}".rstrip()


def _mu_text(mu) -> str:
    if mu is None:
        return "mu drawn"
    if isinstance(mu, tuple):
        return f"mu {mu[0]:g} left / {mu[1]:g} right"
    return f"mu {mu:g}"


def _value_text(value) -> str:
    return f"({', '.join(f'{v:g}' for v in value)})" if isinstance(value, tuple) else f"{value:g}"


def scenario_rows() -> list[tuple[str, str, str]]:
    """One row per scenario of :data:`envs.scenarios.SCENARIOS` (and compare's ``swd_wet``):
    name, what it is, its defaults (speed, road friction, duration, the builder's own options)."""
    common = {"speed_kph", "mu", "duration", "steering", "rear_steer_feedforward", "params"}
    rows = []
    for name, scenario in SCENARIOS.items():
        parameters = inspect.signature(getattr(scenario_builders, name)).parameters
        if parameters["speed_kph"].default is None:  # (random: drawn)
            low, high = parameters["speed_range_kph"].default
            speed = f"speed drawn in {low:g}-{high:g} km/h"
        else:
            speed = f"{scenario.speed_kph:g} km/h"
        options = [
            f"{key}={_value_text(p.default)}"
            for key, p in parameters.items()
            if key not in common and p.default is not None
        ]
        duration = f"{scenario.duration:.1f} s" + (
            " (set by the manoeuvre)" if parameters["duration"].default is None else ""
        )
        defaults = f"{speed}, {_mu_text(parameters['mu'].default)}, {duration}" + (
            f"; {', '.join(options)}" if options else ""
        )
        rows.append((name, SCENARIO_SUMMARIES[name], defaults))
    rows.append(
        (
            "swd_wet",
            f"compare's alias of sine_with_dwell:mu={SWD_MU:g},amplitude_A={SWD_MULTIPLE:g} (A: the car's 0.3 g angle)",
            f"{SCENARIOS['sine_with_dwell'].speed_kph:g} km/h, mu {SWD_MU:g}, {SWD_MULTIPLE:g}A",
        )
    )
    return rows


def estimator_rows() -> list[tuple[str, str, str]]:
    """One row per estimator of :data:`estimation.ESTIMATORS`: name, what it is, its defaults
    (friction: fixed or estimated and from what, noise: hand-set or the shipped tuning, the
    Huber threshold of the robust ones, the step)."""
    default = {f.name: f.default for f in fields(StateEstimator) if f.init}
    tuned = tuned_noise() is not None
    rows = []
    for name in ESTIMATORS:
        if name == "oracle":
            defaults = "no sensors read, no settings"
        else:
            mu = (
                f"mu estimated from {default['nominal_mu']:g}"
                if name in FRICTION_KINDS
                else f"mu fixed at {default['nominal_mu']:g}"
            )
            noise = (
                "ALO-tuned noise (estimation/data/tuned_noise.json)"
                if name in TUNED_KINDS and tuned
                else "hand-set noise"
            )
            robust = f", Huber c {default['huber_c']:g}" if name in ROBUST_KINDS else ""
            defaults = f"{mu}, {noise}{robust}, step {1000 * default['dt']:g} ms"
        rows.append((name, ESTIMATOR_SUMMARIES[name], defaults))
    return rows


def controller_rows() -> list[tuple[str, str, str]]:
    """One row per controller of :data:`control.CONTROLLERS` and per shipped policy
    (``rl:training/policies/<name>``): name, what it is, its defaults."""
    rows = []
    for name in CONTROLLERS:
        controller = make_controller(name, VehicleParams())
        if controller is None:
            defaults = "no settings"
        elif isinstance(controller, BrakeESC):
            defaults = (
                f"entry {STABLE_YAW_ERROR:g} rad/s or {STABLE_SIDESLIP:g} x the sideslip bound, exit "
                f"{EXIT_YAW_ERROR:g} rad/s and {EXIT_SIDESLIP:g} x; step {1000 * controller.dt:g} ms"
            )
        else:
            understeer = (
                "the car's own" if controller.reference_understeer is None else f"{controller.reference_understeer:g}"
            )
            defaults = (
                f"law {controller.law}, rear steer {'on' if controller.rear_steer else 'off'}, "
                f"mu_margin {controller.mu_margin:g} sigma, friction_ellipse {controller.friction_ellipse}, "
                f"reference understeer {understeer}, step {1000 * controller.dt:g} ms"
            )
        rows.append((name, CONTROLLER_SUMMARIES[name], defaults))
    policies = resources.files("fourwis.training").joinpath("policies")
    for run in sorted((p for p in policies.iterdir() if p.is_dir()), key=lambda p: p.name):
        config = json.loads(run.joinpath("config.json").read_text())
        env = config["env_kwargs"]
        rows.append(
            (
                f"rl:training/policies/{run.name}",
                f"a {config['algo'].upper()} policy shipped with the package (fourwis train; needs the rl extra)",
                f"trained {config['timesteps']:,} env steps with estimator "
                f"{env.get('estimator', EnvConfig.estimator)}, observation "
                f"{env.get('observation', EnvConfig.observation)}",
            )
        )
    return rows


def log_rows() -> list[tuple[str, str, str]]:
    """One row per recorded log the package ships (:func:`training.logs.shipped_logs`): name,
    what it is, its length, rate and vehicle file."""
    from fourwis.training.logs import read_log, shipped_logs

    rows = []
    for name in shipped_logs():
        log = read_log(name)
        rate = (len(log.t) - 1) / log.duration
        what = log.metadata.get("description", "").split(":")[0]
        rows.append((name, what, f"{log.duration:.0f} s at {rate:.0f} Hz, vehicle {log.metadata.get('vehicle', '?')}"))
    return rows


#: the rows of each section, and what the list adds below them
ROWS = {"scenarios": scenario_rows, "estimators": estimator_rows, "controllers": controller_rows, "logs": log_rows}
FOOTNOTES = {
    "scenarios": "(overrides: NAME:key=value,... ; a +faults suffix adds gyro faults in compare)",
    "estimators": f"(also: NAME+true-<{'|'.join(TRUTH_GROUPS)}> reports those quantities from the truth; "
    "module:factory for your own)",
    "controllers": "(also: rl:<run dir> or rl:<run dir>/model.zip for your own policy; "
    "module:factory for your own law)",
    "logs": "(fourwis estimate --log NAME, or --log FILE --vehicle FILE for your own: docs/logs.md)",
}
NO_LOGS = "no recorded logs shipped"


def rows(section: str) -> list[tuple[str, str, str]]:
    """(name, what it is, its defaults) of each entry of ``section`` (:data:`SECTIONS`)."""
    if section not in SECTIONS:
        raise ValueError(f"unknown section {section!r}; known: {list(SECTIONS)}")
    return ROWS[section]()


def catalog(section: str | None = None) -> str:
    """The text of ``fourwis list [section]``: one section of :data:`SECTIONS`, or all (None)."""
    if section is not None and section not in SECTIONS:
        raise ValueError(f"unknown section {section!r}; known: {list(SECTIONS)}")
    blocks = []
    for name in SECTIONS if section is None else (section,):
        entries = rows(name)
        if name == "logs" and not entries:
            blocks.append(f"{name}:\n  {NO_LOGS}")
            continue
        lines = [f"{name}:", "  " + _line("name", "what it is", "defaults")]
        lines += [f"  {_line(*entry)}" for entry in entries] + ([f"  {FOOTNOTES[name]}"] if FOOTNOTES[name] else [])
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks)

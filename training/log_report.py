"""The estimators on a recorded log, beside the baselines: ``fourwis estimate --log`` and
``fourwis tune --log``.

:func:`estimate_log_report` runs every estimator and baseline on a log (training.replay) and
writes, as one set (training.io.staged_output): report.md, scores.csv (one row per estimator or
baseline: :data:`SCORE_COLUMNS`), sideslip.png (the sideslip over time against the reference,
the whole log and the 20 s around its largest reference sideslip), friction.png (each
estimator's mean friction over time, and the reference where the log has one) and errors.png
(histograms of the sideslip error). :func:`tune_log_report` tunes an estimator's noise on a
log's first part and scores it on the rest, beside its shipped noise and the baselines.

Scores are taken over the samples where the reference is given; the yaw rate against the
log's ``ref_yaw_rate``, else against the measured yaw rate itself (a log without an
independent yaw-rate reference: then r_rmse says how far a filter strays from its gyro).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from fourwis.core.checks import is_integer
from fourwis.core.types import CH_AX, CH_AY, CH_OMEGA, CH_SPEED, CH_YAW_RATE
from fourwis.estimation import BASELINES, NoiseParams, check_estimator_name, make_estimator, parse_estimator_name
from fourwis.estimation.joint import KINDS
from fourwis.estimation.optimizers import METHODS, minimize
from fourwis.training.io import (
    atomic_write,
    atomic_write_json,
    atomic_write_text,
    check_writable,
    pyplot,
    staged_output,
)
from fourwis.training.logs import Log, log_path, read_log, shipped_logs
from fourwis.training.provenance import Provenance, provenance
from fourwis.training.replay import LogInputs, ReplayResult, gap_summary, log_inputs, log_noise, replay_estimator
from fourwis.training.tables import csv_number, require_distinct
from fourwis.training.vehicle_file import Vehicle, fourwis_vehicle, read_vehicle

DEG = 180.0 / math.pi
LOG_ESTIMATORS = KINDS + BASELINES  #: what ``fourwis estimate --log`` runs by default
#: scores.csv's columns, in order (units in the names: deg, m/s, rad/s, deg/s; "-" dimensionless)
SCORE_COLUMNS = (
    "estimator",
    "beta_rmse_deg",
    "beta_max_err_deg",
    "beta_mae_deg",
    "vy_rmse",  # [m/s]
    "vx_rmse",  # [m/s]
    "r_rmse",  # [rad/s]
    "r_rmse_deg_s",
    "beta_within_2sigma",  # the fraction of samples with |beta error| <= 2 beta_std (filters only)
    "mu_mean_final",  # the wheels' mean friction estimate at the end [-]
    "mu_mae",  # mean |mu_hat - mu| against ref_mu [-]
    "runtime_s",
    "status",
)
ZOOM = 20.0  #: [s] the zoomed window of sideslip.png


def resolve_vehicle(log: Log, vehicle: str | Path | Vehicle | None) -> Vehicle:
    """The car of a log: ``vehicle`` (a Vehicle or a vehicle file), else the file the log's
    metadata names (relative to the log), else ValueError asking for one."""
    if isinstance(vehicle, Vehicle):
        return vehicle
    if vehicle is not None:
        return read_vehicle(vehicle)
    named = log.metadata.get("vehicle")
    if named == "fourwis":
        return fourwis_vehicle()
    if named:
        return read_vehicle(Path(log.source).parent / named)
    raise ValueError(f"log {log.source} names no vehicle file (metadata 'vehicle'): give --vehicle FILE")


def _rmse(error: np.ndarray) -> float:
    return float(np.sqrt(np.mean(error**2))) if error.size else math.nan


def scores(result: ReplayResult, inputs: LogInputs, rows: np.ndarray | None = None) -> dict:
    """The :data:`SCORE_COLUMNS` of one run (``rows``: the samples scored, all by default;
    within them, those where each reference is finite)."""
    rows = np.arange(len(inputs.t)) if rows is None else rows
    out = {name: math.nan for name in SCORE_COLUMNS[1:-1]}
    out["runtime_s"] = result.seconds
    out["status"] = "ok" if result.error is None else f"failed: {result.error}"
    estimate = result.estimate
    if estimate is None:
        return out
    ref = inputs.references

    def error(field: np.ndarray, reference: np.ndarray) -> np.ndarray:
        e = field[rows] - reference[rows]
        return e[np.isfinite(e)]

    if "beta" in ref:
        e = error(estimate.beta, ref["beta"])
        out["beta_rmse_deg"] = _rmse(e) * DEG
        out["beta_max_err_deg"] = float(np.max(np.abs(e))) * DEG if e.size else math.nan
        out["beta_mae_deg"] = float(np.mean(np.abs(e))) * DEG if e.size else math.nan
        sigma = estimate.beta_std[rows]
        both = np.isfinite(estimate.beta[rows] - ref["beta"][rows]) & np.isfinite(sigma)
        if np.any(sigma[both] > 0):
            out["beta_within_2sigma"] = float(
                np.mean(np.abs(estimate.beta[rows][both] - ref["beta"][rows][both]) <= 2 * sigma[both])
            )
    for name, key in (("vy_rmse", "vy"), ("vx_rmse", "vx")):
        if key in ref:
            out[name] = _rmse(error(estimate.v if key == "vy" else estimate.u, ref[key]))
    yaw_ref = ref.get("yaw_rate")
    if yaw_ref is None:
        yaw_ref = np.where(inputs.valid[:, CH_YAW_RATE], inputs.values[:, CH_YAW_RATE], np.nan)
    out["r_rmse"] = _rmse(error(estimate.r, yaw_ref))
    out["r_rmse_deg_s"] = out["r_rmse"] * DEG
    final = estimate.mu[rows][np.isfinite(estimate.mu[rows]).all(axis=1)]
    out["mu_mean_final"] = float(final[-1].mean()) if len(final) else math.nan
    if "mu" in ref:
        e = (estimate.mu[rows] - ref["mu"][rows]).ravel()
        e = e[np.isfinite(e)]
        out["mu_mae"] = float(np.mean(np.abs(e))) if e.size else math.nan
    return out


def scores_csv(rows: list[dict]) -> str:
    """scores.csv: :data:`SCORE_COLUMNS`, numbers to 6 significant digits, NaN empty."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(SCORE_COLUMNS)
    for row in rows:
        writer.writerow(
            [row["estimator"], *(csv_number(row[c]) for c in SCORE_COLUMNS[1:-1]), row["status"]]
        )  # fmt: skip
    return buf.getvalue()


def _cell(value: float, digits: int = 3) -> str:
    return "—" if not math.isfinite(value) else f"{value:.{digits}f}"


def _table(rows: list[dict]) -> list[str]:
    lines = [
        "| estimator | beta RMSE [deg] | beta max err [deg] | beta MAE [deg] | vy RMSE [m/s] | vx RMSE [m/s] "
        "| r RMSE [deg/s] | within 2 sigma | mu at the end | mu MAE | status |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        status = "ok" if r["status"] == "ok" else "failed (below)"
        lines.append(
            f"| {r['estimator']} | {_cell(r['beta_rmse_deg'])} | {_cell(r['beta_max_err_deg'])} | "
            f"{_cell(r['beta_mae_deg'])} | {_cell(r['vy_rmse'])} | {_cell(r['vx_rmse'])} | "
            f"{_cell(r['r_rmse_deg_s'])} | {_cell(r['beta_within_2sigma'], 2)} | {_cell(r['mu_mean_final'], 2)} | "
            f"{_cell(r['mu_mae'])} | {status} |"
        )
    failures = [f"- `{r['estimator']}`: {r['status'].removeprefix('failed: ')}" for r in rows if r["status"] != "ok"]
    return lines + ([""] + failures if failures else [])


def _held_fraction(inputs: LogInputs) -> dict[str, float]:
    """The fraction of each measurement channel's samples that repeat the previous one exactly."""
    out = {}
    for name, c in (("ax", CH_AX), ("ay", CH_AY), ("yaw_rate", CH_YAW_RATE), ("speed", CH_SPEED)):
        x = inputs.values[inputs.valid[:, c], c]
        if x.size > 1:
            out[name] = float(np.mean(np.diff(x) == 0))
    return out


def log_summary(log: Log, inputs: LogInputs, vehicle: Vehicle) -> list[str]:
    """The report's description of the log, the car and the inputs made of them."""
    dt = inputs.nominal_dt
    n_gaps, longest, missing, when = gap_summary(log.t, dt)
    held = _held_fraction(inputs)
    c_f, c_r = make_estimator("ckf", vehicle.params, dt, **vehicle.estimator_options()).params.axle_cornering_stiffness
    refs = ", ".join(sorted(inputs.references)) or "none"
    lines = [
        "## The log",
        "",
        f"- `{log.name}` ({log.source}): {len(log.t)} samples over {log.duration:.1f} s, nominal step "
        f"{1000 * dt:g} ms ({1 / dt:.4g} Hz).",
        f"- Time gaps (steps over 1.5 nominal): {n_gaps}"
        + (
            f", the longest {1000 * longest:.1f} ms at t = {when:.3f} s, {missing:.3f} s missing in all "
            "(the estimators coast through them on the model)"
            if n_gaps
            else ""
        )
        + ".",
        "- Held samples (a value repeating the previous one exactly; the estimators skip them as "
        "no new measurement): " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in held.items()) + ".",
        f"- Channels: {', '.join(f'{k} [{v}]' for k, v in log.units.items())}"
        + (f"; ignored (not in the format): {', '.join(log.ignored)}" if log.ignored else "")
        + ".",
        f"- References for scoring: {refs}"
        + ("" if "yaw_rate" in inputs.references else "; the yaw rate is scored against the measured gyro")
        + ".",
        "- Inputs made for the estimators: " + "; ".join(inputs.notes) + ".",
        f"- The estimators start at {inputs.initial_speed:.3f} m/s"
        + (" (the log's metadata initial_speed)." if "initial_speed" in log.metadata else "."),
    ]
    for key in ("source", "license", "description"):
        if key in log.metadata:
            lines.append(f"- {key.capitalize()}: {log.metadata[key]}")
    p = vehicle.params
    lines += [
        "",
        "## The car",
        "",
        f"- `{vehicle.name}` ({vehicle.source}): mass {p.mass:g} kg, yaw inertia {p.yaw_inertia:g} kg m^2, "
        f"a {p.cg_to_front:g} m, b {p.cg_to_rear:g} m, tracks {p.track_front:g} / {p.track_rear:g} m, "
        f"CG height {p.cg_height:g} m, wheel radius {' / '.join(f'{r:g}' for r in vehicle.wheel_radius)} m.",
        f"- Tyres: {'its own per axle' if vehicle.tyres else 'fourwis own tyre fit on both axles'}: axle cornering "
        f"stiffness at the static loads {c_f / 1000:.1f} / {c_r / 1000:.1f} kN/rad (front / rear); "
        f"nominal road friction {vehicle.nominal_mu:g} (the fixed-mu filters hold it, the joint estimator starts "
        "from it).",
    ]
    if vehicle.sensor_noise:
        lines.append(
            "- Declared sensor noise (added in quadrature to the filters' measurement noise): "
            + ", ".join(f"{k} {v:g}" for k, v in vehicle.sensor_noise.items())
        )
    return lines


def _check_names(estimators: Sequence[str]) -> list[str]:
    if not estimators:
        raise ValueError("estimators must not be empty")
    for name in estimators:
        check_estimator_name(name)
        base = parse_estimator_name(name)[0]
        if base == "oracle" or "+true-" in name:
            raise ValueError(f"estimator {name!r} needs the simulator's truth; a log has none")
    require_distinct("estimators", estimators)
    return list(estimators)


def run_on_log(
    log: Log, vehicle: Vehicle, estimators: Sequence[str], noise: NoiseParams | None = None, progress: bool = False
) -> tuple[LogInputs, dict[str, ReplayResult]]:
    """Every estimator of ``estimators`` replayed on ``log`` (training.replay)."""
    inputs = log_inputs(log, vehicle)
    results = {}
    for name in estimators:
        if progress:
            print(f"  {name} ...", flush=True)
        results[name] = replay_estimator(name, vehicle, inputs, noise)
    return inputs, results


def _zoom_window(t: np.ndarray, beta: np.ndarray | None) -> tuple[float, float]:
    if beta is None or not np.isfinite(beta).any():
        return float(t[0]), float(min(t[-1], t[0] + ZOOM))
    centre = float(t[int(np.nanargmax(np.abs(beta)))])
    start = min(max(centre - ZOOM / 2, float(t[0])), max(float(t[-1]) - ZOOM, float(t[0])))
    return start, start + ZOOM


def plot_log(inputs: LogInputs, results: dict[str, ReplayResult], out: Path, title: str) -> list[Path]:
    """sideslip.png, friction.png and errors.png (module docstring) into folder ``out``."""
    plt = pyplot()
    t, ref = inputs.t, inputs.references
    beta_ref = ref.get("beta")
    ran = {name: r.estimate for name, r in results.items() if r.estimate is not None}
    paths = []
    fig, axes = plt.subplots(2, 1, figsize=(14, 8))
    start, stop = _zoom_window(t, beta_ref)
    for ax, window in zip(axes, (None, (start, stop))):
        rows = slice(None) if window is None else (t >= window[0]) & (t <= window[1])
        if beta_ref is not None:
            ax.plot(t[rows], DEG * beta_ref[rows], "k", lw=1.6, label="reference")
        for name, e in ran.items():
            ax.plot(t[rows], DEG * e.beta[rows], lw=0.8, ls="--" if name in BASELINES else "-", label=name)
        ax.set(xlabel="t [s]", ylabel="sideslip beta [deg]")
        ax.grid(alpha=0.3)
    axes[0].set_title(f"{title}: sideslip, the whole log")
    axes[1].set_title(f"the {ZOOM:g} s around the largest reference sideslip")
    axes[0].legend(loc="upper right", fontsize=7, ncol=3)
    fig.tight_layout()
    paths.append(atomic_write(out / "sideslip.png", lambda p: fig.savefig(p, format="png", dpi=90)))
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(14, 4.5))
    if "mu" in ref:
        ax.plot(t, ref["mu"].mean(axis=1), "k", lw=1.6, label="reference (mean of the wheels)")
    for name, e in ran.items():
        ax.plot(t, e.mu.mean(axis=1), lw=0.9, ls="--" if name in BASELINES else "-", label=name)
    ax.set(xlabel="t [s]", ylabel="friction mu, mean of the wheels [-]", title=f"{title}: road friction")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7, ncol=3)
    fig.tight_layout()
    paths.append(atomic_write(out / "friction.png", lambda p: fig.savefig(p, format="png", dpi=90)))
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(10, 5))
    if beta_ref is not None:
        errors = {n: DEG * (e.beta - beta_ref) for n, e in ran.items()}
        errors = {n: x[np.isfinite(x)] for n, x in errors.items()}
        span = max((np.percentile(np.abs(x), 99.5) for x in errors.values() if x.size), default=1.0)
        bins = np.linspace(-span, span, 81)
        for name, x in errors.items():
            ax.hist(x, bins=bins, histtype="step", lw=1.2, ls="--" if name in BASELINES else "-", label=name)
    ax.set(xlabel="sideslip error [deg]", ylabel="samples", title=f"{title}: sideslip error (estimate - reference)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7)
    fig.tight_layout()
    paths.append(atomic_write(out / "errors.png", lambda p: fig.savefig(p, format="png", dpi=90)))
    plt.close(fig)
    return paths


def _read(log: Log | str | Path) -> Log:
    return log if isinstance(log, Log) else read_log(log)


def estimate_log_report(
    out: str | Path,
    log: Log | str | Path,
    vehicle: Vehicle | str | Path | None = None,
    estimators: Sequence[str] = LOG_ESTIMATORS,
    noise: NoiseParams | None = None,
    command: str | None = None,
    progress: bool = False,
) -> Path:
    """Run ``estimators`` (default: every estimator and the three baselines) on ``log`` (a Log,
    a file or a shipped log's name) of the car ``vehicle`` (:func:`resolve_vehicle`); write
    report.md, scores.csv and the plots into ``out`` as one set; returns report.md's path.
    ``noise``: every filter's noise (default: what make_estimator gives each)."""
    out = check_writable(out)
    estimators = _check_names(estimators)
    pyplot()
    log = _read(log)
    vehicle = resolve_vehicle(log, vehicle)
    header = provenance(command)
    inputs, results = run_on_log(log, vehicle, estimators, noise, progress)
    rows = [{"estimator": name, **scores(result, inputs)} for name, result in results.items()]
    with staged_output(out) as stage:
        atomic_write_text(stage / "scores.csv", scores_csv(rows))
        plot_log(inputs, results, stage, log.name)
        atomic_write_text(stage / "report.md", _report(log, inputs, vehicle, rows, header))
    return out / "report.md"


def _report(log: Log, inputs: LogInputs, vehicle: Vehicle, rows: list[dict], header: Provenance) -> str:
    lines = [
        f"# fourwis estimators on the log `{log.name}`",
        "",
        *header.markdown(),
        "",
        *log_summary(log, inputs, vehicle),
        "",
        "## Scores",
        "",
        "Every estimator ran on the whole log at its own rate and times, from the same start; "
        "scores over the samples with a reference (scores.csv has them unrounded, with the run times). "
        "The baselines (`baseline-*`) are what a filter must beat: a Kalman observer on the linear "
        "single-track model, the single-track steady-state sideslip of the measured yaw rate, and beta = 0. "
        "'within 2 sigma': the share of samples whose sideslip error is within twice the filter's own "
        "sigma (0.95 for a calibrated filter).",
        "",
        *_table(rows),
        "",
        "Plots: sideslip.png (over time against the reference), friction.png (the friction estimates), "
        "errors.png (sideslip error histograms).",
        "",
    ]
    return "\n".join(lines)


# ---- tuning on a log -------------------------------------------------------------------------
FACTOR_NAMES = ("process", "ax", "ay", "gyro", "wheel_speed", "speed")  #: NoiseParams.scaled's 6 factors
BOUNDS = (-1.5, 1.5)  #: log10 factor bounds of each tuned noise


def _active_factors(inputs: LogInputs) -> list[int]:
    """The factors a log can inform: the process and inertial noise, and the wheel-speed and
    speed noise only where those channels are measured."""
    active = [0, 1, 2, 3]
    if inputs.valid[:, CH_OMEGA : CH_OMEGA + 4].any():
        active.append(4)
    if inputs.valid[:, CH_SPEED].any():
        active.append(5)
    return active


def tune_log_report(
    out: str | Path,
    log: Log | str | Path,
    vehicle: Vehicle | str | Path | None = None,
    estimator: str = "alo-fkf",
    split: float = 0.3,
    agents: int = 12,
    iterations: int = 20,
    seed: int = 0,
    optimizer: str = "alo",
    command: str | None = None,
    progress: bool = True,
) -> Path:
    """Tune ``estimator``'s noise on the first ``split`` of ``log`` by the innovation negative
    log-likelihood (no reference needed: training.tune), with ``optimizer`` over log10 factors
    of its process and measurement noise (:data:`FACTOR_NAMES`, those the log informs); then
    run it over the whole log with its shipped noise and with the tuned noise, beside the
    baselines, and score every run on the rest of the log only (held out). Writes
    tuned_noise.json, report.md and scores.csv into ``out`` as one set; returns report.md's
    path. ``make_estimator(..., noise=NoiseParams().scaled(factors))`` runs the tuning."""
    out = check_writable(out)
    check_estimator_name(estimator)
    if parse_estimator_name(estimator)[0] not in KINDS:
        raise ValueError(f"tune --log tunes a filter of {list(KINDS)}, not {estimator!r}")
    if not (isinstance(split, float | int) and 0.05 <= split <= 0.95):
        raise ValueError(f"split must be the tuning part's fraction of the log in [0.05, 0.95], got {split!r}")
    for name, value in (("agents", agents), ("iterations", iterations)):
        if not (is_integer(value) and value >= 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if not (is_integer(seed) and seed >= 0):
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if optimizer not in METHODS:
        raise ValueError(f"unknown optimizer {optimizer!r}; known: {list(METHODS)}")
    log = _read(log)
    vehicle = resolve_vehicle(log, vehicle)
    header = provenance(command)
    inputs = log_inputs(log, vehicle)
    cut = int(round(split * len(inputs.t)))
    if cut < 2 or len(inputs.t) - cut < 2:
        raise ValueError(f"split {split!r} leaves fewer than two samples on a side of the {len(inputs.t)}-sample log")
    active = _active_factors(inputs)
    base = NoiseParams()
    part = slice(0, cut)

    def objective(X: np.ndarray) -> np.ndarray:
        factors = np.zeros((len(X), len(FACTOR_NAMES)))
        factors[:, active] = X
        noise = log_noise(estimator, vehicle, base.scaled(factors))
        est = make_estimator(estimator, vehicle.params, inputs.nominal_dt, noise, **vehicle.estimator_options())
        result = est.replay(inputs.values[part], inputs.valid[part], inputs.t[part], inputs.initial_speed, record=False)
        cost = result.nll / cut
        return np.where((result.status == 0) & np.isfinite(cost), cost, math.inf)

    default_cost = float(objective(np.zeros((1, len(active))))[0])
    found = minimize(
        objective, [BOUNDS] * len(active), optimizer, n_agents=agents, iterations=iterations, seed=seed,
        progress=progress,
    )  # fmt: skip
    factors = np.zeros(len(FACTOR_NAMES))
    improved = bool(found.fun < default_cost)
    if improved:
        factors[active] = found.x
    tuned = base.scaled(factors)
    shipped = None  # (make_estimator's own: the shipped tuning for alo-fkf and joint)
    held_out = np.arange(cut, len(inputs.t))
    runs = {
        f"{estimator} (shipped noise)": replay_estimator(estimator, vehicle, inputs, shipped),
        f"{estimator} (tuned on the first {100 * split:g}%)": replay_estimator(estimator, vehicle, inputs, tuned),
        **{name: replay_estimator(name, vehicle, inputs) for name in BASELINES},
    }
    rows = [{"estimator": name, **scores(result, inputs, held_out)} for name, result in runs.items()]
    data = {
        "log10_factors": [float(f) for f in factors],
        "factor_names": list(FACTOR_NAMES),
        "tuned": [FACTOR_NAMES[i] for i in active],
        "cost": float(found.fun) if improved else default_cost,
        "default_cost": default_cost,
        "improved": improved,
        "optimizer_best": {"log10_factors": [float(v) for v in found.x], "cost": float(found.fun)},
        "estimator": estimator,
        "log": log.name,
        "log_source": log.source,
        "tuning_samples": [0, cut],
        "tuning_time_s": [float(inputs.t[0]), float(inputs.t[cut - 1])],
        "criterion": f"mean innovation NLL per step of {estimator} with hand-set noise x 10^factors",
        "optimizer": optimizer,
        "agents": int(agents),
        "iterations": int(iterations),
        "seed": int(seed),
        "usage": "make_estimator(name, params, noise=NoiseParams().scaled(log10_factors))",
        "written_by": header._asdict(),
    }
    text = [
        f"# Noise tuned on the log `{log.name}`, scored on the rest",
        "",
        *header.markdown(),
        "",
        f"`{estimator}`'s noise (log10 factors on the hand-set NoiseParams: "
        + ", ".join(f"{FACTOR_NAMES[i]} {factors[i]:+.3f}" for i in range(len(FACTOR_NAMES)))
        + f") tuned by {optimizer} ({agents} agents x {iterations} iterations, seed {seed}) on the innovation "
        f"negative log-likelihood of the first {100 * split:g}% of the log (t = {inputs.t[0]:.2f}-"
        f"{inputs.t[cut - 1]:.2f} s; mean NLL per step {default_cost:.3f} hand-set -> {data['cost']:.3f}"
        + ("" if improved else ": no better noise found, the hand-set one kept")
        + "). No reference entered the tuning. Scores: the held-out rest of the log "
        f"(t = {inputs.t[cut]:.2f}-{inputs.t[-1]:.2f} s), every run having started at the log's start.",
        "",
        *_table(rows),
        "",
        *log_summary(log, inputs, vehicle),
        "",
    ]
    with staged_output(out) as stage:
        atomic_write_json(stage / "tuned_noise.json", data)
        atomic_write_text(stage / "scores.csv", scores_csv(rows))
        atomic_write_text(stage / "report.md", "\n".join(text))
    return out / "report.md"


__all__ = [
    "LOG_ESTIMATORS",
    "SCORE_COLUMNS",
    "estimate_log_report",
    "log_path",
    "resolve_vehicle",
    "run_on_log",
    "scores",
    "shipped_logs",
    "tune_log_report",
]

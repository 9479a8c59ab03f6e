"""Open-loop estimator accuracy in the paper's Table 2 form: scenario x estimator x seed.

Every run drives the uncontrolled car (controller None) through a scenario with noisy sensors
and runs one estimator alongside. Reported per run: MAE and RMSE of u, v [m/s] and beta [rad]
against the truth, the mean absolute per-wheel mu error over the last half of the run, and
the mu convergence time [s] (estimators that estimate mu only). Writes estimate.csv,
estimate.md (with the paper's own Table 2 beside ours) and one PNG per scenario in the style
of the paper's Figures 8-13.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from fourwis.core.checks import is_integer
from fourwis.envs.metrics import mae, rmse
from fourwis.envs.road import contact_points
from fourwis.envs.scenarios import PAPER_SCENARIOS, Scenario
from fourwis.envs.simulation import Trajectory, simulate
from fourwis.estimation import (
    BASELINES,
    ESTIMATORS,
    Estimate,
    check_estimator_name,
    make_estimator,
    parse_estimator_name,
)
from fourwis.estimation.joint import FRICTION_KINDS, KINDS, StateEstimator
from fourwis.training.compare import (
    FAULT_SUFFIX,
    build_scenario,
    check_file_stems,
    entry_A,
    file_stem,
    naming_the_run,
    parse_scenario,
)
from fourwis.training.io import atomic_write, atomic_write_text, check_writable, pyplot, staged_output
from fourwis.training.pool import Backend, as_backend, parallel_map
from fourwis.training.provenance import Provenance, provenance
from fourwis.training.tables import mean_over_seeds, require_distinct, write_runs_csv
from fourwis.training.tyre_fit import plot_tyre_curves

#: The filters' consistency from their own covariance (:func:`filter_consistency`), each a mean of a
#: normalised statistic (1: consistent) and the share of samples inside its chi-square 95% band
#: (0.95: consistent): the NEES of (u, v, r) against the reported covariance (3 degrees of freedom),
#: of the wheels' mean friction (1), and the NIS of the state and friction filters' innovations
#: (their valid channels' count), each divided by its degrees of freedom. The friction's are named
#: friction_*: :func:`run_metrics`' mu_nees_in_band is each wheel's mu against its own sigma
CONSISTENCY_METRICS = (
    "state_nees",
    "state_nees_in_band",
    "friction_nees",
    "friction_nees_in_band",
    "state_nis",
    "state_nis_in_band",
    "friction_nis",
    "friction_nis_in_band",
)


#: the filters (the oracle is the truth itself) and the baselines they must beat (estimation.baselines)
DEFAULT_ESTIMATORS = tuple(e for e in ESTIMATORS if e != "oracle") + BASELINES
MU_TOLERANCE = 0.1  #: mean |mu_hat - mu| over the wheels below which mu counts as converged
METRICS = (
    "mae_u",
    "rmse_u",
    "mae_v",
    "rmse_v",
    "mae_beta",
    "rmse_beta",
    "mu_error_last_half",
    "mu_convergence_time",
    "mu_estimated",
    "beta_z_rms",
    "beta_nees_in_band",
    "mu_z_rms",
    "mu_nees_in_band",
    *CONSISTENCY_METRICS,
)
#: the unit of each metric, as estimate.csv heads its columns ("-": dimensionless, "0/1": a flag)
METRIC_UNITS = {
    "mae_u": "m/s",
    "rmse_u": "m/s",
    "mae_v": "m/s",
    "rmse_v": "m/s",
    "mae_beta": "rad",
    "rmse_beta": "rad",
    "mu_error_last_half": "-",
    "mu_convergence_time": "s",
    "mu_estimated": "0/1",
    "beta_z_rms": "-",
    "beta_nees_in_band": "-",
    "mu_z_rms": "-",
    "mu_nees_in_band": "-",
    **{name: "-" for name in CONSISTENCY_METRICS},
}
#: the two-sided 95% chi-square band of a one-degree-of-freedom NEES, (error / sigma)^2 of one
#: sample: a consistent filter's samples lie inside it 95% of the time
NEES_BAND = (float(chi2.ppf(0.025, 1)), float(chi2.ppf(0.975, 1)))
WHEELS = ("FL", "FR", "RL", "RR")

#: The paper's Table 2 (section 3.3.3, double lane change on mu 0.5 at 35 km/h, CarSim, sampled
#: every 0.002 s): (statistic, estimator) -> (longitudinal speed, lateral speed, sideslip). Units
#: are not stated in the paper.
PAPER_TABLE2 = {
    ("MAE", "fkf"): (0.0050, 0.0274, 0.0025),
    ("MAE", "alo-fkf"): (0.0008, 0.0024, 0.0002),
    ("RMSE", "fkf"): (0.0063, 0.0572, 0.0052),
    ("RMSE", "alo-fkf"): (0.0010, 0.0040, 0.0003),
}
PAPER_TABLE2_SCENARIO = "paper_dlc"


#: the estimators that hold a nominal mu (``road_mu`` sets it to the road's): all but the joint one
FIXED_MU = tuple(kind for kind in KINDS if kind not in FRICTION_KINDS)


@dataclass(frozen=True)
class RunSpec:
    scenario: Scenario
    estimator: str
    seed: int
    nominal_mu: float | None = None  #: a fixed-mu filter's friction (None: its default, 0.8)


def road_friction(scenario: Scenario) -> float:
    """The mean friction under the four wheels at the scenario's start."""
    params = scenario.vehicle_params
    gx, gy = contact_points(scenario.initial_state(), params)
    return float(np.mean(scenario.road.mu_at(gx[0], gy[0])))


def convergence_time(t: np.ndarray, error: np.ndarray, tolerance: float = MU_TOLERANCE) -> float:
    """First time t[k] [s] from which ``error`` stays below ``tolerance`` to the end; NaN if it never does."""
    t, error = np.asarray(t, dtype=float), np.asarray(error, dtype=float)
    above = np.flatnonzero(~(error < tolerance))  # NaN counts as not converged
    k = above[-1] + 1 if above.size else 0
    return float(t[k]) if k < t.size else math.nan


def consistency(error: np.ndarray, sigma: np.ndarray) -> tuple[float, float]:
    """(RMS of error / sigma, the fraction of samples whose NEES (error / sigma)^2 lies in
    :data:`NEES_BAND`) over the samples of ``error`` and ``sigma`` (same shape, same units) with a
    sigma > 0; (NaN, NaN) where there is none (an estimator that reports no uncertainty). A
    calibrated sigma gives an RMS ratio near 1 and 95% in the band (issue 41's target: a ratio in
    [0.5, 2])."""
    has = sigma > 0
    if not np.any(has):
        return math.nan, math.nan
    z2 = np.square(error[has] / sigma[has])
    return float(np.sqrt(np.mean(z2))), float(np.mean((z2 >= NEES_BAND[0]) & (z2 <= NEES_BAND[1])))


def run_metrics(traj: Trajectory) -> dict[str, float]:
    """Table 2 metrics of one run: MAE/RMSE of u, v [m/s] and beta [rad]; mu error and convergence
    time [s]; the consistency of the reported sigmas (:func:`consistency`) of beta (``beta_z_rms``,
    ``beta_nees_in_band``) and of each wheel's mu (``mu_z_rms``, ``mu_nees_in_band``).

    An estimator with neither a mu_std nor a mu_hat that moves from its first value holds a
    nominal mu: its convergence time is NaN (not meaningful).
    """
    T, E = traj.truth, traj.estimate
    out: dict[str, float] = {}
    for name in ("u", "v", "beta"):
        out[f"mae_{name}"] = mae(getattr(E, name), getattr(T, name))
        out[f"rmse_{name}"] = rmse(getattr(E, name), getattr(T, name))
    mu_error = np.mean(np.abs(E.mu - T.mu), axis=1)  # (T,) mean over the wheels
    out["mu_error_last_half"] = float(np.mean(mu_error[mu_error.size // 2 :]))
    estimated = bool(np.any(E.mu_std > 0) or np.any(E.mu != E.mu[0]))
    out["mu_convergence_time"] = convergence_time(traj.t, mu_error) if estimated else math.nan
    out["mu_estimated"] = float(estimated)
    out["beta_z_rms"], out["beta_nees_in_band"] = consistency(E.beta - T.beta, E.beta_std)
    out["mu_z_rms"], out["mu_nees_in_band"] = consistency(E.mu - T.mu, E.mu_std)
    return out


def in_chi2_band(statistic: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """Whether each sample's chi-square ``statistic`` with ``dof`` degrees of freedom (arrays of
    one shape) lies inside its two-sided 95% band (a consistent filter's: 95% of its samples)."""
    return (statistic >= chi2.ppf(0.025, dof)) & (statistic <= chi2.ppf(0.975, dof))


def nees(error: np.ndarray, P: np.ndarray) -> np.ndarray:
    """The normalised estimation error squared e^T P^-1 e of each sample: errors (T, n) with their
    reported covariances (T, n, n) (SI, alike); chi-square with n degrees of freedom for a
    consistent filter."""
    return np.einsum("ti,ti->t", error, np.linalg.solve(P, error[..., None])[..., 0])


def filter_consistency(traj: Trajectory, estimator) -> dict[str, float]:
    """The :data:`CONSISTENCY_METRICS` of the run ``traj`` by ``estimator`` (a fourwis filter, a
    :class:`fourwis.estimation.StateEstimator` built afresh as the run's was, or its name): the
    run's sensor log replayed through it with its diagnostics (StateEstimator.replay), which
    reproduces the run's estimate exactly (checked: ValueError otherwise), from the first sample
    on. NaN for an estimator without a covariance (the oracle, the baselines, your own) and for
    a statistic without samples (the friction NIS of a filter that holds mu)."""
    out = dict.fromkeys(CONSISTENCY_METRICS, math.nan)
    if isinstance(estimator, str):
        base, groups = parse_estimator_name(estimator)
        if groups or base not in KINDS:
            return out
        estimator = make_estimator(estimator, traj.scenario.vehicle_params, traj.t[1] - traj.t[0])
    if not isinstance(estimator, StateEstimator):
        return out
    replay = estimator.replay(traj.sensors, traj.sensor_valid, traj.t, traj.scenario.speed, diagnostics=True)
    if replay.status[0] or not np.array_equal(replay.estimate.beta[:, 0], traj.estimate.beta, equal_nan=True):
        raise ValueError(f"the {estimator.kind} filter's replay does not reproduce the run's estimate")
    E, T, D = traj.estimate, traj.truth, replay.diagnostics
    error = np.stack([E.u - T.u, E.v - T.v, E.r - T.r], axis=1)  # (T, 3)
    state = nees(error, D.P_state[:, 0])
    out["state_nees"] = float(np.mean(state) / 3.0)
    out["state_nees_in_band"] = float(np.mean(in_chi2_band(state, np.full(state.shape, 3))))
    if estimator.settings.friction:
        mu_error = np.mean(E.mu - T.mu, axis=1)
        mu_var = np.mean(D.P_mu[:, 0], axis=(1, 2))  # (the variance of the four's mean)
        friction = mu_error**2 / mu_var
        out["friction_nees"] = float(np.mean(friction))
        out["friction_nees_in_band"] = float(np.mean(in_chi2_band(friction, np.ones(friction.shape))))
    for name, updates in (("state", slice(0, 2)), ("friction", slice(2, 4))):
        nis, dof = D.nis[:, 0, updates].ravel(), D.nis_dof[:, 0, updates].ravel()
        ran = (dof > 0) & np.isfinite(nis)
        if np.any(ran):
            out[f"{name}_nis"] = float(np.mean(nis[ran] / dof[ran]))
            out[f"{name}_nis_in_band"] = float(np.mean(in_chi2_band(nis[ran], dof[ran])))
    return out


@naming_the_run
def _run(spec: RunSpec) -> tuple[RunSpec, dict[str, float], tuple[np.ndarray, Estimate, Estimate] | None]:
    def estimator():
        if spec.nominal_mu is None:
            return spec.estimator
        return make_estimator(spec.estimator, spec.scenario.vehicle_params, nominal_mu=spec.nominal_mu)

    traj = simulate(spec.scenario, controller=None, estimator=estimator(), seed=spec.seed)
    keep = (traj.t, traj.truth, traj.estimate) if spec.seed == 0 else None  # seed 0 feeds the plots
    metrics = run_metrics(traj) | filter_consistency(traj, estimator())  # (a fresh one: it replays the run)
    if _reports_true_mu(spec.estimator):  # not an estimate of mu, however the road's friction moves
        metrics.update(mu_estimated=0.0, mu_convergence_time=math.nan)
    return spec, metrics, keep


def _reports_true_mu(estimator: str) -> bool:
    base, groups = parse_estimator_name(estimator)
    return base == "oracle" or "mu" in groups


def _scenarios(scenarios: Sequence[str | Scenario]) -> list[Scenario]:
    """Scenarios as given, or built from compare's entries (``iso3888_2:mu=0.6``, ``swd_wet``;
    an entry with overrides is named by its text)."""
    if not scenarios:
        raise ValueError("scenarios must not be empty")
    texts = [s for s in scenarios if not isinstance(s, Scenario)]
    for text in texts:
        if not isinstance(text, str) or text.endswith(FAULT_SUFFIX):
            raise ValueError(
                f"scenario {text!r}: give a Scenario or a name with optional overrides "
                f"(the {FAULT_SUFFIX} variant is the closed-loop comparison's)"
            )
    built = [
        s
        if isinstance(s, Scenario)
        else replace(build_scenario(s, entry_A(s) if "amplitude_A" in parse_scenario(s)[1] else math.nan), name=s)
        for s in scenarios
    ]
    require_distinct("scenario names", [s.name for s in built])
    check_file_stems([s.name for s in built])
    return built


def run_all(
    scenarios: Sequence[str | Scenario] = PAPER_SCENARIOS,
    estimators: Sequence[str] = DEFAULT_ESTIMATORS,
    seeds: int = 1,
    jobs: int | None = None,
    progress: bool = True,
    road_mu: bool = False,
    backend: Backend | str | None = None,
) -> tuple[list[tuple[RunSpec, dict]], dict]:
    """Run every (scenario, estimator, seed) open loop in parallel on ``backend`` (training.pool:
    local processes by default, or Ray; the same results on either). ``road_mu``: the
    fixed-mu filters (:data:`FIXED_MU`) assume the road's friction at the start
    (:func:`road_friction`) instead of 0.8, as the paper's section-3 filters presumably do.

    Returns per-run (spec, metrics) and the seed-0 series {(scenario name, estimator): (t, truth, estimate)}.
    """
    backend = as_backend(backend)
    built = _scenarios(scenarios)
    if not estimators:
        raise ValueError("estimators must not be empty")
    for name in estimators:
        check_estimator_name(name)
    require_distinct("estimators", estimators)
    if not (is_integer(seeds) and seeds >= 1):
        raise ValueError(f"seeds must be an integer >= 1, got {seeds!r}")
    if not isinstance(road_mu, bool):
        raise ValueError(f"road_mu must be True or False, got {road_mu!r}")
    specs = [
        RunSpec(s, e, k, road_friction(s) if road_mu and e in FIXED_MU else None)
        for s in built
        for e in estimators
        for k in range(seeds)
    ]
    results, series = [], {}
    for spec, metrics, keep in parallel_map(_run, specs, jobs, "open-loop estimation runs", progress, backend):
        results.append((spec, metrics))
        if keep is not None:
            series[(spec.scenario.name, spec.estimator)] = keep
    return results, series


def aggregate(results: list[tuple[RunSpec, dict]]) -> dict[tuple[str, str], dict[str, float]]:
    """Mean of every metric over seeds per (scenario name, estimator); NaN convergence stays NaN."""
    return mean_over_seeds(results, lambda spec: (spec.scenario.name, spec.estimator))


def write_csv(results: list[tuple[RunSpec, dict]], path: Path) -> Path:
    """estimate.csv: a run per row (scenario, estimator, seed, then :data:`METRICS` headed
    ``name [unit]``, SI units; NaN, e.g. a convergence that never came, an empty field)."""
    return write_runs_csv(
        results,
        ["scenario", "estimator", "seed"],
        lambda spec, metrics: [spec.scenario.name, spec.estimator, spec.seed],
        METRICS,
        METRIC_UNITS,
        path,
    )


def _fmt(value: float, digits: int = 5, scale: float = 1.0) -> str:
    return "—" if not math.isfinite(value) else f"{value * scale:.{digits}f}"


DEG = 180.0 / math.pi  #: rad -> deg, for the report's tables and plots


def _convergence(m: dict[str, float], estimator: str) -> str:
    if _reports_true_mu(estimator):
        return "n/a (true mu)"
    if not m["mu_estimated"]:
        return "n/a (nominal mu)"
    return "never" if not math.isfinite(m["mu_convergence_time"]) else f"{m['mu_convergence_time']:.2f}"


def markdown_report(
    table: dict,
    scenarios: Sequence[Scenario],
    estimators: Sequence[str],
    seeds: int,
    road_mu: bool = False,
    header: Provenance | None = None,
) -> str:
    """estimate.md: who wrote it (``header``, default: :func:`training.provenance.provenance` of
    now), per-scenario tables (means over seeds; sideslip in degrees) and the paper's Table 2
    beside ours."""
    lines = [
        "# fourwis open-loop estimation accuracy (paper Table 2 form)",
        "",
        *(header or provenance()).markdown(),
        "",
        f"Runs: {len(scenarios)} scenarios x {len(estimators)} estimators x {seeds} seeds, no controller "
        "(scripted steering or the path-following driver; the estimator only observes). Values are "
        "means over seeds. mu error: mean over wheels of |mu_hat - mu| over the last half of the run; "
        f"mu convergence: first time after which that error stays below {MU_TOLERANCE} to the end "
        "(estimators that hold a nominal mu: n/a). "
        + (
            f"The fixed-mu filters ({', '.join(FIXED_MU)}) assume the road's friction at the start (--road-mu)."
            if road_mu
            else f"The fixed-mu filters ({', '.join(FIXED_MU)}) assume mu 0.8 (--road-mu: the road's)."
        ),
        "",
    ]
    for s in scenarios:
        heading = f"## {s.name} ({s.speed_kph:g} km/h, {s.duration:.1f} s, mean mu {road_friction(s):.2f} at the start)"
        lines += [
            heading,
            "",
            "| estimator | MAE u [m/s] | RMSE u [m/s] | MAE v [m/s] | RMSE v [m/s] | MAE beta [deg] "
            "| RMSE beta [deg] | mu error, last half | mu convergence [s] |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for e in estimators:
            m = table[(s.name, e)]
            lines.append(
                f"| {e} | "
                + " | ".join(_fmt(m[k]) for k in METRICS[:4])
                + " | "
                + " | ".join(_fmt(m[k], 4, DEG) for k in ("mae_beta", "rmse_beta"))
                + f" | {_fmt(m['mu_error_last_half'], 3)} | {_convergence(m, e)} |"
            )
        lines.append("")
    lines += [
        "## The paper's Table 2 beside ours",
        "",
        "Table 2 of *Joint Estimation of Driving State and Road Surface Adhesion Coefficient of a "
        "Four-Wheel Independent and Steering-Drive Electric Vehicle* (section 3.3.3: double lane change, "
        "mu 0.5, 35 km/h, CarSim 2019 + MATLAB/Simulink, sampled every 0.002 s), transcribed as printed; "
        f"ours: the same estimator on `{PAPER_TABLE2_SCENARIO}` (mean over seeds; u, v in m/s, beta in deg: "
        "the paper's sideslip column read as rad and converted).",
        "",
        "| statistic | estimator | u: paper | u: ours | v: paper | v: ours | beta [deg]: paper | beta [deg]: ours |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for (stat, e), paper in PAPER_TABLE2.items():
        ours = table.get((PAPER_TABLE2_SCENARIO, e))
        cells = [
            f"{p * scale:.4f} | {_fmt(ours[f'{stat.lower()}_{q}'], digits, scale) if ours else 'not run'}"
            for p, q, scale, digits in zip(paper, ("u", "v", "beta"), (1.0, 1.0, DEG), (5, 5, 4))
        ]
        lines.append(f"| {stat} | {e} | " + " | ".join(cells) + " |")
    lines += _ratio_section(table, scenarios, estimators)
    lines += _consistency_section(table, scenarios, estimators)
    lines += [
        "",
        "The estimators' tyre: `tyre_curves.png` draws the plant's PAC2002 curves against the fitted "
        "Dugoff (eq. 17 stiffness and friction scale, training/tyre_fit.py) at 2-5 kN, in the form of the "
        "paper's Figures 2 and 3.",
    ]
    lines += [
        "",
        "Caveats: the paper states no sensor noise levels (nor biases) for its CarSim runs, "
        "nor the units of Table 2 (the sideslip column is read as rad here and shown in degrees), nor its "
        "filters' initial "
        "errors; its plant is CarSim's, ours is fourwis's own model. Our runs use the default sensor "
        "model (envs.sensors.SensorParams: white noise and turn-on biases on every channel), so the "
        "numbers are comparable in form, not like for like.",
        "",
    ]
    return "\n".join(lines)


def _consistency_section(table: dict, scenarios: Sequence[Scenario], estimators: Sequence[str]) -> list[str]:
    """The filters' NEES and NIS (:func:`filter_consistency`) per scenario and estimator: each mean
    divided by its degrees of freedom (1: consistent) with the share of the samples inside the
    per-sample chi-square 95% band (95%: consistent); estimators without a covariance left out."""
    has = [
        e for e in estimators if any(math.isfinite(table[(s.name, e)].get("state_nees", math.nan)) for s in scenarios)
    ]
    if not has:
        return []

    def cell(m: dict, name: str) -> str:
        value, inside = m.get(name, math.nan), m.get(f"{name}_in_band", math.nan)
        return "—" if not math.isfinite(value) else f"{value:.3g} ({inside:.0%})"

    bands = ", ".join(f"{dof} dof [{chi2.ppf(0.025, dof):.3g}, {chi2.ppf(0.975, dof):.3g}]" for dof in (1, 2, 3, 7))
    lines = [
        "",
        "## Consistency: NEES and NIS",
        "",
        "Each filter's own covariance against its errors (its sensor log replayed with the filter's diagnostics): "
        "the mean NEES of (u, v, r) over 3 (the covariance of v with the sideslip's consider term, as beta_std "
        "reports it), of the wheels' mean friction (1 degree of freedom), and the mean NIS of the state and "
        "friction filters' innovations over their valid channels; 1 is consistent, above 1 the filter is too "
        "sure. In brackets the share of samples inside the per-sample chi-square 95% band (95% is consistent; "
        f"bands: {bands}). Means over seeds; — where the filter has no such update.",
        "",
        "| scenario | estimator | NEES (u, v, r) / 3 | NEES friction | NIS state / dof | NIS friction / dof |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for s in scenarios:
        for e in has:
            m = table[(s.name, e)]
            lines.append(
                f"| {s.name} | {e} | "
                + " | ".join(cell(m, n) for n in ("state_nees", "friction_nees", "state_nis", "friction_nis"))
                + " |"
            )
    return lines


def _ratio_section(table: dict, scenarios: Sequence[Scenario], estimators: Sequence[str]) -> list[str]:
    """Sideslip RMSE of each estimator over fkf's (the same federated filter with hand-set noise),
    per scenario, with the paper's ratio on its DLC beside ours (below 1: better than fkf)."""
    others = [e for e in estimators if e != "fkf"]
    if "fkf" not in estimators or not others:
        return []
    paper = PAPER_TABLE2[("RMSE", "alo-fkf")][2] / PAPER_TABLE2[("RMSE", "fkf")][2]
    lines = [
        "",
        "### Sideslip RMSE relative to fkf",
        "",
        f"Below 1: better than `fkf`. The paper's ALO-FKF / FKF on its DLC: {paper:.3f} "
        f"({PAPER_TABLE2[('RMSE', 'alo-fkf')][2]} / {PAPER_TABLE2[('RMSE', 'fkf')][2]}).",
        "",
        "| scenario | " + " | ".join(f"{e} / fkf" for e in others) + " |",
        "|---|" + "---:|" * len(others),
    ]
    for s in scenarios:
        fkf = table[(s.name, "fkf")]["rmse_beta"]
        lines.append(
            f"| {s.name} | " + " | ".join(f"{table[(s.name, e)]['rmse_beta'] / fkf:.3f}" for e in others) + " |"
        )
    return lines


def plot_scenario(name: str, series: dict, estimators: Sequence[str], path: Path) -> Path:
    """PNG of seed 0 in the style of the paper's Figures 8-13: estimates vs truth of u, v, beta
    (in degrees) and mu per wheel."""
    plt = pyplot()

    fig, axes = plt.subplots(2, 4, figsize=(16, 7), sharex=True)
    panels = [
        ("u", "longitudinal speed u [m/s]", 1.0),
        ("v", "lateral speed v [m/s]", 1.0),
        ("beta", "sideslip beta [deg]", DEG),
    ]
    first = next(series[(name, e)] for e in estimators)
    t, truth = first[0], first[1]
    for ax, (field_name, title, scale) in zip(axes[0], panels):
        ax.plot(t, scale * getattr(truth, field_name), "k--", lw=1.5, label="truth")
        ax.set_title(title)
    for i, ax in enumerate(axes[1]):
        ax.plot(t, truth.mu[:, i], "k--", lw=1.5, label="truth")
        ax.set_title(f"road friction mu, {WHEELS[i]}")
        ax.set_xlabel("t [s]")
    for e in estimators:
        _, _, est = series[(name, e)]
        for ax, (field_name, _, scale) in zip(axes[0], panels):
            ax.plot(t, scale * getattr(est, field_name), lw=1, label=e)
        for i, ax in enumerate(axes[1]):
            ax.plot(t, est.mu[:, i], lw=1, label=e)
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    axes[0, 3].axis("off")
    axes[0, 3].legend(*axes[0, 0].get_legend_handles_labels(), loc="center", title="seed 0")
    fig.suptitle(f"{name}: estimates vs truth (open loop, seed 0)")
    fig.tight_layout()
    atomic_write(path, lambda p: fig.savefig(p, format="png", dpi=100))
    plt.close(fig)
    return path


def estimate_report(
    out: str | Path,
    scenarios: Sequence[str | Scenario] = PAPER_SCENARIOS,
    estimators: Sequence[str] = DEFAULT_ESTIMATORS,
    seeds: int = 1,
    jobs: int | None = None,
    road_mu: bool = False,
    command: str | None = None,
    backend: Backend | str | None = None,
) -> Path:
    """Run the open-loop matrix; write estimate.csv, estimate.md, <scenario>.png and tyre_curves.png
    (the plant's tyre against the estimator's fitted Dugoff, paper Figures 2-3) into ``out``, as
    one set (:func:`training.io.staged_output`: an interrupt leaves the previous set).
    ``command``: what the report's header says wrote it (default: this process's command line).

    ``scenarios``: Scenario objects, or names with optional overrides as in compare
    (``paper_step:mu=0.5``; the plot's file name replaces ':', ',' and '=' by '_'); returns
    the path of estimate.md. ``road_mu``, ``backend``: see :func:`run_all`.
    """
    out = check_writable(out)
    pyplot()  # (its plots need matplotlib: say so before the runs, not after them)
    results, series = run_all(scenarios, estimators, seeds, jobs, road_mu=road_mu, backend=backend)
    built = list({spec.scenario.name: spec.scenario for spec, _ in results}.values())
    table = aggregate(results)
    header = provenance(command)
    with staged_output(out) as stage:
        write_csv(results, stage / "estimate.csv")
        for s in built:
            plot_scenario(s.name, series, estimators, stage / f"{file_stem(s.name)}.png")
        plot_tyre_curves(stage / "tyre_curves.png")
        atomic_write_text(stage / "estimate.md", markdown_report(table, built, estimators, seeds, road_mu, header))
    return out / "estimate.md"

"""Trajectory output: one CSV row per sample (each column headed ``name [unit]``) and a PNG overview plot."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from fourwis.control.reference import reference_yaw_rate
from fourwis.core.constants import GRAVITY
from fourwis.envs.layout import A_AX, A_AY, A_FZ, A_MU, S_DELTA_F, S_DELTA_R, S_PSI, S_R, S_TORQUE, S_U, S_V, S_X, S_Y
from fourwis.envs.simulation import Trajectory
from fourwis.training.io import atomic_write, atomic_write_text, pyplot
from fourwis.training.tables import MISSING

WHEELS = ("fl", "fr", "rl", "rr")
#: the unit of each column of :func:`trajectory_columns` by its quantity (an ``est_`` prefix and a
#: ``_<wheel>`` suffix taken off): "-" dimensionless
UNITS = {
    "t": "s",
    "x": "m",
    "y": "m",
    "psi": "rad",
    "u": "m/s",
    "v": "m/s",
    "r": "rad/s",
    "beta": "rad",
    "ax": "m/s^2",
    "ay": "m/s^2",
    "steering_wheel": "rad",
    "delta_f": "rad",
    "delta_r": "rad",
    "torque": "N m",
    "mu": "-",
    "fz": "N",
    "beta_std": "rad",
    "mu_std": "-",
}


def column_unit(name: str) -> str:
    """The unit of the trajectory column ``name`` (``est_mu_std_fl`` -> "-"; KeyError for none)."""
    quantity = name.removeprefix("est_")
    stem, _, wheel = quantity.rpartition("_")
    return UNITS[stem if wheel in WHEELS else quantity]


def reference_yaw_rate_of(traj: Trajectory) -> np.ndarray:
    """(T,) the yaw-rate reference [rad/s] a run's tracking is measured against: the linear 2-DOF
    steady state of the true forward speed and front road-wheel angle, bounded by the true
    friction (:func:`control.reference.reference_yaw_rate`), whatever the controller aims at."""
    return reference_yaw_rate(traj.state[:, S_U], traj.state[:, S_DELTA_F], traj.truth.mu, traj.scenario.vehicle_params)


def trajectory_columns(traj: Trajectory) -> dict[str, np.ndarray]:
    """Named time series of a trajectory, truth and estimate side by side, in SI units (angles
    in rad, also steering_wheel, beta, delta_f/r and est_beta_std; the PNG plots degrees):
    t [s]; pose x, y [m], psi; body u, v [m/s], r [rad/s], sideslip beta; specific forces ax,
    ay [m/s^2]; the driver's steering_wheel angle; road-wheel steer delta_f, delta_r (the
    servos' actual angles); torque_<wheel> [N m] (the motors' actual torques, after their lag
    and limits, not the commands); per wheel the road's mu_<wheel> and normal load fz_<wheel>
    [N]; est_<quantity> for every field of the estimate (est_mu_<wheel>, est_fz_<wheel>,
    est_mu_std_<wheel>, ...)."""
    s, a, est = traj.state, traj.aux, traj.estimate
    cols = {
        "t": traj.t,
        "x": s[:, S_X],
        "y": s[:, S_Y],
        "psi": s[:, S_PSI],
        "u": s[:, S_U],
        "v": s[:, S_V],
        "r": s[:, S_R],
        "beta": traj.truth.beta,
        "ax": a[:, A_AX],
        "ay": a[:, A_AY],
        "steering_wheel": traj.steering_wheel,
        "delta_f": s[:, S_DELTA_F],
        "delta_r": s[:, S_DELTA_R],
    }
    for i, w in enumerate(WHEELS):
        cols[f"torque_{w}"] = s[:, S_TORQUE + i]
    for i, w in enumerate(WHEELS):
        cols[f"mu_{w}"] = a[:, A_MU + i]
    for i, w in enumerate(WHEELS):
        cols[f"fz_{w}"] = a[:, A_FZ + i]
    for name in ("u", "v", "beta", "r", "ax", "ay", "beta_std"):
        cols[f"est_{name}"] = getattr(est, name)
    for name in ("mu", "fz", "mu_std"):
        for i, w in enumerate(WHEELS):
            cols[f"est_{name}_{w}"] = getattr(est, name)[:, i]
    return cols


def write_trajectory_csv(traj: Trajectory, path: str | Path) -> Path:
    """Write the trajectory's columns to ``path`` as CSV (atomically), headed ``name [unit]``
    (:func:`column_unit`), a NaN as the runs CSVs' empty field (:data:`training.tables.MISSING`)."""
    cols = trajectory_columns(traj)
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow([f"{name} [{column_unit(name)}]" for name in cols])
    table = np.column_stack(list(cols.values()))
    rows = table.tolist()
    if np.isnan(table).any():
        rows = [[MISSING if v != v else v for v in row] for row in rows]
    writer.writerows(rows)
    return atomic_write_text(path, buf.getvalue())


def plot_trajectory(
    traj: Trajectory, path: str | Path, *, controller: str, estimator: str, seed: int, name: str | None = None
) -> Path:
    """PNG overview: path (with cones), steering, yaw rate (with the reference it is measured
    against, :func:`reference_yaw_rate_of`), sideslip, accelerations, per-wheel mu. The title
    names the run: ``name`` (default: the scenario's; give the entry with its overrides), speed,
    ``controller``, ``estimator`` and the sensor-noise ``seed``."""
    plt = pyplot()
    cols = trajectory_columns(traj)
    t = cols["t"]
    fig, axes = plt.subplots(3, 2, figsize=(12, 10), constrained_layout=True)
    ax = axes[0, 0]
    ax.plot(cols["x"], cols["y"], label="CG path")
    scenario = traj.scenario
    if scenario.course is not None:
        cones = scenario.course.cones
        ax.plot(cones[:, 0], cones[:, 1], "^", color="tab:orange", ms=4, label="cones")
    ax.set(xlabel="X [m]", ylabel="Y [m]", title="path")
    ax.legend(loc="best")
    ax = axes[0, 1]
    ax.plot(t, np.degrees(cols["steering_wheel"]) / 10.0, label="steering wheel / 10", color="0.5")
    ax.plot(t, np.degrees(cols["delta_f"]), label="front road wheel")
    ax.plot(t, np.degrees(cols["delta_r"]), label="rear steer")
    ax.set(xlabel="t [s]", ylabel="[deg]", title="steering")
    ax.legend(loc="best")
    for ax, key, label, scale in (
        (axes[1, 0], "r", "yaw rate [deg/s]", np.degrees),
        (axes[1, 1], "beta", "sideslip [deg]", np.degrees),
    ):
        ax.plot(t, scale(cols[key]), label="truth")
        ax.plot(t, scale(cols[f"est_{key}"]), "--", label="estimate")
        ax.set(xlabel="t [s]", ylabel=label)
    axes[1, 0].plot(t, np.degrees(reference_yaw_rate_of(traj)), ":", color="k", label="reference (2-DOF, true mu)")
    for ax in axes[1]:
        ax.legend(loc="best")
    ax = axes[2, 0]
    ax.plot(t, cols["ay"] / GRAVITY, label="ay")
    ax.plot(t, cols["ax"] / GRAVITY, label="ax")
    ax.set(xlabel="t [s]", ylabel="[g]", title="accelerations")
    ax.legend(loc="best")
    ax = axes[2, 1]
    for w in WHEELS:
        (line,) = ax.plot(t, cols[f"mu_{w}"], label=f"mu {w.upper()}")
        ax.plot(t, cols[f"est_mu_{w}"], "--", color=line.get_color())
    ax.set(xlabel="t [s]", ylabel="mu [-]", title="road friction (solid truth, dashed estimate)")
    ax.legend(loc="best", ncol=2)
    fig.suptitle(
        f"{name or scenario.name}: {scenario.speed_kph:.0f} km/h, "
        f"controller {controller}, estimator {estimator}, seed {seed}"
    )
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    plt.close(fig)
    return Path(path)

"""Fit the estimator's tyre (Dugoff with load-dependent stiffness, paper eq. 17) to the plant's
PAC2002 tyre, the way the paper fits CarSim's: C(Fz) = m Fz - n Fz^2 by least squares on the
plant tyre's cornering and slip stiffness over 1-5 kN, then Dugoff's friction scale k (Dugoff
uses k mu where the road has mu) by least squares on the lateral force from zero slip to the
plant tyre's peak over the same loads and mu 0.3-1.0. Dugoff's curve rounds off into its
saturation more gently than the Magic Formula's, so at mu it under-predicts the force near the
peak (fitted k ~1.07); without k the joint estimator reads mu high by about that much.
Writes estimation/data/dugoff_fit.json; :func:`plot_tyre_curves` draws the fitted tyre against
the plant's in the form of the paper's Figures 2 and 3 (``fourwis estimate`` writes it beside its
report).

Run: ``python -m fourwis.training.tyre_fit`` (``--plot DIR``: only the figure, DIR/tyre_curves.png)
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from fourwis.envs.tyre import TyreParams, tyre_forces
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation.model import MIN_SPEED, ModelParams, dugoff, stiffness
from fourwis.training.io import atomic_write, atomic_write_json, pyplot

OUTPUT = Path(__file__).resolve().parent.parent / "estimation" / "data" / "dugoff_fit.json"
LOADS = np.linspace(1000.0, 5000.0, 17)  #: fit loads [N]
FRICTIONS = (0.3, 0.5, 0.8, 1.0)  #: road mu of the friction-scale fit
FIGURE_LOADS = (2000.0, 3000.0, 4000.0, 5000.0)  #: wheel loads [N] of the tyre-curve figure
FIGURE_SPEED = 20.0  #: wheel-centre speed [m/s] at which the figure's slip ratios are taken


def fit_quadratic(fz: np.ndarray, stiffness: np.ndarray) -> tuple[float, float, float]:
    """Least-squares (m, n, R^2) of ``stiffness = m fz - n fz^2`` (no constant: zero at zero load)."""
    design = np.column_stack([fz, -(fz**2)])
    (m, n), *_ = np.linalg.lstsq(design, stiffness, rcond=None)
    residual = stiffness - design @ (m, n)
    return float(m), float(n), float(1.0 - residual.var() / stiffness.var())


def fit_friction_scale(tyre: TyreParams, m2: float, n2: float, reference_load: float) -> tuple[float, float, float]:
    """Least-squares Dugoff friction scale k and the RMS lateral-force error [mu Fz] with k and
    with 1: pure cornering, tan(alpha) from 0.002 up to the plant tyre's peak (beyond it the
    Magic Formula falls off and Dugoff cannot follow), loads LOADS, road mu FRICTIONS, the plant
    normalising mu at ``reference_load`` [N] as the truth plant does."""
    fz, mu, ta, fy = _plant_lateral(tyre, reference_load)
    cy = m2 * fz - n2 * fz**2

    def rms_error(k: float) -> float:
        # the estimator's own tyre at zero longitudinal slip, Dugoff's speed term off
        model = np.array([dugoff(f, 0.0, t, k * m, 1.0, c, 0.0, 0.0)[1] for f, t, m, c in zip(fz, ta, mu, cy)])
        return float(np.sqrt(np.mean(((model - fy) / (mu * fz)) ** 2)))

    best = minimize_scalar(rms_error, bounds=(0.5, 2.0), method="bounded", options={"xatol": 1e-5})
    return float(best.x), rms_error(best.x), rms_error(1.0)


def _plant_lateral(tyre: TyreParams, reference_load: float) -> tuple[np.ndarray, ...]:
    """The plant tyre's pure-slip lateral force from zero slip to its peak (the fits' data): loads
    (n,) [N], road mu (n,), tan(alpha) (n,) and |Fy| (n,) [N] over LOADS x FRICTIONS."""
    loads, frictions, slips, forces = [], [], [], []
    tan_alpha = np.linspace(0.002, 0.4, 400)
    for fz in LOADS:
        for mu in FRICTIONS:
            fy = np.abs(tyre_forces(tyre, fz, 0.0, tan_alpha, mu, reference_load)[1])
            n = int(np.argmax(fy)) + 1
            loads.append(np.full(n, fz))
            frictions.append(np.full(n, mu))
            slips.append(tan_alpha[:n])
            forces.append(fy[:n])
    return tuple(map(np.concatenate, (loads, frictions, slips, forces)))


def magic_lateral_force(fz, tan_alpha, mu, cy, magic_c, magic_e, mu_scale, load_sensitivity, reference_load):
    """The estimator's Magic Formula lateral force [N] (estimation.model.magic_lateral) on numpy
    arrays: D sin(C atan(B x - E (B x - atan(B x)))), x the slip angle, D = k mu Fz (1 + s (Fz /
    F0 - 1)), B = Cy / (C D)."""
    d = mu_scale * mu * fz * (1.0 + load_sensitivity * (fz / reference_load - 1.0))
    bx = cy / (magic_c * d) * np.arctan(tan_alpha)
    return d * np.sin(magic_c * np.arctan(bx - magic_e * (bx - np.arctan(bx))))


def fit_magic(tyre: TyreParams, m2: float, n2: float, reference_load: float) -> dict:
    """The estimator's Magic Formula lateral shape fitted to the plant tyre: C, E, the friction
    scale k and the load sensitivity s of the peak (about ``reference_load`` [N]) by least squares
    on the lateral force [mu Fz] from zero slip to the plant tyre's peak (loads LOADS, mu
    FRICTIONS), the stiffness at zero slip the eq. 17 fit's (m2, n2); with its RMS error [mu Fz]."""
    fz, mu, ta, fy = _plant_lateral(tyre, reference_load)
    cy = m2 * fz - n2 * fz**2

    def residual(p: np.ndarray) -> np.ndarray:
        return (magic_lateral_force(fz, ta, mu, cy, *p, reference_load) - fy) / (mu * fz)

    best = least_squares(residual, [1.4, 0.0, 1.0, 0.0], bounds=([1.0, -5.0, 0.5, -1.0], [2.0, 1.0, 2.0, 1.0]))
    c, e, k, s = (float(v) for v in best.x)
    return {
        "magic_c": c,
        "magic_e": e,
        "mu_scale": k,
        "load_sensitivity": s,
        "reference_load": float(reference_load),
        "lateral_rms_error_mu_fz": float(np.sqrt(np.mean(best.fun**2))),
    }


def fit_dugoff(tyre: TyreParams | None = None, reference_load: float | None = None) -> dict:
    """Eq. 17 coefficients for the longitudinal (m1, n1) and lateral (m2, n2) stiffness and the
    friction scale ``mu_scale`` (reference load: the car's static wheel load, as in the plant)."""
    vehicle = VehicleParams()
    tyre = tyre or vehicle.tyre
    reference_load = vehicle.reference_wheel_load if reference_load is None else reference_load
    m1, n1, r2x = fit_quadratic(LOADS, np.asarray(tyre.slip_stiffness(LOADS)))
    m2, n2, r2y = fit_quadratic(LOADS, np.asarray(tyre.cornering_stiffness(LOADS)))
    mu_scale, rms_scaled, rms_unscaled = fit_friction_scale(tyre, m2, n2, reference_load)
    return {
        "m1": m1,
        "n1": n1,
        "m2": m2,
        "n2": n2,
        "r2_longitudinal": r2x,
        "r2_lateral": r2y,
        "mu_scale": mu_scale,
        "lateral_rms_error_mu_fz": rms_scaled,
        "lateral_rms_error_mu_fz_unscaled": rms_unscaled,
        "loads_N": [float(LOADS[0]), float(LOADS[-1])],
        "source": "least-squares fit of eq. 17 to the plant tyre (PAC2002, chrono mf_185_80R14.tir) stiffness; "
        "mu_scale: least squares on the lateral force up to the plant tyre's peak; magic: the Magic Formula "
        "lateral shape (joint's tyre) by least squares on the same forces",
        "magic": fit_magic(tyre, m2, n2, reference_load),
    }


class TyreCurves(NamedTuple):
    """Pure-slip force curves at one load: slip ratios kappa (S,) [-] and slip angles (A,) [rad];
    the plant's and the estimator's Dugoff longitudinal (S,) and lateral (A,) forces [N], and the
    joint estimator's Magic Formula lateral force (A,) [N]."""

    kappa: np.ndarray
    fx_plant: np.ndarray
    fx_dugoff: np.ndarray
    alpha: np.ndarray
    fy_plant: np.ndarray
    fy_dugoff: np.ndarray
    fy_magic: np.ndarray


def tyre_curves(load: float, mu: float = 1.0, vehicle=None, points: int = 121) -> TyreCurves:
    """The plant's PAC2002 tyre and the estimator's Dugoff (the shipped eq. 17 stiffness and friction
    scale, estimation/data/dugoff_fit.json, as ``ModelParams.from_vehicle`` loads them: fitted to
    the default car's tyre) at wheel load ``load`` [N] on road friction ``mu``: Fx against
    the plant's slip ratio kappa in [0, 0.5] (Dugoff at the slip the estimator computes for it,
    (R omega - u) / max(R omega, u) at FIGURE_SPEED) and Fy against the slip angle in
    [0, 15 deg], each with the other slip zero. (The estimators take Fx from the wheel's torque
    balance; Dugoff's longitudinal stiffness enters only through its combined-slip cut of Fy.)"""
    vehicle = vehicle or VehicleParams()
    p = ModelParams.from_vehicle(vehicle)
    cx, cy = stiffness(load, p.front.kernel)
    kappa, alpha = np.linspace(0.0, 0.5, points), np.radians(np.linspace(0.0, 15.0, points))
    fx_plant = tyre_forces(vehicle.tyre, load, kappa, 0.0, mu, vehicle.reference_wheel_load)[0]
    fy_plant = np.abs(tyre_forces(vehicle.tyre, load, 0.0, np.tan(alpha), mu, vehicle.reference_wheel_load)[1])
    wheel_speed = FIGURE_SPEED * (1.0 + kappa)
    slip = (wheel_speed - FIGURE_SPEED) / np.maximum(np.maximum(wheel_speed, FIGURE_SPEED), MIN_SPEED)
    k = p.front.mu_scale
    fx_dugoff = np.array([dugoff(load, s, 0.0, k * mu, cx, cy, 0.0, 0.0)[0] for s in slip])
    fy_dugoff = np.array([dugoff(load, 0.0, t, k * mu, cx, cy, 0.0, 0.0)[1] for t in np.tan(alpha)])
    m = ModelParams.from_vehicle(vehicle, shape="magic").front
    fy_magic = magic_lateral_force(
        load, np.tan(alpha), mu, cy, m.magic_c, m.magic_e, m.mu_scale, m.load_sensitivity, m.reference_load
    )
    return TyreCurves(kappa, fx_plant, fx_dugoff, alpha, fy_plant, fy_dugoff, fy_magic)


def plot_tyre_curves(path: str | Path, mu: float = 1.0, loads=FIGURE_LOADS, vehicle=None) -> Path:
    """PNG in the form of the paper's Figures 2 (longitudinal force against slip ratio) and 3
    (lateral force against slip angle) at several wheel loads [N]: the plant tyre solid, the
    estimator's fitted Dugoff dashed, on road friction ``mu``."""
    plt = pyplot()
    fig, (ax_x, ax_y) = plt.subplots(1, 2, figsize=(12, 4.5))
    for load in loads:
        c = tyre_curves(load, mu, vehicle)
        (line,) = ax_x.plot(c.kappa, c.fx_plant, lw=1.5, label=f"{load / 1000:g} kN")
        ax_x.plot(c.kappa, c.fx_dugoff, "--", lw=1.2, color=line.get_color())
        ax_y.plot(np.degrees(c.alpha), c.fy_plant, lw=1.5, color=line.get_color(), label=f"{load / 1000:g} kN")
        ax_y.plot(np.degrees(c.alpha), c.fy_dugoff, "--", lw=1.2, color=line.get_color())
        ax_y.plot(np.degrees(c.alpha), c.fy_magic, ":", lw=1.5, color=line.get_color())
    ax_x.set(
        xlabel="slip ratio [-]",
        ylabel="longitudinal force Fx [N]",
        title="longitudinal slip characteristic (paper Fig. 2)",
    )
    ax_y.set(
        xlabel="slip angle [deg]", ylabel="lateral force |Fy| [N]", title="lateral slip characteristic (paper Fig. 3)"
    )
    for ax in (ax_x, ax_y):
        ax.grid(alpha=0.3)
        ax.legend(
            title="wheel load (solid: plant PAC2002, dashed: fitted Dugoff, dotted: joint's Magic Formula)",
            fontsize=8,
            title_fontsize=8,
        )
    fig.suptitle(f"tyre curves on mu {mu:g}: the plant's Magic Formula and the estimator's Dugoff (eq. 17 fit)")
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=100))
    plt.close(fig)
    return Path(path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m fourwis.training.tyre_fit", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--plot",
        metavar="DIR",
        help="only draw DIR/tyre_curves.png (paper Figs. 2-3) from the shipped fit; the fit file is left as it is",
    )
    args = parser.parse_args(argv)
    if args.plot:
        directory = Path(args.plot)
        directory.mkdir(parents=True, exist_ok=True)
        print(plot_tyre_curves(directory / "tyre_curves.png"))
        return
    fit = fit_dugoff()
    print(atomic_write_json(OUTPUT, fit), end="")


if __name__ == "__main__":
    main()

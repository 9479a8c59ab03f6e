"""Fit the estimator's tyre (Dugoff with load-dependent stiffness, paper eq. 17) to the plant's
PAC2002 tyre, the way the paper fits CarSim's: C(Fz) = m Fz - n Fz^2 by least squares on the
plant tyre's cornering and slip stiffness over 1-5 kN, then Dugoff's friction scale k (Dugoff
uses k mu where the road has mu) by least squares on the lateral force from zero slip to the
plant tyre's peak over the same loads and mu 0.3-1.0. Dugoff's curve rounds off into its
saturation more gently than the Magic Formula's, so at mu it under-predicts the force near the
peak (fitted k ~1.07); without k the joint estimator reads mu high by about that much.
Writes estimation/data/dugoff_fit.json.

Run: ``python -m training.tyre_fit``
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

from envs.tyre import TyreParams, tyre_forces
from envs.vehicle import VehicleParams
from estimation.model import dugoff
from training.io import atomic_write_json

OUTPUT = Path(__file__).resolve().parent.parent / "estimation" / "data" / "dugoff_fit.json"
LOADS = np.linspace(1000.0, 5000.0, 17)  #: fit loads [N]
FRICTIONS = (0.3, 0.5, 0.8, 1.0)  #: road mu of the friction-scale fit


def fit_quadratic(fz: np.ndarray, stiffness: np.ndarray) -> tuple[float, float, float]:
    """Least-squares (m, n, R^2) of ``stiffness = m fz - n fz^2`` (no constant: zero at zero load)."""
    design = np.column_stack([fz, -fz**2])
    (m, n), *_ = np.linalg.lstsq(design, stiffness, rcond=None)
    residual = stiffness - design @ (m, n)
    return float(m), float(n), float(1.0 - residual.var() / stiffness.var())


def fit_friction_scale(tyre: TyreParams, m2: float, n2: float, reference_load: float) -> tuple[float, float, float]:
    """Least-squares Dugoff friction scale k and the RMS lateral-force error [mu Fz] with k and
    with 1: pure cornering, tan(alpha) from 0.002 up to the plant tyre's peak (beyond it the
    Magic Formula falls off and Dugoff cannot follow), loads LOADS, road mu FRICTIONS, the plant
    normalising mu at ``reference_load`` [N] as the truth plant does."""
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
    fz, mu, ta, fy = map(np.concatenate, (loads, frictions, slips, forces))
    cy = m2 * fz - n2 * fz**2

    def rms_error(k: float) -> float:
        # the estimator's own tyre at zero longitudinal slip, Dugoff's speed term off
        model = np.array([dugoff(f, 0.0, t, k * m, 1.0, c, 0.0, 0.0)[1] for f, t, m, c in zip(fz, ta, mu, cy)])
        return float(np.sqrt(np.mean(((model - fy) / (mu * fz)) ** 2)))

    best = minimize_scalar(rms_error, bounds=(0.5, 2.0), method="bounded", options={"xatol": 1e-5})
    return float(best.x), rms_error(best.x), rms_error(1.0)


def fit_dugoff(tyre: TyreParams | None = None, reference_load: float | None = None) -> dict:
    """Eq. 17 coefficients for the longitudinal (m1, n1) and lateral (m2, n2) stiffness and the
    friction scale ``mu_scale`` (reference load: the car's static wheel load, as in the plant)."""
    vehicle = VehicleParams()
    tyre = tyre or vehicle.tyre
    reference_load = vehicle.reference_wheel_load if reference_load is None else reference_load
    m1, n1, r2x = fit_quadratic(LOADS, np.asarray(tyre.slip_stiffness(LOADS)))
    m2, n2, r2y = fit_quadratic(LOADS, np.asarray(tyre.cornering_stiffness(LOADS)))
    mu_scale, rms_scaled, rms_unscaled = fit_friction_scale(tyre, m2, n2, reference_load)
    return {"m1": m1, "n1": n1, "m2": m2, "n2": n2, "r2_longitudinal": r2x, "r2_lateral": r2y,
            "mu_scale": mu_scale, "lateral_rms_error_mu_fz": rms_scaled, "lateral_rms_error_mu_fz_unscaled": rms_unscaled,
            "loads_N": [float(LOADS[0]), float(LOADS[-1])],
            "source": "least-squares fit of eq. 17 to the plant tyre (PAC2002, chrono mf_185_80R14.tir) stiffness; "
                      "mu_scale: least squares on the lateral force up to the plant tyre's peak"}


def main() -> None:
    fit = fit_dugoff()
    print(atomic_write_json(OUTPUT, fit), end="")


if __name__ == "__main__":
    main()

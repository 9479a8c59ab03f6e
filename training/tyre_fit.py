"""Fit the estimator's tyre (Dugoff with load-dependent stiffness, paper eq. 17) to the plant's
PAC2002 tyre, the way the paper fits CarSim's: C(Fz) = m Fz - n Fz^2 by least squares on the
plant tyre's cornering and slip stiffness over 1-5 kN. Writes estimation/data/dugoff_fit.json.

Run: ``python -m training.tyre_fit``
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from envs.tyre import TyreParams
from training.io import atomic_write_text

OUTPUT = Path(__file__).resolve().parent.parent / "estimation" / "data" / "dugoff_fit.json"
LOADS = np.linspace(1000.0, 5000.0, 17)  #: fit loads [N]


def fit_quadratic(fz: np.ndarray, stiffness: np.ndarray) -> tuple[float, float, float]:
    """Least-squares (m, n, R^2) of ``stiffness = m fz - n fz^2`` (no constant: zero at zero load)."""
    design = np.column_stack([fz, -fz**2])
    (m, n), *_ = np.linalg.lstsq(design, stiffness, rcond=None)
    residual = stiffness - design @ (m, n)
    return float(m), float(n), float(1.0 - residual.var() / stiffness.var())


def fit_dugoff(tyre: TyreParams | None = None) -> dict:
    """Eq. 17 coefficients for the longitudinal (m1, n1) and lateral (m2, n2) stiffness."""
    tyre = tyre or TyreParams()
    m1, n1, r2x = fit_quadratic(LOADS, np.asarray(tyre.slip_stiffness(LOADS)))
    m2, n2, r2y = fit_quadratic(LOADS, np.asarray(tyre.cornering_stiffness(LOADS)))
    return {"m1": m1, "n1": n1, "m2": m2, "n2": n2, "r2_longitudinal": r2x, "r2_lateral": r2y,
            "loads_N": [float(LOADS[0]), float(LOADS[-1])],
            "source": "least-squares fit of eq. 17 to the plant tyre (PAC2002, chrono mf_185_80R14.tir) stiffness"}


def main() -> None:
    fit = fit_dugoff()
    atomic_write_text(OUTPUT, json.dumps(fit, indent=2) + "\n")
    print(json.dumps(fit, indent=2))


if __name__ == "__main__":
    main()

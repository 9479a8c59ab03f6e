"""Derive this car's sideslip phase-plane stability region, the way Inagaki, Kushiro and
Yamamoto derive it ("Analysis on vehicle stability in critical cornering using phase-plane
method", AVEC '94 / JSAE Review 16(2), 1995; the band form |beta_dot + c1 beta| <= c2 is the one
He, Crolla, Levesque and Manning use, Proc. IMechE D 220, 2006): trajectories of the nonlinear
2-DOF model (sideslip beta, yaw rate r) with the steering straight, started on a grid of
initial states, either return to straight running or diverge; in the (beta, beta_dot) plane the
states that return lie in a band between two parallel lines, bounded by the separatrices of the
model's saddle points. Their numbers (Inagaki et al.'s dry-road c1 = 2.49 1/s, c2 = 9.55 deg/s)
belong to their car; these are this car's.

Model: the plant's own tyre (PAC2002, :mod:`envs.tyre`) at the static axle loads, pure
cornering, constant forward speed u (the 2-DOF assumption; no load transfer, no drive slip):
    v_dot = (F_yf + F_yr) / m - u r,   r_dot = (a F_yf - b F_yr) / I_z,
    beta = atan(v / u), so beta_dot = cos^2(beta) v_dot / u,
integrated by RK4 (5 ms) for 4 s from a grid of (beta, r): |beta| <= 20 deg, |r| <= 3 mu g / u
(three times the friction-limited steady yaw rate; the region is the band within this window,
since the band alone, an unbounded strip, reaches spinning states far outside it).
A start counts as stable when the car is back within 1 deg of sideslip and 0.02 rad/s of yaw
rate at the end. Between neighbouring starts (along r) that end differently, the separatrix is
located by bisection (12 halvings: to 1/4096 of a grid step). For each slope c1 on a grid, c2 is the largest
half-width such that the band holds no diverging start and no separatrix point; the slope kept
is the one whose band holds the most stable starts ("coverage", reported). The band is
therefore conservative on the 2-DOF model within the window: inside it, the car recovers by
itself with the steering straight.

Writes control/data/phase_plane.json (SI: slope [1/s], bound [rad/s]) for a table of speeds x
road friction. Run: ``python -m fourwis.training.phase_plane_fit`` (~3.5 min).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from tqdm import tqdm

from fourwis.core.constants import GRAVITY
from fourwis.envs.tyre import tyre_forces
from fourwis.envs.vehicle import VehicleParams
from fourwis.training.io import atomic_write_json

OUTPUT = Path(__file__).resolve().parent.parent / "control" / "data" / "phase_plane.json"
SPEEDS = (10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)  #: table speeds [m/s]
FRICTIONS = (0.2, 0.3, 0.5, 0.7, 1.0)  #: table road friction [-]
MAX_SIDESLIP = np.radians(20.0)  #: initial-state window [rad]
YAW_RATE_WINDOW = 3.0  #: initial |r| up to this many friction-limited yaw rates mu g / u
GRID = 101  #: initial states per axis
BISECTIONS = 12  #: halvings of a grid step to locate the separatrix
HORIZON = 4.0  #: [s]
STEP = 0.005  #: [s]
RECOVERED_SIDESLIP = np.radians(1.0)  #: [rad]
RECOVERED_YAW_RATE = 0.02  #: [rad/s]
SLOPES = np.linspace(0.0, 10.0, 201)  #: candidate slopes c1 [1/s]


def sideslip_dynamics(
    beta: np.ndarray, r: np.ndarray, u: float, mu: float, params: VehicleParams
) -> tuple[np.ndarray, np.ndarray]:
    """(beta_dot [rad/s], r_dot [rad/s^2]) of the straight-steered 2-DOF model, shapes of ``beta``."""
    fz = params.static_wheel_loads
    a, b = params.cg_to_front, params.cg_to_rear
    tan_beta = np.tan(beta)
    slip = np.concatenate([tan_beta + a * r / u, tan_beta - b * r / u])  # contact-centre tan(alpha)
    loads = np.repeat([fz[0], fz[2]], beta.size)
    _, fy = tyre_forces(params.tyre, loads, 0.0, slip, mu, params.reference_wheel_load)
    fy_front, fy_rear = 2.0 * fy[: beta.size], 2.0 * fy[beta.size :]
    v_dot = (fy_front + fy_rear) / params.mass - u * r
    return np.cos(beta) ** 2 * v_dot / u, (a * fy_front - b * fy_rear) / params.yaw_inertia


def recovers(beta: np.ndarray, r: np.ndarray, u: float, mu: float, params: VehicleParams) -> np.ndarray:
    """Whether each start (beta [rad], r [rad/s]) returns to straight running (bool, shape of beta)."""

    def f(x):
        return np.stack(sideslip_dynamics(x[0], x[1], u, mu, params))

    x = np.stack([beta, r]).astype(float)
    for _ in range(int(round(HORIZON / STEP))):
        k1 = f(x)
        k2 = f(x + 0.5 * STEP * k1)
        k3 = f(x + 0.5 * STEP * k2)
        k4 = f(x + STEP * k3)
        x = x + STEP / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        x[0] = np.clip(x[0], -1.5, 1.5)  # a spun car stays spun; keeps tan(beta) finite
    return (np.abs(x[0]) < RECOVERED_SIDESLIP) & (np.abs(x[1]) < RECOVERED_YAW_RATE)


def fit_band(
    beta: np.ndarray, beta_rate: np.ndarray, stable: np.ndarray, boundary_beta: np.ndarray, boundary_rate: np.ndarray
) -> tuple[float, float, float]:
    """(c1 [1/s], c2 [rad/s], coverage): the band |beta_rate + c1 beta| < c2 free of diverging
    starts and of separatrix points (``boundary_*``) that holds the largest share (coverage) of
    the stable starts."""
    best = (0.0, 0.0, -1.0)
    excluded_beta = np.concatenate([beta[~stable], boundary_beta])
    excluded_rate = np.concatenate([beta_rate[~stable], boundary_rate])
    for c1 in SLOPES:
        c2 = float(np.min(np.abs(excluded_rate + c1 * excluded_beta))) if excluded_beta.size else np.inf
        coverage = float(np.mean(np.abs(beta_rate[stable] + c1 * beta[stable]) < c2))
        if coverage > best[2]:
            best = (float(c1), c2, coverage)
    return best


def separatrix(
    beta: np.ndarray, r: np.ndarray, stable: np.ndarray, u: float, mu: float, params: VehicleParams
) -> tuple[np.ndarray, np.ndarray]:
    """Points (beta, r) on the boundary between recovering and diverging starts, by bisection
    between neighbours along r of the (GRID, GRID) grid (rows: r) that end differently."""
    b, rr, ok = (x.reshape(GRID, GRID) for x in (beta, r, stable))
    rows, cols = np.nonzero(ok[:-1] != ok[1:])
    beta_b = b[rows, cols]
    low, high = rr[rows, cols], rr[rows + 1, cols]
    low_ok = ok[rows, cols]
    for _ in range(BISECTIONS):
        mid = 0.5 * (low + high)
        mid_ok = recovers(beta_b, mid, u, mu, params)
        same = mid_ok == low_ok
        low, high = np.where(same, mid, low), np.where(same, high, mid)
    return beta_b, 0.5 * (low + high)


def fit_cell(u: float, mu: float, params: VehicleParams | None = None) -> tuple[float, float, float]:
    """(c1, c2, coverage) at speed ``u`` [m/s] and road friction ``mu``."""
    params = params or VehicleParams()
    beta, r = np.meshgrid(
        np.linspace(-MAX_SIDESLIP, MAX_SIDESLIP, GRID),
        np.linspace(-1.0, 1.0, GRID) * YAW_RATE_WINDOW * mu * GRAVITY / u,
    )
    beta, r = beta.ravel(), r.ravel()
    stable = recovers(beta, r, u, mu, params)
    beta_rate, _ = sideslip_dynamics(beta, r, u, mu, params)
    boundary_beta, boundary_r = separatrix(beta, r, stable, u, mu, params)
    boundary_rate, _ = sideslip_dynamics(boundary_beta, boundary_r, u, mu, params)
    return fit_band(beta, beta_rate, stable, boundary_beta, boundary_rate)


def fit_table(params: VehicleParams | None = None) -> dict:
    """The region over SPEEDS x FRICTIONS, in the layout of control/data/phase_plane.json."""
    cells = [
        [fit_cell(u, mu, params) for mu in FRICTIONS] for u in tqdm(SPEEDS, desc="phase-plane region", unit="speed")
    ]
    return {
        "speeds_m_s": list(SPEEDS),
        "frictions": list(FRICTIONS),
        "slope_1_s": [[c[0] for c in row] for row in cells],
        "bound_rad_s": [[c[1] for c in row] for row in cells],
        "coverage": [[c[2] for c in row] for row in cells],
        "yaw_rate_window": YAW_RATE_WINDOW,
        "source": "python -m fourwis.training.phase_plane_fit: Inagaki et al. (AVEC '94) phase-plane method on the "
        "2-DOF model with the plant tyre (PAC2002) at static axle loads, steering straight",
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m fourwis.training.phase_plane_fit",
        description="Derive this car's sideslip phase-plane stability region (Inagaki et al.) for a table of "
        "speeds x road friction and overwrite control/data/phase_plane.json (~3.5 min).",
    )
    parser.parse_args(argv)
    table = fit_table()
    print(atomic_write_json(OUTPUT, table), end="")


if __name__ == "__main__":
    main()

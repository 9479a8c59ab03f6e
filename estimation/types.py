"""Types shared by every estimator: what goes out of a step."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Order of the state vector x_s of the paper's state filter.
STATE_NAMES = ("u", "v", "ax", "ay", "r", "gamma")


class Estimate(NamedTuple):
    """One estimator step's output for a batch of B vehicles (SI units).

    u, v: body velocities [m/s] (B,); beta = atan2(v, u) [rad] (B,); r: yaw rate [rad/s] (B,);
    ax, ay: body specific forces [m/s^2] (B,); mu: road friction per wheel (B, 4);
    fz: normal loads per wheel [N] (B, 4); beta_std [rad] (B,) and mu_std (B, 4): one-sigma
    uncertainty (zero for the oracle).
    """

    u: np.ndarray
    v: np.ndarray
    beta: np.ndarray
    r: np.ndarray
    ax: np.ndarray
    ay: np.ndarray
    mu: np.ndarray
    fz: np.ndarray
    beta_std: np.ndarray
    mu_std: np.ndarray

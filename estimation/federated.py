"""Federated Kalman filter with reset (Carlson, IEEE TAES 26(3), 1990; paper eq. 33-35, 59-61).

Each step the master's (x_g, P_g) is shared out to N sub-filters with information-sharing
coefficients beta_i (sum 1): P_i = P_g / beta_i, Q_i = Q / beta_i. Each sub-filter predicts
with the common model and updates with its own measurements; the master fuses them by
information weighting. For linear-Gaussian systems this equals the centralised filter.
The betas adapt to each sub-filter's confidence (paper eq. 59-61): beta_i proportional to
trace(P_i^-1) after its last update, floored at 5% so no sub-filter is switched off.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from estimation.ckf import ckf_predict, ckf_update

BETA_FLOOR = 0.05


def fuse(xs: Sequence[np.ndarray], Ps: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Information-weighted fusion: P_g = (sum P_i^-1)^-1, x_g = P_g sum P_i^-1 x_i."""
    infos = [np.linalg.inv(P) for P in Ps]
    P_g = np.linalg.inv(sum(infos))
    x_g = (P_g @ sum(I @ x[..., None] for I, x in zip(infos, xs)))[..., 0]
    return x_g, 0.5 * (P_g + np.swapaxes(P_g, -1, -2))


def sharing_coefficients(Ps: Sequence[np.ndarray]) -> np.ndarray:
    """beta (B, N): proportional to trace(P_i^-1), floored at BETA_FLOOR, summing to 1."""
    conf = np.stack([np.trace(np.linalg.inv(P), axis1=1, axis2=2) for P in Ps], axis=1)
    beta = conf / conf.sum(axis=1, keepdims=True)
    beta = np.maximum(beta, BETA_FLOOR)
    return beta / beta.sum(axis=1, keepdims=True)


class SubMeasurement(NamedTuple):
    """One sub-filter's measurement: z (B, m), h(points) -> (B, K, m), R (m, m) or (B, m, m),
    valid (B, m) bool or None."""

    z: np.ndarray
    h: Callable[[np.ndarray], np.ndarray]
    R: np.ndarray
    valid: np.ndarray | None


class FederatedStep(NamedTuple):
    """Fused state (B, n), covariance (B, n, n), next betas (B, N), per-sub-filter innovation NLL list."""

    x: np.ndarray
    P: np.ndarray
    beta: np.ndarray
    nll: list[np.ndarray]


def federated_step(x: np.ndarray, P: np.ndarray, f: Callable[[np.ndarray], np.ndarray], Q: np.ndarray,
                   subs: Sequence[SubMeasurement], beta: np.ndarray, huber_c: float | None = None) -> FederatedStep:
    """One federated CKF cycle: share (reset), predict + update each sub-filter, fuse."""
    xs, Ps, nlls = [], [], []
    for i, sub in enumerate(subs):
        b = beta[:, i][:, None, None]
        x_i, P_i = ckf_predict(x, P / b, f, Q / b)
        upd = ckf_update(x_i, P_i, sub.z, sub.h, sub.R, huber_c=huber_c, valid=sub.valid)
        xs.append(upd.x)
        Ps.append(upd.P)
        nlls.append(upd.nll)
    x_g, P_g = fuse(xs, Ps)
    return FederatedStep(x_g, P_g, sharing_coefficients(Ps), nlls)

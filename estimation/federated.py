"""Federated Kalman filter with reset (Carlson, IEEE TAES 26(3), 1990; paper eq. 33-35, 59-61):
compiled fusion and sharing rules, and :func:`federated_step`, one cycle for a batch and any
vectorised models (the estimators' compiled steps run the same cycle on the vehicle model:
joint._federated, tested against this one).

Each step the master's (x_g, P_g) is shared out to the sub-filters with information-sharing
coefficients beta_i (sum 1): P_i = P_g / beta_i, Q_i = Q / beta_i. Each sub-filter predicts
with the common model and updates with its own measurements; the master fuses them by
information weighting (eq. 59-61; eq. 60 prints P_sf^-1 where P_sf is meant). For
linear-Gaussian systems with independent measurements this equals the centralised filter
(tested). The paper's sub-filters share channels (sub-filter 1 [ax, ay, r], sub-filter 2
[ay, r]): the fusion then counts the shared channels' information twice, as the paper's
design does, and the fused covariance is optimistic by up to that much.

Sharing coefficients: a replacement for the paper's adaptive rule (eq. 58), whose printed
form does not define its quantities: beta_i proportional to trace(P_i^-1) after sub-filter
i's last update (its confidence), floored at BETA_FLOOR before normalising (so ~4.8% at
least: no sub-filter is switched off). The trace adds inverse variances of unlike units, so
the best-known states dominate it; in the mu filter the strongly correlated prior dominates.
The coefficients stay near 1/2, so the rule is nearly inert
(docs/decisions/0010-estimation-model-and-paper-deviations.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numba
import numpy as np

from fourwis.core.kernels import JIT, scratch
from fourwis.estimation.ckf import batch_arrays, ckf_predict, ckf_update, noise_matrix, spd_inverse

BETA_FLOOR = 0.05


@numba.njit(**JIT)
def fuse(xs: np.ndarray, Ps: np.ndarray, x_out: np.ndarray, P_out: np.ndarray, confidence: np.ndarray) -> bool:
    """Information-weighted fusion of N estimates xs (N, n), Ps (N, n, n):
    P_g = (sum P_i^-1)^-1, x_g = P_g sum P_i^-1 x_i; confidence (N,) = trace(P_i^-1)."""
    N, n = xs.shape
    info_sum, weighted, info = scratch((n, n)), scratch((n,)), scratch((n, n))
    info_sum[:, :] = 0.0
    weighted[:] = 0.0
    for s in range(N):
        if not spd_inverse(Ps[s], info):
            return False
        confidence[s] = np.trace(info)
        for i in range(n):
            for j in range(n):
                info_sum[i, j] += info[i, j]
                weighted[i] += info[i, j] * xs[s, j]
    if not spd_inverse(info_sum, P_out):
        return False
    for i in range(n):
        t = 0.0
        for j in range(n):
            t += P_out[i, j] * weighted[j]
        x_out[i] = t
    return True


@numba.njit(inline="always", **JIT)
def sharing_coefficients(confidence: np.ndarray, beta: np.ndarray) -> None:
    """beta (N,): proportional to the confidences, floored at BETA_FLOOR, summing to 1."""
    total = confidence.sum()
    for s in range(beta.shape[0]):
        beta[s] = max(confidence[s] / total, BETA_FLOOR)
    beta /= beta.sum()


# ---- batched entry point from Python ------------------------------------------------------
class SubMeasurement(NamedTuple):
    """One sub-filter's measurement: z (B, m), h(points (B, K, n)) -> (B, K, m), R (m, m) or
    (B, m, m), valid (B, m) bool or None (every channel valid)."""

    z: np.ndarray
    h: Callable[[np.ndarray], np.ndarray]
    R: np.ndarray
    valid: np.ndarray | None = None


class FederatedStep(NamedTuple):
    """Fused state (B, n), covariance (B, n, n), next betas (B, N), innovation NLL (B, N)."""

    x: np.ndarray
    P: np.ndarray
    beta: np.ndarray
    nll: np.ndarray


@numba.njit(**JIT)
def _fuse_batch(xs, Ps, x_out, P_out, beta_out, ok):
    for b in range(xs.shape[0]):
        confidence = np.empty(xs.shape[1])
        ok[b] = fuse(xs[b], Ps[b], x_out[b], P_out[b], confidence)
        sharing_coefficients(confidence, beta_out[b])


def federated_step(
    x: np.ndarray,
    P: np.ndarray,
    f: Callable[[np.ndarray], np.ndarray],
    Q: np.ndarray,
    subs: Sequence[SubMeasurement],
    beta: np.ndarray,
    huber_c: float | None = None,
) -> FederatedStep:
    """One federated CKF cycle for a batch: share (reset) with beta (B, N), predict + update each
    sub-filter, fuse. x (B, n), P (B, n, n), f maps point sets (B, K, n) to (B, K, n)."""
    x, P = batch_arrays(x, P)
    beta = np.asarray(beta, dtype=np.float64)
    if beta.shape != (len(x), len(subs)):
        raise ValueError(f"beta must have shape {(len(x), len(subs))}, got {beta.shape}")
    if not (np.all(beta > 0.0) and np.allclose(beta.sum(axis=1), 1.0, rtol=0.0, atol=1e-9)):
        raise ValueError(f"information-sharing coefficients must be > 0 and sum to 1 per member, got {beta!r}")
    Q = noise_matrix(Q, P.shape, "Q")
    xs, Ps, nlls = [], [], []
    for i, sub in enumerate(subs):
        b = beta[:, i][:, None, None]
        x_i, P_i = ckf_predict(x, P / b, f, Q / b)
        upd = ckf_update(x_i, P_i, sub.z, sub.h, sub.R, huber_c=huber_c, valid=sub.valid)
        xs.append(upd.x)
        Ps.append(upd.P)
        nlls.append(upd.nll)
    x_g, P_g, beta_next, ok = np.empty_like(x), np.empty_like(P), np.empty_like(beta), np.empty(len(x), np.bool_)
    _fuse_batch(np.stack(xs, axis=1), np.stack(Ps, axis=1), x_g, P_g, beta_next, ok)
    if not ok.all():
        raise ValueError(f"fusion of member {int(np.argmin(ok))} failed: a covariance is not finite")
    return FederatedStep(x_g, P_g, beta_next, np.stack(nlls, axis=1))

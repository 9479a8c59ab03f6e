"""Batched cubature Kalman filter (Arasaratnam & Haykin, IEEE TAC 54(6), 2009) with a
Huber-robust measurement update (paper eq. 21-29) and dropout masking.

Shapes: B batch, n state, m measurement, K = 2n cubature points. Process and measurement
functions take point sets (B, K, n) and return (B, K, n) / (B, K, m).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

DROPOUT_VARIANCE = 1e12  #: variance given to a channel without valid data (no information)


def robust_sqrt(P: np.ndarray) -> np.ndarray:
    """S with S S^T = P (B, n, n): batched Cholesky of the symmetrised P; members where it
    fails fall back to an eigen-decomposition with eigenvalues floored at 1e-12 trace(P)."""
    if not np.all(np.isfinite(P)):
        raise ValueError("covariance contains NaN or inf")
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    S = np.empty_like(P)
    for i in range(P.shape[0]):
        try:
            S[i] = np.linalg.cholesky(P[i])
        except np.linalg.LinAlgError:
            w, V = np.linalg.eigh(P[i])
            w = np.maximum(w, 1e-12 * max(np.trace(P[i]), 1e-300))
            S[i] = V * np.sqrt(w)
    return S


def cubature_points(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """The 2n third-degree spherical-radial points x +/- sqrt(n) S e_j (B, 2n, n)."""
    n = x.shape[-1]
    offsets = np.sqrt(n) * np.swapaxes(robust_sqrt(P), -1, -2)  # rows: scaled columns of S
    return x[:, None, :] + np.concatenate([offsets, -offsets], axis=1)


def _moments(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = points.mean(axis=1)
    d = points - mean[:, None, :]
    return mean, np.swapaxes(d, 1, 2) @ d / points.shape[1]


def ckf_predict(x: np.ndarray, P: np.ndarray, f: Callable[[np.ndarray], np.ndarray],
                Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time update: propagate the cubature points through ``f``; returns (x_pred, P_pred)."""
    mean, cov = _moments(f(cubature_points(x, P)))
    cov = cov + Q
    return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))


class CKFUpdate(NamedTuple):
    """Measurement update result: state x (B, n) and P (B, n, n), innovation (B, m), its
    covariance S (B, m, m), Huber weights (B, m) and innovation negative log-likelihood (B,)."""

    x: np.ndarray
    P: np.ndarray
    innovation: np.ndarray
    innovation_cov: np.ndarray
    weights: np.ndarray
    nll: np.ndarray


def huber_weights(standardised: np.ndarray, c: float) -> np.ndarray:
    """Huber's equivalent weights (eq. 27): 1 inside |r| <= c, c/|r| outside."""
    a = np.abs(standardised)
    return np.where(a <= c, 1.0, c / np.maximum(a, 1e-300))


def ckf_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, h: Callable[[np.ndarray], np.ndarray], R: np.ndarray,
               huber_c: float | None = None, valid: np.ndarray | None = None) -> CKFUpdate:
    """Measurement update with fresh cubature points of (x, P).

    Robust (``huber_c``): standardised innovations r_i = nu_i / sqrt(S_ii) give Huber weights
    w_i; the noise covariance is inflated to R_ij / sqrt(w_i w_j) (the equivalent-weight form
    R_bar = P_bar^-1 of eq. 28-29; the paper's printed indices slip) and the update redone.
    Channels with ``valid`` False (B, m) carry no information (variance 1e12)."""
    if z.ndim != 2 or z.shape[0] != x.shape[0]:
        raise ValueError(f"measurement must have shape (B, m) with B = {x.shape[0]}, got {z.shape}")
    valid = np.ones(z.shape, dtype=bool) if valid is None else valid
    if not np.all(np.isfinite(z[valid])):
        raise ValueError("a valid measurement is NaN or inf")
    points = cubature_points(x, P)
    Z = h(points)
    z_mean, Pzz = _moments(Z)
    Pxz = np.swapaxes(points - x[:, None, :], 1, 2) @ (Z - z_mean[:, None, :]) / points.shape[1]
    nu = np.where(valid, z - z_mean, 0.0)
    R = np.broadcast_to(R, Pzz.shape).copy()
    idx = np.arange(z.shape[1])
    R[:, idx, idx] = np.where(valid, R[:, idx, idx], DROPOUT_VARIANCE)
    S = Pzz + R
    weights = np.ones_like(nu)
    if huber_c is not None:
        weights = huber_weights(nu / np.sqrt(np.diagonal(S, axis1=1, axis2=2)), huber_c)
        R = R / np.sqrt(weights[:, :, None] * weights[:, None, :])
        S = Pzz + R
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    gain = np.linalg.solve(S, np.swapaxes(Pxz, -1, -2))  # S^-1 Pzx, i.e. K^T
    gain = np.swapaxes(gain, -1, -2)
    x_new = x + (gain @ nu[..., None])[..., 0]
    P_new = P - gain @ S @ np.swapaxes(gain, -1, -2)
    P_new = 0.5 * (P_new + np.swapaxes(P_new, -1, -2))
    sign, logdet = np.linalg.slogdet(S)
    m_valid = valid.sum(axis=1)
    maha = np.sum(nu * np.linalg.solve(S, nu[..., None])[..., 0], axis=1)
    logdet_valid = logdet - np.log(DROPOUT_VARIANCE) * (z.shape[1] - m_valid)
    nll = 0.5 * (maha + logdet_valid + m_valid * np.log(2 * np.pi))
    return CKFUpdate(x_new, P_new, nu, S, weights, nll)

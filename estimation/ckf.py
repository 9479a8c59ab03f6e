"""Cubature Kalman filter (Arasaratnam & Haykin, IEEE TAC 54(6), 2009) with a Huber-robust
measurement update (paper eq. 21-29) and dropout masking, compiled with numba.

The compiled building blocks take the model's values at the cubature points rather than the
model itself (numba cannot cache code that receives a function): a filter step draws
:func:`cubature_points`, evaluates its model at each, and hands the results to
:func:`predicted_moments` (time update) or :func:`measurement_update`. The estimators' compiled
steps (estimation/joint.py) do this for the vehicle model; :func:`ckf_predict` and
:func:`ckf_update` do it from Python for a batch (leading axis B) and any vectorised model
``f(points (B, K, n)) -> (B, K, k)``.

Shapes: n state, m measurement, K = 2n cubature points.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from fourwis.core.kernels import JIT, scratch

DROPOUT_VARIANCE = 1e12  #: variance given to a channel without valid data (no information)
NO_HUBER = math.inf  #: Huber threshold meaning "plain (non-robust) update"


@numba.njit(inline="always", **JIT)
def cholesky(A: np.ndarray, L: np.ndarray) -> bool:
    """Lower Cholesky factor of the symmetrised A, 0.5 (A + A^T), into L; False if it is not
    numerically positive definite (or not finite)."""
    n = A.shape[0]
    L[:, :] = 0.0
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not (s > 0.0 and s < math.inf):
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = 0.5 * (A[i, j] + A[j, i])
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
    return True


@numba.njit(**JIT)
def covariance_sqrt(P: np.ndarray, S: np.ndarray) -> bool:
    """Lower-triangular S with S S^T = P: Cholesky of the symmetrised P; if that fails (P
    numerically semi-definite), of P plus a diagonal jitter growing tenfold from 1e-12 trace(P)
    until it succeeds. False if P is not finite or no jitter up to trace(P) helps."""
    if cholesky(P, S):
        return True
    n = P.shape[0]
    sym = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            sym[i, j] = 0.5 * (P[i, j] + P[j, i])
            if not math.isfinite(sym[i, j]):
                return False
    jitter = 1e-12 * max(np.trace(sym), 1e-300)
    while jitter <= max(np.trace(sym), 1e-300):
        for i in range(n):
            sym[i, i] += jitter
        if cholesky(sym, S):
            return True
        for i in range(n):
            sym[i, i] -= jitter
        jitter *= 10.0
    return False


@numba.njit(inline="always", **JIT)
def cholesky_solve(L: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """out = (L L^T)^-1 b for a lower-triangular L."""
    n = L.shape[0]
    for i in range(n):
        t = b[i]
        for k in range(i):
            t -= L[i, k] * out[k]
        out[i] = t / L[i, i]
    for i in range(n - 1, -1, -1):
        t = out[i]
        for k in range(i + 1, n):
            t -= L[k, i] * out[k]
        out[i] = t / L[i, i]


@numba.njit(**JIT)
def spd_inverse(A: np.ndarray, out: np.ndarray) -> bool:
    """Inverse of a symmetric positive definite A into out, through its (jittered if need be)
    Cholesky factor S: A^-1 = S^-T S^-1. False if A is not finite."""
    n = A.shape[0]
    S = scratch((n, n))
    if not covariance_sqrt(A, S):
        return False
    S_inv = scratch((n, n))  # inverse of the lower-triangular S, column by column
    S_inv[:, :] = 0.0
    for c in range(n):
        for i in range(c, n):
            t = 1.0 if i == c else 0.0
            for k in range(c, i):
                t -= S[i, k] * S_inv[k, c]
            S_inv[i, c] = t / S[i, i]
    for i in range(n):
        for j in range(i, n):
            t = 0.0
            for k in range(n):
                t += S_inv[k, i] * S_inv[k, j]
            out[i, j] = t
            out[j, i] = t
    return True


@numba.njit(**JIT)
def cubature_points(x: np.ndarray, P: np.ndarray, points: np.ndarray) -> bool:
    """The 2n third-degree spherical-radial points x +/- sqrt(n) S e_j into points (2n, n)."""
    n = x.shape[0]
    S = scratch((n, n))
    if not covariance_sqrt(P, S):
        return False
    c = math.sqrt(n)
    for k in range(n):
        for i in range(n):
            points[k, i] = x[i] + c * S[i, k]
            points[n + k, i] = x[i] - c * S[i, k]
    return True


@numba.njit(**JIT)
def predicted_moments(moved: np.ndarray, Q: np.ndarray, x_out: np.ndarray, P_out: np.ndarray) -> None:
    """Time update from the propagated cubature points moved (K, n): their mean, and their
    covariance plus Q, into (x_out, P_out)."""
    K, n = moved.shape
    for i in range(n):
        t = 0.0
        for k in range(K):
            t += moved[k, i]
        x_out[i] = t / K
    for i in range(n):
        for j in range(i, n):
            t = 0.0
            for k in range(K):
                t += (moved[k, i] - x_out[i]) * (moved[k, j] - x_out[j])
            t = t / K + 0.5 * (Q[i, j] + Q[j, i])
            P_out[i, j] = t
            P_out[j, i] = t


@numba.njit(**JIT)
def measurement_update(x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nu, S, weights, z_centre=None) -> float:
    """Measurement update of one filter from its cubature points (K, n) of (x, P) and their
    predicted measurements Z (K, m); returns the innovation negative log-likelihood (NaN if
    the innovation covariance is not positive definite).

    Writes the state and covariance (x_out, P_out), the innovation nu (m,) (zero on channels
    with ``valid`` False, which carry no information: variance 1e12), its covariance S (m, m)
    and the Huber weights (m,). Robust (finite ``huber_c``): standardised innovations
    r_i = nu_i / sqrt(S_ii) give Huber weights w_i = min(1, c / |r_i|) (eq. 27); the noise is
    inflated to R_ij / sqrt(w_i w_j) (the equivalent-weight form R_bar = P_bar^-1 of eq. 28-29;
    the paper's printed indices slip) and the update redone.

    ``z_centre`` (m,), where given: the model's measurement at the mean x itself, which the
    innovation takes instead of the points' mean (their spread still gives S and the gain).
    Where the model is curved and the update repeats on the same information, the points' mean
    sits off the model at x by the curvature times P / 2 every step, and the update walks the
    state along it (the friction filter's climb in a steady turn,
    docs/decisions/0045-friction-and-sideslip-consistency.md)."""
    K, n = points.shape
    m = z.shape[0]
    z_mean = scratch((m,))
    for i in range(m):
        t = 0.0
        for k in range(K):
            t += Z[k, i]
        z_mean[i] = t / K
    Pzz = scratch((m, m))
    for i in range(m):
        for j in range(i, m):
            t = 0.0
            for k in range(K):
                t += (Z[k, i] - z_mean[i]) * (Z[k, j] - z_mean[j])
            Pzz[i, j] = t / K
            Pzz[j, i] = t / K
    Pxz = scratch((n, m))
    for i in range(n):
        for j in range(m):
            t = 0.0
            for k in range(K):
                t += (points[k, i] - x[i]) * (Z[k, j] - z_mean[j])
            Pxz[i, j] = t / K
    Rv = scratch((m, m))
    if z_centre is None:
        m_valid = innovation(z, z_mean, valid, R, nu, Rv)
    else:
        m_valid = innovation(z, z_centre, valid, R, nu, Rv)
    weights[:] = 1.0
    if huber_c < math.inf:
        for i in range(m):
            a = abs(nu[i]) / math.sqrt(Pzz[i, i] + Rv[i, i])
            weights[i] = 1.0 if a <= huber_c else huber_c / max(a, 1e-300)
        for i in range(m):
            for j in range(m):
                Rv[i, j] /= math.sqrt(weights[i] * weights[j])
    for i in range(m):
        for j in range(m):
            S[i, j] = Pzz[i, j] + 0.5 * (Rv[i, j] + Rv[j, i])
    L = scratch((m, m))
    if not cholesky(S, L):
        return math.nan
    gain = scratch((n, m))  # K = Pxz S^-1, row by row
    for i in range(n):
        cholesky_solve(L, Pxz[i], gain[i])
    for i in range(n):
        t = x[i]
        for j in range(m):
            t += gain[i, j] * nu[j]
        x_out[i] = t
    KS = scratch((n, m))
    for i in range(n):
        for j in range(m):
            t = 0.0
            for k in range(m):
                t += gain[i, k] * S[k, j]
            KS[i, j] = t
    for i in range(n):
        for j in range(i, n):
            t = 0.0
            for k in range(m):
                t += KS[i, k] * gain[j, k]
            value = 0.5 * (P[i, j] + P[j, i]) - t
            P_out[i, j] = value
            P_out[j, i] = value
    return innovation_nll(L, nu, m_valid)


@numba.njit(inline="always", **JIT)
def innovation(
    z: np.ndarray, z_pred: np.ndarray, valid: np.ndarray, R: np.ndarray, nu: np.ndarray, Rv: np.ndarray
) -> int:
    """The innovation nu = z - z_pred (m,) and its noise Rv (m, m) = R, zero and the dropout
    variance (no information) on channels with ``valid`` False; returns the valid count."""
    m = z.shape[0]
    m_valid = 0
    for i in range(m):
        nu[i] = z[i] - z_pred[i] if valid[i] else 0.0
        m_valid += 1 if valid[i] else 0
        for j in range(m):
            Rv[i, j] = R[i, j]
        if not valid[i]:
            Rv[i, i] = DROPOUT_VARIANCE
    return m_valid


@numba.njit(inline="always", **JIT)
def innovation_nll(L: np.ndarray, nu: np.ndarray, m_valid: int) -> float:
    """Gaussian negative log-likelihood of the innovation nu (m,) with covariance S = L L^T
    (L: its Cholesky factor), over the m_valid channels that carry information (the others
    have nu = 0 and the dropout variance, whose log det is taken out again)."""
    m = nu.shape[0]
    white = scratch((m,))  # L^-1 nu: maha = |white|^2
    log_det = 0.0
    for i in range(m):
        t = nu[i]
        for k in range(i):
            t -= L[i, k] * white[k]
        white[i] = t / L[i, i]
        log_det += 2.0 * math.log(L[i, i])
    maha = 0.0
    for i in range(m):
        maha += white[i] * white[i]
    log_det -= math.log(DROPOUT_VARIANCE) * (m - m_valid)
    return 0.5 * (maha + log_det + m_valid * math.log(2.0 * math.pi))


@numba.njit(**JIT)
def normalised_innovation(nu: np.ndarray, S: np.ndarray, valid: np.ndarray) -> tuple[float, int]:
    """(NIS, valid channels): nu^T S^-1 nu of the innovation nu (m,) with covariance S (m, m)
    over the channels that are ``valid`` (m,) (the others carry the dropout variance and nu = 0,
    so they add nothing), and how many those are; (NaN, 0) if S is not positive definite. A
    consistent filter's NIS follows chi-square with that many degrees of freedom."""
    m = nu.shape[0]
    L = scratch((m, m))
    if not cholesky(S, L):
        return math.nan, 0
    white = scratch((m,))
    nis = 0.0
    for i in range(m):
        t = nu[i]
        for k in range(i):
            t -= L[i, k] * white[k]
        white[i] = t / L[i, i]
        nis += white[i] * white[i]
    count = 0
    for i in range(m):
        count += 1 if valid[i] else 0
    return nis, count


# ---- batched entry points from Python ----------------------------------------------------
@numba.njit(**JIT)
def _points_batch(x, P, points, ok):
    for b in range(x.shape[0]):
        ok[b] = cubature_points(x[b], P[b], points[b])


@numba.njit(**JIT)
def _moments_batch(moved, Q, x_out, P_out):
    for b in range(moved.shape[0]):
        predicted_moments(moved[b], Q[b], x_out[b], P_out[b])


@numba.njit(**JIT)
def _update_batch(x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nu, S, weights, nll):
    for b in range(x.shape[0]):
        nll[b] = measurement_update(
            x[b], P[b], points[b], Z[b], z[b], valid[b], R[b], huber_c, x_out[b], P_out[b], nu[b], S[b], weights[b]
        )


def batch_arrays(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x (B, n) and P (B, n, n) as contiguous float64, checked: shapes, a finite x, and P a
    covariance (:func:`noise_matrix`; the compiled steps only jitter away rounding)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    P = np.ascontiguousarray(P, dtype=np.float64)
    if x.ndim != 2 or P.shape != x.shape + x.shape[-1:]:
        raise ValueError(f"state must have shape (B, n) and covariance (B, n, n), got {x.shape} and {P.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"state must be finite, got {x!r}")
    return x, noise_matrix(P, P.shape, "covariance P")


def noise_matrix(M: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    """A noise covariance (k, k) or (B, k, k) as a contiguous (B, k, k) float64 array (``shape``),
    checked: finite, symmetric and positive semi-definite (ValueError naming ``name`` otherwise)."""
    given = np.asarray(M, dtype=np.float64)
    if given.shape not in (shape[-2:], (1, *shape[-2:]), shape):
        raise ValueError(f"{name} must have shape {shape[-2:]} or {shape}, got {given.shape}")
    if not np.all(np.isfinite(given)):
        raise ValueError(f"{name} must be finite, got {given!r}")
    scale = max(float(np.abs(given).max()), 1e-300)
    if (
        float(np.abs(given - np.swapaxes(given, -1, -2)).max()) > 1e-12 * scale
        or np.linalg.eigvalsh(given).min() < -1e-12 * scale
    ):
        raise ValueError(f"{name} must be a symmetric positive semi-definite covariance, got {given!r}")
    return np.ascontiguousarray(np.broadcast_to(given, shape))


def check_huber(huber_c: float | None) -> float:
    """The Huber threshold as the compiled update takes it: None (plain update) or a number > 0."""
    if huber_c is None:
        return NO_HUBER
    if not float(huber_c) > 0.0:
        raise ValueError(f"huber_c must be > 0 (or None for the plain update), got {huber_c!r}")
    return float(huber_c)


def batch_points(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """The cubature points (B, 2n, n) of a batch x (B, n), P (B, n, n)."""
    points, ok = np.empty((x.shape[0], 2 * x.shape[1], x.shape[1])), np.empty(len(x), dtype=np.bool_)
    _points_batch(x, P, points, ok)
    if not ok.all():
        raise ValueError(f"covariance of member {int(np.argmin(ok))} is not finite or not positive definite")
    return points


def _model_values(fn, points: np.ndarray, width: int | None = None) -> np.ndarray:
    values = np.ascontiguousarray(fn(points), dtype=np.float64)
    if values.ndim != 3 or values.shape[:2] != points.shape[:2] or (width is not None and values.shape[2] != width):
        raise ValueError(f"the model must map points {points.shape} to (B, K, k), got {values.shape}")
    if not np.all(np.isfinite(values)):
        raise ValueError("the model returned NaN or inf at a cubature point")
    return values


def ckf_predict(x: np.ndarray, P: np.ndarray, f, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time update of a batch: x (B, n), P and Q (B, n, n) (Q may be (n, n)); ``f`` maps point
    sets (B, 2n, n) to (B, 2n, n). Returns (x_pred, P_pred)."""
    x, P = batch_arrays(x, P)
    moved = _model_values(f, batch_points(x, P), x.shape[1])
    x_out, P_out = np.empty_like(x), np.empty_like(P)
    _moments_batch(moved, noise_matrix(Q, P.shape, "Q"), x_out, P_out)
    return x_out, P_out


class CKFUpdate(NamedTuple):
    """Measurement update result: state x (B, n) and P (B, n, n), innovation (B, m), its
    covariance S (B, m, m), Huber weights (B, m) and innovation negative log-likelihood (B,)."""

    x: np.ndarray
    P: np.ndarray
    innovation: np.ndarray
    innovation_cov: np.ndarray
    weights: np.ndarray
    nll: np.ndarray


def ckf_update(
    x: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
    h,
    R: np.ndarray,
    huber_c: float | None = None,
    valid: np.ndarray | None = None,
) -> CKFUpdate:
    """Measurement update of a batch (see :func:`measurement_update`) with fresh cubature points
    of (x, P): z (B, m), ``h`` maps point sets (B, 2n, n) to (B, 2n, m), R (m, m) or (B, m, m),
    ``huber_c`` None for the plain update, ``valid`` (B, m) bool (default all valid)."""
    x, P = batch_arrays(x, P)
    z = np.ascontiguousarray(z, dtype=np.float64)
    if z.ndim != 2 or z.shape[0] != x.shape[0]:
        raise ValueError(f"measurement must have shape (B, m) with B = {x.shape[0]}, got {z.shape}")
    valid = np.ones(z.shape, dtype=np.bool_) if valid is None else np.ascontiguousarray(valid, dtype=np.bool_)
    if valid.shape != z.shape:
        raise ValueError(f"valid must have the measurement's shape {z.shape}, got {valid.shape}")
    if not np.all(np.isfinite(z[valid])):
        raise ValueError("a valid measurement is NaN or inf")
    B, m = z.shape
    points = batch_points(x, P)
    Z = _model_values(h, points, m)
    x_out, P_out = np.empty_like(x), np.empty_like(P)
    nu, S, weights, nll = np.empty((B, m)), np.empty((B, m, m)), np.empty((B, m)), np.empty(B)
    _update_batch(
        x,
        P,
        points,
        Z,
        z,
        valid,
        noise_matrix(R, (B, m, m), "R"),
        check_huber(huber_c),
        x_out,
        P_out,
        nu,
        S,
        weights,
        nll,
    )
    if not np.all(np.isfinite(nll)):
        raise ValueError(
            f"update of member {int(np.argmin(np.isfinite(nll)))} failed: innovation covariance not positive definite"
        )
    return CKFUpdate(x_out, P_out, nu, S, weights, nll)

"""The cubature Kalman filter's arithmetic over a block of cars in SIMD lanes.

Each function here runs one filter operation for ``lanes`` cars at once: a car is a lane, the
lane axis is the last axis of every array (a vector (n, lanes), a matrix (n, n, lanes), cubature
points (K, n, lanes)), and every loop over lanes is innermost, branch-free and call-free, so that
LLVM runs it in packed vector instructions (docs/decisions/0005-plant-polynomial-math-in-simd-lanes.md
gives the rules, docs/decisions/0046-lane-estimator.md the measurements). The sizes
``n``, ``m`` and ``lanes`` are compile-time constants where the callers pass them as literals or
module constants: the loops then have constant trip counts and the work arrays
(:func:`fourwis.core.kernels.scratch`) sit on the stack at their exact size.

Each lane runs the very operations, in the very order, of the single-car filter (estimation/ckf.py,
estimation/federated.py), so its results are equal bit for bit; a lane whose Cholesky factor fails
is redone alone through the single-car fallback (the diagonal jitter of
:func:`fourwis.estimation.ckf.covariance_sqrt`). Where a lane's filter fails, its ``ok`` flag
(lanes,) turns False and its outputs are not to be used.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from fourwis.core.kernels import JIT, scratch
from fourwis.core.vecmath import sqrt
from fourwis.estimation.ckf import DROPOUT_VARIANCE, covariance_sqrt
from fourwis.estimation.federated import BETA_FLOOR


@numba.njit(inline="always", **JIT)
def cholesky_lanes(A, out, ok, n, lanes) -> None:
    """Lower Cholesky factor of each lane's symmetrised A (n, n, lanes), 0.5 (A + A^T), into out
    (n, n, lanes); ok (lanes,) False where it is not numerically positive definite (or not finite),
    and that lane's factor is not to be used. :func:`fourwis.estimation.ckf.cholesky` lane by lane."""
    for i in range(n):
        for j in range(n):
            for lane in range(lanes):
                out[i, j, lane] = 0.0
    for lane in range(lanes):
        ok[lane] = True
    s, t = scratch((lanes,)), scratch((lanes,))
    for j in range(n):
        for lane in range(lanes):
            s[lane] = A[j, j, lane]
        for k in range(j):
            for lane in range(lanes):
                s[lane] -= out[j, k, lane] * out[j, k, lane]
        for lane in range(lanes):
            good = s[lane] > 0.0 and s[lane] < math.inf
            ok[lane] = ok[lane] and good
            out[j, j, lane] = sqrt(s[lane]) if good else 1.0
        for i in range(j + 1, n):
            for lane in range(lanes):
                t[lane] = 0.5 * (A[i, j, lane] + A[j, i, lane])
            for k in range(j):
                for lane in range(lanes):
                    t[lane] -= out[i, k, lane] * out[j, k, lane]
            for lane in range(lanes):
                out[i, j, lane] = t[lane] / out[j, j, lane]


@numba.njit(**JIT)
def _jittered_lane(P, S, lane, n) -> bool:
    """Lane ``lane``'s factor of P (n, n, lanes) into S through the single-car
    :func:`fourwis.estimation.ckf.covariance_sqrt` (its diagonal jitter); False if that fails."""
    P1, S1 = scratch((n, n)), scratch((n, n))
    for i in range(n):
        for j in range(n):
            P1[i, j] = P[i, j, lane]
    if not covariance_sqrt(P1, S1):
        return False
    for i in range(n):
        for j in range(n):
            S[i, j, lane] = S1[i, j]
    return True


@numba.njit(inline="always", **JIT)
def covariance_sqrt_lanes(P, S, ok, n, lanes) -> None:
    """:func:`fourwis.estimation.ckf.covariance_sqrt` of each lane of P (n, n, lanes) into S;
    ok (lanes,) False where it fails."""
    cholesky_lanes(P, S, ok, n, lanes)
    for lane in range(lanes):
        if not ok[lane]:
            ok[lane] = _jittered_lane(P, S, lane, n)


@numba.njit(inline="always", **JIT)
def cubature_points_lanes(x, P, points, ok, n, lanes) -> None:
    """The 2n third-degree spherical-radial points x +/- sqrt(n) S e_j of each lane of x (n, lanes)
    and P (n, n, lanes) into points (2n, n, lanes); ok (lanes,) False where P has no factor."""
    S = scratch((n, n, lanes))
    covariance_sqrt_lanes(P, S, ok, n, lanes)
    c = math.sqrt(n)
    for k in range(n):
        for i in range(n):
            for lane in range(lanes):
                points[k, i, lane] = x[i, lane] + c * S[i, k, lane]
                points[n + k, i, lane] = x[i, lane] - c * S[i, k, lane]


@numba.njit(inline="always", **JIT)
def predicted_moments_lanes(moved, Q, x_out, P_out, n, lanes) -> None:
    """Time update of each lane from its propagated cubature points moved (K, n, lanes): their
    mean, and their covariance plus Q (n, n, lanes), into x_out (n, lanes), P_out (n, n, lanes)."""
    K = moved.shape[0]
    t = scratch((lanes,))
    for i in range(n):
        for lane in range(lanes):
            t[lane] = 0.0
        for k in range(K):
            for lane in range(lanes):
                t[lane] += moved[k, i, lane]
        for lane in range(lanes):
            x_out[i, lane] = t[lane] / K
    for i in range(n):
        for j in range(i, n):
            for lane in range(lanes):
                t[lane] = 0.0
            for k in range(K):
                for lane in range(lanes):
                    t[lane] += (moved[k, i, lane] - x_out[i, lane]) * (moved[k, j, lane] - x_out[j, lane])
            for lane in range(lanes):
                value = t[lane] / K + 0.5 * (Q[i, j, lane] + Q[j, i, lane])
                P_out[i, j, lane] = value
                P_out[j, i, lane] = value


@numba.njit(inline="always", **JIT)
def _points_mean(Z, out, m, lanes) -> None:
    """The mean over the points of Z (K, m, lanes) into out (m, lanes)."""
    K = Z.shape[0]
    t = scratch((lanes,))
    for i in range(m):
        for lane in range(lanes):
            t[lane] = 0.0
        for k in range(K):
            for lane in range(lanes):
                t[lane] += Z[k, i, lane]
        for lane in range(lanes):
            out[i, lane] = t[lane] / K


@numba.njit(**JIT)
def measurement_update_lanes(
    x, P, points, Z, z, valid, R, huber_c, x_out, P_out, nll, ok, n, m, lanes, nu, S, z_centre=None
) -> None:
    """:func:`fourwis.estimation.ckf.measurement_update` of each lane: from the cubature points
    (K, n, lanes) of x (n, lanes), P (n, n, lanes) and their predicted measurements Z (K, m, lanes),
    the measurement z (m, lanes), valid (m, lanes) bool and noise R (m, m, lanes), with the Huber
    threshold ``huber_c`` (inf: plain update), into x_out, P_out, the innovation nu (m, lanes) and
    its covariance S (m, m, lanes); each lane's innovation negative log-likelihood into nll
    (lanes,) and ok (lanes,) False where the innovation covariance is not positive definite (nll
    NaN). ``z_centre`` (m, lanes), where given: the innovation against it instead of the points'
    mean (the single-car ``z_centre``)."""
    K = points.shape[0]
    t = scratch((lanes,))
    z_mean = scratch((m, lanes))
    _points_mean(Z, z_mean, m, lanes)
    Pzz = scratch((m, m, lanes))
    for i in range(m):
        for j in range(i, m):
            for lane in range(lanes):
                t[lane] = 0.0
            for k in range(K):
                for lane in range(lanes):
                    t[lane] += (Z[k, i, lane] - z_mean[i, lane]) * (Z[k, j, lane] - z_mean[j, lane])
            for lane in range(lanes):
                Pzz[i, j, lane] = t[lane] / K
                Pzz[j, i, lane] = t[lane] / K
    Pxz = scratch((n, m, lanes))
    for i in range(n):
        for j in range(m):
            for lane in range(lanes):
                t[lane] = 0.0
            for k in range(K):
                for lane in range(lanes):
                    t[lane] += (points[k, i, lane] - x[i, lane]) * (Z[k, j, lane] - z_mean[j, lane])
            for lane in range(lanes):
                Pxz[i, j, lane] = t[lane] / K
    # the innovation and its noise (ckf.innovation): no information on invalid channels
    Rv, m_valid = scratch((m, m, lanes)), scratch((lanes,))
    if z_centre is not None:
        for i in range(m):
            for lane in range(lanes):
                z_mean[i, lane] = z_centre[i, lane]  # (Pzz and Pxz are taken: the centre is the innovation's only)
    for lane in range(lanes):
        m_valid[lane] = 0.0
    for i in range(m):
        for lane in range(lanes):
            nu[i, lane] = z[i, lane] - z_mean[i, lane] if valid[i, lane] else 0.0
            m_valid[lane] += 1.0 if valid[i, lane] else 0.0
        for j in range(m):
            for lane in range(lanes):
                Rv[i, j, lane] = R[i, j, lane]
        for lane in range(lanes):
            Rv[i, i, lane] = Rv[i, i, lane] if valid[i, lane] else DROPOUT_VARIANCE
    if huber_c < math.inf:  # Huber weights (eq. 27), the noise inflated by them
        weights = scratch((m, lanes))
        for i in range(m):
            for lane in range(lanes):
                a = abs(nu[i, lane]) / sqrt(Pzz[i, i, lane] + Rv[i, i, lane])
                weights[i, lane] = 1.0 if a <= huber_c else huber_c / max(a, 1e-300)
        for i in range(m):
            for j in range(m):
                for lane in range(lanes):
                    Rv[i, j, lane] /= sqrt(weights[i, lane] * weights[j, lane])
    for i in range(m):
        for j in range(m):
            for lane in range(lanes):
                S[i, j, lane] = Pzz[i, j, lane] + 0.5 * (Rv[i, j, lane] + Rv[j, i, lane])
    Lc = scratch((m, m, lanes))
    cholesky_lanes(S, Lc, ok, m, lanes)
    gain = scratch((n, m, lanes))  # K = Pxz S^-1, row by row (ckf.cholesky_solve)
    for i in range(n):
        for a in range(m):
            for lane in range(lanes):
                t[lane] = Pxz[i, a, lane]
            for k in range(a):
                for lane in range(lanes):
                    t[lane] -= Lc[a, k, lane] * gain[i, k, lane]
            for lane in range(lanes):
                gain[i, a, lane] = t[lane] / Lc[a, a, lane]
        for a in range(m - 1, -1, -1):
            for lane in range(lanes):
                t[lane] = gain[i, a, lane]
            for k in range(a + 1, m):
                for lane in range(lanes):
                    t[lane] -= Lc[k, a, lane] * gain[i, k, lane]
            for lane in range(lanes):
                gain[i, a, lane] = t[lane] / Lc[a, a, lane]
    for i in range(n):
        for lane in range(lanes):
            t[lane] = x[i, lane]
        for j in range(m):
            for lane in range(lanes):
                t[lane] += gain[i, j, lane] * nu[j, lane]
        for lane in range(lanes):
            x_out[i, lane] = t[lane]
    KS = scratch((n, m, lanes))
    for i in range(n):
        for j in range(m):
            for lane in range(lanes):
                t[lane] = 0.0
            for k in range(m):
                for lane in range(lanes):
                    t[lane] += gain[i, k, lane] * S[k, j, lane]
            for lane in range(lanes):
                KS[i, j, lane] = t[lane]
    for i in range(n):
        for j in range(i, n):
            for lane in range(lanes):
                t[lane] = 0.0
            for k in range(m):
                for lane in range(lanes):
                    t[lane] += KS[i, k, lane] * gain[j, k, lane]
            for lane in range(lanes):
                value = 0.5 * (P[i, j, lane] + P[j, i, lane]) - t[lane]
                P_out[i, j, lane] = value
                P_out[j, i, lane] = value
    innovation_nll_lanes(Lc, nu, m_valid, ok, nll, m, lanes)


@numba.njit(inline="always", **JIT)
def innovation_nll_lanes(Lc, nu, m_valid, ok, nll, m, lanes) -> None:
    """:func:`fourwis.estimation.ckf.innovation_nll` of each lane, from the factor Lc (m, m, lanes)
    of S, the innovation nu (m, lanes) and the count of valid channels m_valid (lanes,) (a float),
    into nll (lanes,); NaN where ``ok`` (lanes,) is False."""
    white, maha = scratch((m, lanes)), scratch((lanes,))
    for lane in range(lanes):
        maha[lane] = 0.0
    for i in range(m):
        for lane in range(lanes):
            white[i, lane] = nu[i, lane]
        for k in range(i):
            for lane in range(lanes):
                white[i, lane] -= Lc[i, k, lane] * white[k, lane]
        for lane in range(lanes):
            white[i, lane] = white[i, lane] / Lc[i, i, lane]
    for i in range(m):
        for lane in range(lanes):
            maha[lane] += white[i, lane] * white[i, lane]
    log_dropout, log_two_pi = math.log(DROPOUT_VARIANCE), math.log(2.0 * math.pi)
    for lane in range(lanes):  # (the C library's log: one call per channel, outside the vector loops)
        log_det = 0.0
        for i in range(m):
            log_det += 2.0 * math.log(Lc[i, i, lane])
        log_det -= log_dropout * (m - int(m_valid[lane]))
        value = 0.5 * (maha[lane] + log_det + int(m_valid[lane]) * log_two_pi)
        nll[lane] = value if ok[lane] else math.nan


@numba.njit(inline="always", **JIT)
def spd_inverse_lanes(A, out, ok, n, lanes) -> None:
    """:func:`fourwis.estimation.ckf.spd_inverse` of each lane of A (n, n, lanes) into out; ok
    (lanes,) False where A has no factor."""
    S = scratch((n, n, lanes))
    covariance_sqrt_lanes(A, S, ok, n, lanes)
    S_inv, t = scratch((n, n, lanes)), scratch((lanes,))
    for i in range(n):
        for j in range(n):
            for lane in range(lanes):
                S_inv[i, j, lane] = 0.0
    for c in range(n):  # the inverse of the lower-triangular S, column by column
        for i in range(c, n):
            for lane in range(lanes):
                t[lane] = 1.0 if i == c else 0.0
            for k in range(c, i):
                for lane in range(lanes):
                    t[lane] -= S[i, k, lane] * S_inv[k, c, lane]
            for lane in range(lanes):
                S_inv[i, c, lane] = t[lane] / S[i, i, lane]
    for i in range(n):
        for j in range(i, n):
            for lane in range(lanes):
                t[lane] = 0.0
            for k in range(n):
                for lane in range(lanes):
                    t[lane] += S_inv[k, i, lane] * S_inv[k, j, lane]
            for lane in range(lanes):
                out[i, j, lane] = t[lane]
                out[j, i, lane] = t[lane]


@numba.njit(**JIT)
def fuse_lanes(xs, Ps, x_out, P_out, confidence, ok, n, lanes) -> None:
    """:func:`fourwis.estimation.federated.fuse` of each lane: N estimates xs (N, n, lanes), Ps (N,
    n, n, lanes) into x_out (n, lanes), P_out (n, n, lanes), confidence (N, lanes) = trace(P_i^-1);
    ok (lanes,) False where a covariance has no factor."""
    N = xs.shape[0]
    info_sum, weighted, info = scratch((n, n, lanes)), scratch((n, lanes)), scratch((n, n, lanes))
    each_ok = scratch((lanes,), np.bool_)
    for lane in range(lanes):
        ok[lane] = True
    for i in range(n):
        for lane in range(lanes):
            weighted[i, lane] = 0.0
        for j in range(n):
            for lane in range(lanes):
                info_sum[i, j, lane] = 0.0
    for s in range(N):
        spd_inverse_lanes(Ps[s], info, each_ok, n, lanes)
        for lane in range(lanes):
            ok[lane] = ok[lane] and each_ok[lane]
            confidence[s, lane] = 0.0
        for i in range(n):
            for lane in range(lanes):
                confidence[s, lane] += info[i, i, lane]
        for i in range(n):
            for j in range(n):
                for lane in range(lanes):
                    info_sum[i, j, lane] += info[i, j, lane]
                    weighted[i, lane] += info[i, j, lane] * xs[s, j, lane]
    spd_inverse_lanes(info_sum, P_out, each_ok, n, lanes)
    t = scratch((lanes,))
    for i in range(n):
        for lane in range(lanes):
            t[lane] = 0.0
        for j in range(n):
            for lane in range(lanes):
                t[lane] += P_out[i, j, lane] * weighted[j, lane]
        for lane in range(lanes):
            x_out[i, lane] = t[lane]
            ok[lane] = ok[lane] and each_ok[lane]


@numba.njit(inline="always", **JIT)
def sharing_coefficients_lanes(confidence, beta, lanes) -> None:
    """:func:`fourwis.estimation.federated.sharing_coefficients` of each lane: beta (N, lanes)
    from confidence (N, lanes)."""
    N = beta.shape[0]
    t = scratch((lanes,))
    for lane in range(lanes):
        t[lane] = 0.0
    for s in range(N):
        for lane in range(lanes):
            t[lane] += confidence[s, lane]
    for s in range(N):
        for lane in range(lanes):
            beta[s, lane] = max(confidence[s, lane] / t[lane], BETA_FLOOR)
    for lane in range(lanes):
        t[lane] = 0.0
    for s in range(N):
        for lane in range(lanes):
            t[lane] += beta[s, lane]
    for s in range(N):
        for lane in range(lanes):
            beta[s, lane] /= t[lane]

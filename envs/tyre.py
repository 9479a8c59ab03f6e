"""Pacejka Magic Formula tyre (PAC2002 / MF 5.2 form), combined slip, load dependent.

Coefficients: the 185/80 R14 passenger tyre of project Chrono's VW microbus model
(``data/vehicle/VW_microbus/json/mf_185_80R14.tir``, PAC2002, dry road, 190 kPa).
At this car's static wheel load (~2.04 kN) it gives a lateral peak friction of 1.02,
a cornering stiffness of 32.0 kN/rad, a longitudinal peak of 1.13 and a slip stiffness
of 37.8 kN; relaxation lengths 0.39 m (longitudinal) and 0.36 m (lateral).

Deviations from the full MF 5.2, all deliberate:

* Camber is zero, and every left/right asymmetric term (PHX*, PVX*, PHY*, PVY*, PEY3,
  RHX1, RBY3, RHY*, RVY*: conicity, ply-steer, kappa-induced side force) is dropped, so
  the tyre, and therefore the car, is exactly mirror symmetric. PEX4 (drive/brake
  asymmetry) is kept: it does not break the left/right mirror.
* Road friction scales the peaks (``LMUX = LMUY = mu_road / mu_ref``), with ``mu_ref``
  the tyre's own peak coefficient at the reference load (the car's static wheel load),
  so that a wheel at its static load on a road of friction ``mu`` has peak force
  ``mu * Fz`` in both directions. Load sensitivity (PDX2, PDY2) still acts around it.
* The combined-slip weights G are floored at 0: MF 5.2's cosine weights turn slightly
  negative near 90 deg of slip, which no tyre does.
* The combined-slip weights take the slips normalised by the friction scales, kappa / LMUX
  and alpha / LMUY (the similarity method, Pacejka 2012, sec. 4.2: on a slippery road the
  slip stiffness stays and the peaks come at slips LMU times the dry road's). MF 5.2 weighs
  the raw slips, whose weights stay near 1 where a low-friction tyre already slides, so its
  resultant exceeds the road's friction; with the normalisation it stays within 1.04 mu Fz on
  every road (``tests/test_vehicle.py``; docs/decisions/0004-plant-tyre-similarity-combined-slip.md).
* Slip angle enters as ``atan(tan_alpha)``; ``tan_alpha`` is the relaxed lateral slip of
  the transient model in :mod:`envs.vehicle`, so the formula never sees a division by
  the wheel's forward speed.

Sign convention (ISO 8855, wheel frame): ``kappa > 0`` when driving, giving ``Fx > 0``;
``tan_alpha = v_cy / |v_cx|`` is the contact centre's lateral slip, and the lateral force
opposes it: ``Fy = -F(alpha)`` with ``F`` odd and increasing near zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np

from fourwis.core import vecmath
from fourwis.core.kernels import JIT


@dataclass(frozen=True)
class TyreParams:
    """Symmetric PAC2002 coefficient set (dimensionless unless stated)."""

    nominal_load: float = 3800.0  #: FNOMIN [N]
    unloaded_radius: float = 0.376  #: UNLOADED_RADIUS [m], only for relaxation lengths
    pcx1: float = 1.5587
    pdx1: float = 1.09
    pdx2: float = -0.079328
    pex1: float = 0.27403
    pex2: float = 0.10232
    pex3: float = 0.074903
    pex4: float = -0.00026944
    pkx1: float = 19.733
    pkx2: float = 0.093405
    pkx3: float = 0.12433
    rbx1: float = 14.927
    rbx2: float = -10.534
    rcx1: float = 1.1288
    rex1: float = 0.62334
    rex2: float = -0.0039079
    ptx1: float = 1.9021
    ptx2: float = -0.0014739
    ptx3: float = 0.03631
    pcy1: float = 1.4675
    pdy1: float = 0.94002
    pdy2: float = -0.17669
    pey1: float = 0.0040023
    pey2: float = 0.00085719
    pky1: float = 12.536  #: |PKY1|: the .tir stores -12.536 in its own sign convention
    pky2: float = 1.3856
    rby1: float = 5.5228
    rby2: float = 2.7966
    rcy1: float = 1.0783
    rey1: float = 0.055543
    rey2: float = -0.0022958
    pty1: float = 1.8473
    pty2: float = 1.9465

    def __post_init__(self) -> None:
        bad = [f.name for f in fields(self) if not math.isfinite(getattr(self, f.name))]
        if bad:
            raise ValueError(f"TyreParams {bad} must be finite")
        for name in ("nominal_load", "unloaded_radius", "pcx1", "pcy1", "pdx1", "pdy1", "pkx1", "pky1", "pky2"):
            if not getattr(self, name) > 0.0:  # divisors and the curves' sizes
                raise ValueError(f"TyreParams.{name} must be > 0, got {getattr(self, name)!r}")

    @cached_property
    def kernel(self) -> TyreCoefficients:
        """These coefficients as the compiled tyre reads them (a value: numba keeps it in registers)."""
        return TyreCoefficients(*(float(getattr(self, f.name)) for f in fields(self)))

    def peak_friction(self, fz: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unscaled (mu_road = mu_ref) peak coefficients (mu_x, mu_y) at load ``fz`` [N]."""
        dfz = (np.asarray(fz, dtype=float) - self.nominal_load) / self.nominal_load
        return self.pdx1 + self.pdx2 * dfz, self.pdy1 + self.pdy2 * dfz

    def cornering_stiffness(self, fz: float | np.ndarray) -> np.ndarray:
        """Lateral slip stiffness dFy/dalpha at zero slip [N/rad] for load ``fz`` [N]."""
        x = np.asarray(fz, dtype=float) / (self.pky2 * self.nominal_load)
        return self.pky1 * self.nominal_load * 2.0 * x / (1.0 + x * x)

    def slip_stiffness(self, fz: float | np.ndarray) -> np.ndarray:
        """Longitudinal slip stiffness dFx/dkappa at zero slip [N] for load ``fz`` [N]."""
        fz = np.asarray(fz, dtype=float)
        dfz = (fz - self.nominal_load) / self.nominal_load
        return fz * (self.pkx1 + self.pkx2 * dfz) * np.exp(self.pkx3 * dfz)


#: :class:`TyreParams` as the compiled tyre reads it (:attr:`TyreParams.kernel`): the same fields (floats)
TyreCoefficients = NamedTuple("TyreCoefficients", [(f.name, float) for f in fields(TyreParams)])


@numba.njit(inline="always", **JIT)
def _magic(b: float, c: float, d: float, e: float, x: float) -> float:
    bx = b * x
    return d * vecmath.sin(c * vecmath.atan(bx - e * (bx - vecmath.atan(bx))))


@numba.njit(inline="always", **JIT)
def _weight(b: float, c: float, e: float, x: float) -> float:
    bx = b * x
    return max(vecmath.cos(c * vecmath.atan(bx - e * (bx - vecmath.atan(bx)))), 0.0)


@numba.njit(**JIT)
def combined_forces(
    tp: TyreCoefficients,
    fz: np.ndarray,
    kappa: np.ndarray,
    tan_alpha: np.ndarray,
    scale_x: np.ndarray,
    scale_y: np.ndarray,
    fx: np.ndarray,
    fy: np.ndarray,
) -> None:
    """Tyre forces (Fx, Fy) [N] in the wheel frame of ``n`` wheels, written to ``fx``, ``fy`` (n,).

    ``tp``: :attr:`TyreParams.kernel`; ``fz`` > 0 [N]; ``kappa`` longitudinal slip [-];
    ``tan_alpha`` lateral slip (tangent of the slip angle) [-]; ``scale_x/y``: LMUX, LMUY; all (n,).
    One branch-free loop over the wheels (:mod:`fourwis.core.vecmath`) that LLVM vectorises. The
    formula is written in the loop body on purpose: in an inlined per-wheel function the loop is
    not vectorised (docs/decisions/0005-plant-polynomial-math-in-simd-lanes.md).
    """
    fz0 = tp.nominal_load
    for i in range(fz.size):
        dfz = (fz[i] - fz0) / fz0
        alpha = vecmath.atan(tan_alpha[i])
        # pure longitudinal
        cx = tp.pcx1
        dx = (tp.pdx1 + tp.pdx2 * dfz) * scale_x[i] * fz[i]
        kx = fz[i] * (tp.pkx1 + tp.pkx2 * dfz) * vecmath.exp(tp.pkx3 * dfz)
        sgn_k = 1.0 if kappa[i] >= 0.0 else -1.0
        ex = (tp.pex1 + tp.pex2 * dfz + tp.pex3 * dfz * dfz) * (1.0 - tp.pex4 * sgn_k)
        ex = min(ex, 1.0)
        fx0 = _magic(kx / (cx * dx), cx, dx, ex, kappa[i])
        # pure lateral (odd in alpha)
        cy = tp.pcy1
        dy = (tp.pdy1 + tp.pdy2 * dfz) * scale_y[i] * fz[i]
        xr = fz[i] / (tp.pky2 * fz0)
        ky = tp.pky1 * fz0 * 2.0 * xr / (1.0 + xr * xr)
        ey = min(tp.pey1 + tp.pey2 * dfz, 1.0)
        fy0 = _magic(ky / (cy * dy), cy, dy, ey, alpha)
        # combined slip weights, of the slips normalised by the friction scales (the
        # similarity method): the peaks come at slips ~scale times the tyre file's
        kappa_n = kappa[i] / scale_x[i]
        alpha_n = alpha / scale_y[i]
        rbx_kappa = tp.rbx2 * kappa_n
        bxa = tp.rbx1 / vecmath.sqrt(1.0 + rbx_kappa * rbx_kappa)
        gxa = _weight(bxa, tp.rcx1, tp.rex1 + tp.rex2 * dfz, alpha_n)
        rby_alpha = tp.rby2 * alpha_n
        byk = tp.rby1 / vecmath.sqrt(1.0 + rby_alpha * rby_alpha)
        gyk = _weight(byk, tp.rcy1, tp.rey1 + tp.rey2 * dfz, kappa_n)
        fx[i] = gxa * fx0
        fy[i] = -gyk * fy0


@numba.njit(inline="always", **JIT)
def relaxation_lengths(tp: TyreCoefficients, fz: float) -> tuple[float, float]:
    """PAC2002 relaxation lengths (sigma_kappa, sigma_alpha) [m] at load ``fz`` [N]."""
    fz0 = tp.nominal_load
    r0 = tp.unloaded_radius
    dfz = (fz - fz0) / fz0
    sig_k = fz * (tp.ptx1 + tp.ptx2 * dfz) * vecmath.exp(-tp.ptx3 * dfz) * r0 / fz0
    xr = fz / (tp.pty2 * fz0)
    sig_a = tp.pty1 * 2.0 * xr / (1.0 + xr * xr) * r0
    return sig_k, sig_a


def tyre_forces(tyre: TyreParams, fz, kappa, tan_alpha, mu_road=1.0, reference_load: float | None = None):
    """Vectorised (Fx, Fy) [N] over broadcast arrays: a convenience for fitting and plots.

    ``mu_road`` scales the peaks relative to ``reference_load`` [N] (default: nominal load).
    """
    fz, kappa, tan_alpha, mu_road = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (fz, kappa, tan_alpha, mu_road))
    )
    if not np.all(fz > 0.0):
        raise ValueError(f"tyre load must be > 0 N, got min {fz.min()!r}")
    good = np.isfinite(mu_road) & (mu_road > 0.0)
    if not np.all(good):
        raise ValueError(f"mu_road must be finite and > 0, got {mu_road[~good][:4]}")
    ref = tyre.nominal_load if reference_load is None else reference_load
    mux_ref, muy_ref = tyre.peak_friction(ref)
    fx = np.empty(fz.size)
    fy = np.empty(fz.size)
    combined_forces(
        tyre.kernel,
        fz.ravel(),
        kappa.ravel(),
        tan_alpha.ravel(),
        (mu_road / mux_ref).ravel(),
        (mu_road / muy_ref).ravel(),
        fx,
        fy,
    )
    return fx.reshape(fz.shape), fy.reshape(fz.shape)

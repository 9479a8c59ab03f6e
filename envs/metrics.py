"""Stability metrics as pure functions on uniformly sampled time series (SI units).

FMVSS 126 (49 CFR 571.126, S7) / UN R13-H Annex 9 / GTR 8 sine-with-dwell evaluation, the
ISO 3888 cone and path measures, and generic ones (peak sideslip, tracking RMS, spin-out,
the paper's Table 2 RMSE/MAE).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

STEERING_CUTOFF = 10.0  #: FMVSS 126 S7.11.2: steering filter cutoff [Hz]
RESPONSE_CUTOFF = 6.0  #: yaw rate and lateral acceleration filter cutoff [Hz]
ZEROING_RATE = math.radians(75.0)  #: steering rate that opens the manoeuvre [rad/s]
ZEROING_HOLD = 0.2  #: ... for at least this long [s]
BOS_ANGLE = math.radians(5.0)  #: beginning of steer threshold [rad]
YAW_RATIO_1000 = 0.35  #: S5.2.1 limit at COS + 1.000 s
YAW_RATIO_1750 = 0.20  #: S5.2.2 limit at COS + 1.750 s
DISPLACEMENT_TIME = 1.07  #: S5.2.3: lateral displacement measured at BOS + 1.07 s
DISPLACEMENT_LIMIT = 1.83  #: [m] for vehicles with GVWR <= 3500 kg
SPIN_OUT_SIDESLIP = math.radians(20.0)  #: |beta| above this counts as a spin-out [rad]


def _series(name: str, x, n: int | None = None) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"{name} must be a 1-D time series, got shape {x.shape}")
    if n is not None and len(x) != n:
        raise ValueError(f"{name} has {len(x)} samples, expected {n}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains NaN or inf")
    return x


def _sample_rate(t: np.ndarray) -> float:
    if len(t) < 16:
        raise ValueError(f"time series too short: {len(t)} samples")
    dt = np.diff(t)
    if np.any(dt <= 0) or np.ptp(dt) > 1e-6 * dt.mean() + 1e-12:
        raise ValueError("time must be uniformly sampled and increasing")
    return 1.0 / dt.mean()


def phaseless_butterworth(x: np.ndarray, fs: float, cutoff: float, order: int = 12) -> np.ndarray:
    """Zero-phase Butterworth low-pass of total ``order`` poles at ``cutoff`` [Hz], sample rate ``fs`` [Hz].

    The regulation's "12-pole phaseless Butterworth" is a 6-pole filter run forwards and
    backwards (``sosfiltfilt``), which doubles the order and cancels the phase; its gain at
    the cutoff is then 0.5 (-6 dB)."""
    if order % 2 or order < 2:
        raise ValueError(f"order must be even (forward-backward), got {order!r}")
    if not 0 < cutoff < fs / 2:
        raise ValueError(f"cutoff {cutoff!r} Hz must lie in (0, fs/2 = {fs / 2})")
    sos = butter(order // 2, cutoff, fs=fs, output="sos")
    return sosfiltfilt(sos, _series("signal", x))


@dataclass(frozen=True)
class SineWithDwellResult:
    """FMVSS 126 results of one sine-with-dwell run (angles [rad], rates [rad/s], times [s])."""

    steering_amplitude: float
    bos_time: float
    cos_time: float
    first_peak_yaw_rate: float
    yaw_rate_ratio_1000: float
    yaw_rate_ratio_1750: float
    lateral_displacement: float
    passed_yaw: bool
    passed_responsiveness: bool | None
    spun_out: bool

    @property
    def passed(self) -> bool:
        """Both criteria that apply to this run (responsiveness only from 5A)."""
        return self.passed_yaw and self.passed_responsiveness is not False

    def as_dict(self) -> dict:
        return {**asdict(self), "passed": self.passed}


def _zeroing_start(t: np.ndarray, rate: np.ndarray) -> int:
    """Index where the steering rate first exceeds 75 deg/s and stays above it for 200 ms.

    At small amplitudes the first quarter-sine is too short for that: the rate of a 0.7 Hz
    sine of amplitude A stays above 75 deg/s for 200 ms only once A > ~31 deg, and below that
    the first 200 ms stretch is at the steering reversal, 0.7 s into the manoeuvre, which
    would put the zeroing range over the first half-wave. So a 200 ms stretch counts only if
    it starts within 0.1 s of the first time the rate exceeds 75 deg/s; otherwise that first
    time is taken. If the rate never exceeds 75 deg/s (A < 17 deg), the manoeuvre starts where
    the rate first exceeds 20% of its peak (within ~30 ms of the sine's start)."""
    dt = t[1] - t[0]
    hold = max(1, int(round(ZEROING_HOLD / dt)))
    fast = np.abs(rate) > ZEROING_RATE
    if not fast.any():
        return int(np.argmax(np.abs(rate) > 0.2 * np.abs(rate).max()))
    first = int(np.argmax(fast))
    run = np.convolve(fast.astype(int), np.ones(hold, dtype=int), mode="valid")
    full = np.flatnonzero(run == hold)
    if full.size and t[full[0]] - t[first] <= 0.1:
        return int(full[0])
    return first


def sine_with_dwell_metrics(t, steering_wheel_angle, yaw_rate, lateral_acceleration, sideslip=None,
                            A: float | None = None) -> SineWithDwellResult:
    """Evaluate one sine-with-dwell run (FMVSS 126 S7.9-S7.11).

    ``steering_wheel_angle`` [rad], ``yaw_rate`` [rad/s], ``lateral_acceleration`` [m/s^2] (body
    frame at the CG) sampled at times ``t`` [s]; ``A`` [rad]: the characterisation angle (0.3 g),
    needed for the responsiveness criterion (applies from 5A). ``sideslip`` [rad] (optional)
    flags a spin-out. Steps: filter (steering 10 Hz, responses 6 Hz, 12-pole phaseless);
    zero each signal by its mean over the 1 s before the manoeuvre starts; BOS: steering
    reaches 5 deg in the initial direction; COS: the steering returns to zero after the dwell
    (the last sign change of the steering, or where it is back within 0.5 deg); first peak
    yaw rate: the largest yaw rate of the dwell's sign between the steering reversal and COS
    + 1.75 s; ratios interpolated at COS + 1.000 s and COS + 1.750 s; lateral displacement:
    double integral of the zeroed lateral acceleration from BOS to BOS + 1.07 s, positive in
    the initial steering direction.
    """
    t = _series("t", t)
    n = len(t)
    fs = _sample_rate(t)
    steer = phaseless_butterworth(_series("steering_wheel_angle", steering_wheel_angle, n), fs, STEERING_CUTOFF)
    yaw = phaseless_butterworth(_series("yaw_rate", yaw_rate, n), fs, RESPONSE_CUTOFF)
    ay = phaseless_butterworth(_series("lateral_acceleration", lateral_acceleration, n), fs, RESPONSE_CUTOFF)
    start = _zeroing_start(t, np.gradient(steer, t))
    window = (t >= t[start] - 1.0) & (t < t[start])
    if window.sum() < 2:
        raise ValueError("the series needs at least 1 s of data before the steering starts")
    steer, yaw, ay = (x - x[window].mean() for x in (steer, yaw, ay))
    direction = float(np.sign(steer[np.argmax(np.abs(steer) > BOS_ANGLE)]))
    if direction == 0 or not np.any(np.abs(steer) > BOS_ANGLE):
        raise ValueError("steering never reaches 5 deg: not a sine-with-dwell run")
    amplitude = float(np.max(np.abs(steer)))
    i_bos = int(np.argmax(direction * steer >= BOS_ANGLE))
    bos = float(np.interp(BOS_ANGLE, direction * steer[i_bos - 1:i_bos + 1], t[i_bos - 1:i_bos + 1]))
    # steering reversal: the first crossing of zero towards the dwell side after BOS
    i_rev = i_bos + int(np.argmax(direction * steer[i_bos:] < 0))
    # COS: after the dwell peak the steering comes back towards zero
    i_dwell = i_rev + int(np.argmax(-direction * steer[i_rev:]))
    back = np.flatnonzero(-direction * steer[i_dwell:] <= math.radians(0.5))
    i_cos = i_dwell + int(back[0]) if back.size else n - 1
    cos_time = float(t[i_cos])
    if cos_time + 1.75 > t[-1]:
        raise ValueError(f"the series ends at {t[-1]:.2f} s, before COS + 1.75 s = {cos_time + 1.75:.2f} s")
    dwell_sign = -direction
    search = (t >= t[i_rev]) & (t <= cos_time + 1.75)
    peak = float(np.max(dwell_sign * yaw[search]))
    if peak <= 0:
        ratio_1000 = ratio_1750 = math.inf
    else:
        ratio_1000 = float(dwell_sign * np.interp(cos_time + 1.0, t, yaw) / peak)
        ratio_1750 = float(dwell_sign * np.interp(cos_time + 1.75, t, yaw) / peak)
    after = t >= bos
    velocity = np.concatenate([[0.0], np.cumsum(0.5 * (ay[after][1:] + ay[after][:-1]) * np.diff(t[after]))])
    position = np.concatenate([[0.0], np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) * np.diff(t[after]))])
    displacement = float(direction * np.interp(bos + DISPLACEMENT_TIME, t[after], position))
    responsive = None if A is None or amplitude < 5.0 * A * 0.98 else displacement >= DISPLACEMENT_LIMIT
    spun = bool(sideslip is not None and spin_out(_series("sideslip", sideslip, n)))
    return SineWithDwellResult(amplitude, bos, cos_time, peak, ratio_1000, ratio_1750, displacement,
                               bool(ratio_1000 <= YAW_RATIO_1000 and ratio_1750 <= YAW_RATIO_1750),
                               responsive, spun)


def steering_angle_at_lateral_acceleration(t, steering_wheel_angle, lateral_acceleration, target_g: float = 0.3,
                                           fit_range_g: tuple[float, float] = (0.1, 0.375)) -> float:
    """FMVSS 126 S7.6: the steering-wheel angle [rad] that produces ``target_g`` in the slowly
    increasing steer test, by linear regression of the filtered steering angle on the filtered
    |ay| over ``fit_range_g`` (the regulation's 0.1-0.375 g window around 0.3 g)."""
    t = _series("t", t)
    fs = _sample_rate(t)
    steer = np.abs(phaseless_butterworth(_series("steering_wheel_angle", steering_wheel_angle, len(t)), fs,
                                         STEERING_CUTOFF))
    ay_g = np.abs(phaseless_butterworth(_series("lateral_acceleration", lateral_acceleration, len(t)), fs,
                                        RESPONSE_CUTOFF)) / 9.80665
    lo, hi = fit_range_g
    peak = int(np.argmax(ay_g))
    fit = np.flatnonzero((ay_g[:peak + 1] >= lo) & (ay_g[:peak + 1] <= hi))
    if fit.size < 10:
        raise ValueError(f"lateral acceleration never spans {lo}-{hi} g: cannot determine A")
    slope, intercept = np.polyfit(ay_g[fit], steer[fit], 1)
    return float(slope * target_g + intercept)


def cone_hits(x, y, psi, cones: np.ndarray, width: float, front_extent: float, rear_extent: float,
              cone_radius: float = 0.15) -> int:
    """Number of distinct cones (M, 2) [m] touched by the car's body rectangle (``width`` [m],
    ``front_extent`` / ``rear_extent`` ahead of / behind the CG [m]) along the CG path x, y [m]
    with heading psi [rad]; a cone is a disc of ``cone_radius`` [m]."""
    x = _series("x", x)
    y, psi = _series("y", y, len(x)), _series("psi", psi, len(x))
    cones = np.asarray(cones, dtype=float).reshape(-1, 2)
    hits = 0
    for cx, cy in cones:
        dx, dy = cx - x, cy - y
        lon = dx * np.cos(psi) + dy * np.sin(psi)
        lat = -dx * np.sin(psi) + dy * np.cos(psi)
        ex = np.maximum(np.maximum(lon - front_extent, -rear_extent - lon), 0.0)
        ey = np.maximum(np.abs(lat) - width / 2, 0.0)
        hits += bool(np.any(np.hypot(ex, ey) < cone_radius))
    return hits


def path_deviation(x, y, path: np.ndarray) -> tuple[float, float]:
    """RMS and largest distance [m] of the points (x, y) from the polyline ``path`` (N, 2)."""
    x = _series("x", x)
    y = _series("y", y, len(x))
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or path.shape[1] != 2 or len(path) < 2:
        raise ValueError(f"path must be an (N >= 2, 2) polyline, got shape {path.shape}")
    a, b = path[:-1], path[1:]
    ab = b - a
    length2 = np.maximum(np.sum(ab**2, axis=1), 1e-12)
    p = np.column_stack([x, y])
    best = np.full(len(p), np.inf)
    for chunk in range(0, len(p), 2048):
        q = p[chunk:chunk + 2048, None, :]
        s = np.clip(np.sum((q - a) * ab, axis=2) / length2, 0.0, 1.0)
        d = np.hypot(*(q - (a + s[..., None] * ab)).transpose(2, 0, 1))
        best[chunk:chunk + 2048] = d.min(axis=1)
    return float(np.sqrt(np.mean(best**2))), float(best.max())


def spin_out(sideslip) -> bool:
    """Whether |sideslip| [rad] ever exceeds 20 deg: beyond it the driver has lost the car
    (ESC literature treats 10-20 deg as the edge of controllability; van Zanten, 2000)."""
    return bool(np.max(np.abs(_series("sideslip", sideslip))) > SPIN_OUT_SIDESLIP)


def rms(x) -> float:
    """Root mean square of a series."""
    x = _series("x", x)
    return float(np.sqrt(np.mean(x**2)))


def rmse(estimate, truth) -> float:
    """Root-mean-square error (the paper's Table 2)."""
    truth = _series("truth", truth)
    return rms(_series("estimate", estimate, len(truth)) - truth)


def mae(estimate, truth) -> float:
    """Mean absolute error (the paper's Table 2)."""
    truth = _series("truth", truth)
    return float(np.mean(np.abs(_series("estimate", estimate, len(truth)) - truth)))

"""Stability metrics as pure functions on uniformly sampled time series (SI units).

* FMVSS 126 (49 CFR 571.126 S7.6, S7.9-S7.11; the same procedure as GTR 8, UN R13-H Annex 9 and
  GB/T 30677-2014): the phaseless filters, the sine-with-dwell evaluation (zeroing, BOS, COS,
  yaw-rate ratios, lateral displacement) and the characterisation angle A.
* ISO 3888-1/-2 lane changes: cones touched by the car's footprint, deviation from a path.
* Generic: peak, RMS, yaw-rate tracking, spin-out, and the paper's Table 2 RMSE/MAE.

Angles are in rad and rates in rad/s throughout; the regulation's thresholds, stated in degrees,
are converted once below.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np
from scipy.signal import butter, find_peaks, sosfiltfilt

from fourwis.core.checks import is_number
from fourwis.core.kernels import JIT
from fourwis.envs.courses import CONE_RADIUS, stack_polylines

STEERING_CUTOFF = 10.0  #: S7.11.1: steering-wheel angle filter cutoff [Hz]
RESPONSE_CUTOFF = 6.0  #: S7.11.2-3: yaw rate and lateral acceleration filter cutoff [Hz]
FILTER_ORDER = 12  #: the regulation's "12-pole phaseless Butterworth" (6 poles each way)
RATE_AVERAGE = 0.1  #: S7.11.4: running average applied to the steering rate [s]
ZEROING_RATE = math.radians(75.0)  #: S7.11.5: steering rate that ends the zeroing range [rad/s]
ZEROING_HOLD = 0.2  #: ... and that it must stay above for this long [s]
ZEROING_RANGE = 1.0  #: the zeroing range: this long before the rate event [s]
BOS_ANGLE = math.radians(5.0)  #: S7.11.6: beginning of steer threshold [rad]
COS_TOLERANCE = math.radians(0.1)  #: COS: back within this of zero (steering sensor resolution) [rad]
YAW_RATIO_1000 = 0.35  #: S5.2.1: limit on r(COS + 1.000 s) / first peak
YAW_RATIO_1750 = 0.20  #: S5.2.2: limit on r(COS + 1.750 s) / first peak
DISPLACEMENT_TIME = 1.07  #: S5.2.3: lateral displacement measured at BOS + 1.07 s
DISPLACEMENT_LIMIT = 1.83  #: S5.2.3: minimum displacement [m] for GVWR <= 3500 kg
HEAVY_DISPLACEMENT_LIMIT = 1.52  #: S5.2.3: minimum displacement [m] for GVWR > 3500 kg
RESPONSIVENESS_FROM = 5.0  #: S5.2.3 applies to amplitudes of 5A and more
AMPLITUDE_MARGIN = 0.01  #: the measured amplitude stands in for the commanded one within 1%
G_UNIT = 9.80665  #: the unit "g" of the regulation's thresholds (standard gravity) [m/s^2]
SPIN_OUT_SIDESLIP = math.radians(20.0)  #: default |beta| spin-out threshold [rad]
#: a sideslip within this of the steering geometry's (kinematic_sideslip) is a rolling car's [rad]
ROLLING_SIDESLIP_TOLERANCE = math.radians(5.0)
#: the largest lateral acceleration of a turn a car can be rolling round [m/s^2] (1 g)
ROLLING_LATERAL_ACCELERATION = G_UNIT
SPIN_OUT_HEADING = math.pi / 2  #: heading this far from the course counts as a spin-out [rad]
#: below this ground speed [m/s] a sideslip is not a spin: atan(v / u) of a car at rest is the
#: direction of millimetres per second, any angle
SPIN_OUT_MIN_SPEED = 1.0
TINY = np.finfo(float).tiny  #: floor of a path segment's squared length [m^2]


def _series(name: str, x, n: int | None = None) -> np.ndarray:
    """``x`` as a finite 1-D float array (of ``n`` samples when given)."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"{name} must be a 1-D time series, got shape {x.shape}")
    if n is not None and len(x) != n:
        raise ValueError(f"{name} has {len(x)} samples, expected {n} (the length of t)")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains NaN or inf")
    return x


def _same_shape(name_a: str, a, name_b: str, b) -> tuple[np.ndarray, np.ndarray]:
    """Two finite arrays of equal, non-empty shape."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or a.size == 0:
        raise ValueError(f"{name_a} {a.shape} and {name_b} {b.shape} must have the same non-empty shape")
    for name, x in ((name_a, a), (name_b, b)):
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{name} contains NaN or inf")
    return a, b


def _sample_rate(t: np.ndarray) -> float:
    """Sample rate [Hz] of the increasing, uniformly spaced (within 0.1%) times ``t`` [s]."""
    if len(t) < 2:
        raise ValueError(f"time series too short: {len(t)} samples")
    dt = np.diff(t)
    if np.any(dt <= 0) or np.ptp(dt) > 1e-3 * dt.mean():
        raise ValueError(f"t must be increasing and uniformly sampled (steps {dt.min():.6g} to {dt.max():.6g} s)")
    return float(1.0 / dt.mean())


def phaseless_butterworth(x, fs: float, cutoff: float, order: int = FILTER_ORDER) -> np.ndarray:
    """Zero-phase Butterworth low-pass of ``x`` (..., n) along the last axis.

    ``fs`` sample rate [Hz], ``cutoff`` [Hz], ``order`` total poles. The regulation's "12-pole
    phaseless Butterworth" is a 6-pole filter run forwards then backwards (``sosfiltfilt``):
    the second pass doubles the order to 12 poles and cancels the phase, so the response is
    |H(f)|^2 of the 6-pole filter, 0.5 in amplitude (-6 dB) at ``cutoff``."""
    if order < 2 or order % 2:
        raise ValueError(f"order must be even (forward-backward halves), got {order!r}")
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sample rate [Hz], got {fs!r}")
    if not 0 < cutoff < fs / 2:
        raise ValueError(f"cutoff {cutoff!r} Hz must lie in (0, fs/2 = {fs / 2} Hz)")
    x = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(x)):
        raise ValueError("signal contains NaN or inf")
    sos = butter(order // 2, cutoff, fs=fs, output="sos")
    padlen = 3 * (2 * len(sos) + 1)
    if x.ndim == 0 or x.shape[-1] <= padlen:
        raise ValueError(f"signal too short to filter: {x.shape[-1] if x.ndim else 0} samples, need > {padlen}")
    return sosfiltfilt(sos, x, axis=-1, padlen=padlen)


#: FMVSS 126's criteria, as :attr:`SineWithDwellResult.failed_criteria` names them: S5.2.1, S5.2.2, S5.2.3
SWD_CRITERIA = ("yaw ratio at 1.00 s", "yaw ratio at 1.75 s", "responsiveness at 1.07 s")


@dataclass(frozen=True)
class SineWithDwellResult:
    """FMVSS 126 evaluation of one sine-with-dwell run."""

    direction: int  #: initial steering direction, +1 left (counter-clockwise), -1 right
    steering_amplitude: float  #: largest |filtered, zeroed steering-wheel angle| [rad]
    bos_time: float  #: beginning of steer [s]
    cos_time: float  #: completion of steer [s]
    first_peak_yaw_rate: float  #: first yaw-rate peak after the steering reversal, dwell sense [rad/s]
    yaw_rate_ratio_1000: float  #: r(COS + 1.000 s) / first peak, signed (inf without a peak)
    yaw_rate_ratio_1750: float  #: r(COS + 1.750 s) / first peak, signed (inf without a peak)
    lateral_displacement: float  #: at BOS + 1.07 s, positive towards the initial steer [m]
    passed_responsiveness: bool | None  #: displacement >= 1.83 m; None below 5A or without A
    spun_out: bool | None  #: sideslip spin-out flag; None when no sideslip was given

    @property
    def passed_yaw(self) -> bool:
        """Lateral stability (S5.2.1-2): |ratio| <= 35% at COS + 1 s and <= 20% at COS + 1.75 s.
        Magnitudes: the regulation's car yaws back the dwell's way; one still yawing hard the
        first way (a reverse-sense spin, a negative ratio) is not stable either."""
        return bool(abs(self.yaw_rate_ratio_1000) <= YAW_RATIO_1000 and abs(self.yaw_rate_ratio_1750) <= YAW_RATIO_1750)

    @property
    def failed_criteria(self) -> tuple[str, ...]:
        """The criteria of :data:`SWD_CRITERIA` this run fails (empty: it passes), in their order."""
        failed = (
            not abs(self.yaw_rate_ratio_1000) <= YAW_RATIO_1000,
            not abs(self.yaw_rate_ratio_1750) <= YAW_RATIO_1750,
            self.passed_responsiveness is False,
        )
        return tuple(name for name, bad in zip(SWD_CRITERIA, failed) if bad)

    @property
    def passed(self) -> bool:
        """Every criterion that applies to this run (responsiveness only from 5A)."""
        return self.passed_yaw and self.passed_responsiveness is not False

    def as_dict(self) -> dict:
        """All fields plus ``passed_yaw``, ``passed`` and ``failed_criteria`` (joined by "; ")."""
        failed = "; ".join(self.failed_criteria)
        return {**asdict(self), "passed_yaw": self.passed_yaw, "passed": self.passed, "failed_criteria": failed}


def _running_mean(x: np.ndarray, window: int) -> np.ndarray:
    """Centred running mean over ``window`` samples (odd), shrinking at the ends."""
    kernel = np.ones(window)
    return np.convolve(x, kernel, mode="same") / np.convolve(np.ones_like(x), kernel, mode="same")


def _zeroing_end(t: np.ndarray, steer: np.ndarray) -> int:
    """Index ending the zeroing range (S7.11.4-5) from the filtered steering angle [rad].

    The steering rate is the derivative of the filtered angle smoothed by a centred 0.1 s
    running average. The range ends at the first instant the |rate| exceeds 75 deg/s and then
    stays above it for 200 ms; failing instants are skipped (the regulation's iteration).
    Two cases the regulation does not meet: (1) below ~27 deg of amplitude the first quarter-sine
    (0.36 s) is too short to hold 75 deg/s for 200 ms, and the iteration would land on the
    steering reversal and zero the signals over the first half-wave; a qualifying instant
    therefore only counts before the rate first changes sign, else the first instant above
    75 deg/s is taken. (2) Below ~17 deg the rate never reaches 75 deg/s; half the largest
    |rate| then replaces the threshold (the sine's rate starts at its maximum, so this is
    within a few ms of the start too)."""
    fs = 1.0 / (t[1] - t[0])
    rate = _running_mean(np.gradient(steer, t), 2 * int(round(RATE_AVERAGE * fs / 2)) + 1)
    threshold = ZEROING_RATE if np.max(np.abs(rate)) > ZEROING_RATE else 0.5 * np.max(np.abs(rate))
    if threshold <= 0:
        raise ValueError("the steering-wheel angle never moves: not a sine-with-dwell run")
    fast = np.abs(rate) > threshold
    onsets = np.flatnonzero(fast & ~np.r_[False, fast[:-1]])
    first = int(onsets[0])
    flips = np.flatnonzero(np.sign(rate[first:]) != np.sign(rate[first]))
    initial_motion_end = first + int(flips[0]) if flips.size else len(t)
    hold = int(round(ZEROING_HOLD * fs))
    for onset in onsets[onsets < initial_motion_end]:
        if onset + hold < len(t) and fast[onset : onset + hold + 1].all():
            return int(onset)
    return first


def _crossing_time(t: np.ndarray, x: np.ndarray, level: float, i: int) -> float:
    """Time [s] at which ``x`` falls to ``level`` between samples i-1 and i (linear)."""
    if i == 0:
        return float(t[0])
    x0, x1 = x[i - 1], x[i]
    return float(t[i - 1] + (t[i] - t[i - 1]) * (x0 - level) / (x0 - x1)) if x0 != x1 else float(t[i])


def sine_with_dwell_metrics(
    t,
    steering_wheel_angle,
    yaw_rate,
    lateral_acceleration,
    A: float | None = None,
    direction: int | None = None,
    sideslip=None,
    displacement_limit: float = DISPLACEMENT_LIMIT,
) -> SineWithDwellResult:
    """Evaluate one sine-with-dwell run by FMVSS 126 S7.11.

    ``t`` (n,) uniform times [s]; ``steering_wheel_angle`` [rad], ``yaw_rate`` [rad/s],
    ``lateral_acceleration`` [m/s^2] (n,) (ISO 8855 signs, left positive). ``A`` [rad]: the
    characterisation angle, needed for the responsiveness criterion (amplitudes >= 5A).
    ``direction``: initial steering direction (+1 left, -1 right); None infers it from the first
    5 deg excursion, which a given direction must agree with (ValueError otherwise).
    ``sideslip`` [rad] (n,), optional: sets ``spun_out`` (see :func:`spin_out`).
    ``displacement_limit`` [m]: the responsiveness minimum, 1.83 m; a vehicle of GVWR above
    3,500 kg is held to :data:`HEAVY_DISPLACEMENT_LIMIT` (VehicleParams has a test mass, no
    GVWR, so fourwis's runs use the light-vehicle limit).

    1. Filter: steering 10 Hz, yaw rate and lateral acceleration 6 Hz (12-pole phaseless).
    2. Zero each filtered signal by its mean over the zeroing range: the 1 s before the steering
       rate first exceeds 75 deg/s and holds it for 200 ms (see ``_zeroing_end``). The series
       must cover at least half of that second.
    3. BOS: the filtered, zeroed steering first reaches 5 deg in the initial direction after
       the zeroing range (interpolated).
    4. COS: after the dwell (the largest steering excursion opposite the initial direction), the
       first time the zeroed steering angle is back within 0.1 deg (the sensor resolution) of
       zero, or of its closest approach to zero when a zeroing residue keeps it off zero
       (interpolated; early by 0.1 deg / steering rate, ~1 ms at 20 deg of amplitude). S7.11.7
       does not ask for the filtered angle, and the 10 Hz filter rounds the abrupt stop of the
       profile and moves its zero ~15 ms later, so the unfiltered angle (zeroed like the
       others) is used.
    5. First peak yaw rate: the first local maximum of the yaw rate in the dwell's sense after
       the steering reverses (S7.11.8); the largest such yaw rate if it never peaks (a spin).
    6. Ratios: the yaw rate at COS + 1.000 s and COS + 1.750 s (interpolated, dwell sense) over
       that peak. Lateral stability: <= 0.35 and <= 0.20.
    7. Lateral displacement: the zeroed, filtered lateral acceleration integrated twice from
       BOS (velocity and displacement zero there; cumulative trapezoid), read at BOS + 1.07 s
       and signed towards the initial steering. The regulation integrates the lateral
       acceleration of the CG corrected for roll; here it is the body-frame value given.
    """
    t = _series("t", t)
    n = len(t)
    fs = _sample_rate(t)
    raw_steer = _series("steering_wheel_angle", steering_wheel_angle, n)
    steer = phaseless_butterworth(raw_steer, fs, STEERING_CUTOFF)
    yaw = phaseless_butterworth(_series("yaw_rate", yaw_rate, n), fs, RESPONSE_CUTOFF)
    ay = phaseless_butterworth(_series("lateral_acceleration", lateral_acceleration, n), fs, RESPONSE_CUTOFF)
    if direction not in (None, 1, -1):
        raise ValueError(f"direction must be +1 (left), -1 (right) or None, got {direction!r}")
    if A is not None and not (math.isfinite(A) and A > 0):
        raise ValueError(f"A must be a positive angle [rad], got {A!r}")
    if not (is_number(displacement_limit) and math.isfinite(displacement_limit) and displacement_limit > 0):
        raise ValueError(f"displacement_limit must be a distance > 0 [m], got {displacement_limit!r}")

    end = _zeroing_end(t, steer)
    window = (t >= t[end] - ZEROING_RANGE) & (t < t[end])
    if not window.any() or t[end] - max(t[0], t[end] - ZEROING_RANGE) < 0.5 * ZEROING_RANGE:
        raise ValueError(f"the steering starts at {t[end]:.3f} s: the series needs ~1 s of data before it")
    steer, yaw, ay, raw_steer = (x - x[window].mean() for x in (steer, yaw, ay, raw_steer))

    excursion = np.abs(steer[end:]) >= BOS_ANGLE
    if not excursion.any():
        raise ValueError("the steering never reaches 5 deg: not a sine-with-dwell run")
    i_bos = end + int(np.argmax(excursion))
    if direction is not None and np.sign(steer[i_bos]) != direction:
        raise ValueError(
            f"the steering first moves {'left' if steer[i_bos] > 0 else 'right'}: direction={direction} contradicts it"
        )
    direction = int(np.sign(steer[i_bos]))
    bos = _crossing_time(t, -direction * steer, -BOS_ANGLE, i_bos)

    dwell_sign = -direction
    reversed_ = np.flatnonzero(dwell_sign * steer[i_bos:] > 0)
    if not reversed_.size:
        raise ValueError("the steering never reverses after BOS: not a sine-with-dwell run")
    i_rev = i_bos + int(reversed_[0])
    i_dwell = i_rev + int(np.argmax(dwell_sign * steer[i_rev:]))
    back = dwell_sign * raw_steer[i_dwell:]
    level = max(float(back.min()), 0.0) + COS_TOLERANCE
    if level > 0.5 * np.max(np.abs(steer)):
        raise ValueError("the steering does not return to zero after the dwell")
    cos = _crossing_time(t[i_dwell:], back, level, int(np.argmax(back <= level)))
    if cos + 1.75 > t[-1]:
        raise ValueError(f"the series ends at {t[-1]:.3f} s, before COS + 1.75 s = {cos + 1.75:.3f} s")

    response = dwell_sign * yaw[i_rev:]
    peaks, _ = find_peaks(response, height=0.0)
    peak = float(response[peaks[0]] if peaks.size else response.max())
    if peak > 0:
        ratio_1000 = float(dwell_sign * np.interp(cos + 1.0, t, yaw) / peak)
        ratio_1750 = float(dwell_sign * np.interp(cos + 1.75, t, yaw) / peak)
    else:
        ratio_1000 = ratio_1750 = math.inf

    t_end = bos + DISPLACEMENT_TIME
    if t_end > t[-1]:
        raise ValueError(f"the series ends at {t[-1]:.3f} s, before BOS + 1.07 s = {t_end:.3f} s")
    inside = (t > bos) & (t < t_end)
    grid = np.concatenate([[bos], t[inside], [t_end]])
    acc = direction * np.interp(grid, t, ay)
    dt = np.diff(grid)
    velocity = np.concatenate([[0.0], np.cumsum(0.5 * (acc[1:] + acc[:-1]) * dt)])
    displacement = float(np.sum(0.5 * (velocity[1:] + velocity[:-1]) * dt))

    amplitude = float(np.max(np.abs(steer)))
    applies = A is not None and amplitude >= (1.0 - AMPLITUDE_MARGIN) * RESPONSIVENESS_FROM * A
    responsive = bool(displacement >= displacement_limit) if applies else None
    # (sideslip alone: the regulation's steer, at most ~19 deg at the road wheels, leaves no
    # slow full-lock turn to tell apart, spin_out's ``rolling``)
    spun = None if sideslip is None else spin_out(_series("sideslip", sideslip, n))
    return SineWithDwellResult(
        direction, amplitude, bos, cos, peak, ratio_1000, ratio_1750, displacement, responsive, spun
    )


def steering_angle_at_lateral_acceleration(
    t,
    steering_wheel_angle,
    lateral_acceleration,
    target_g: float = 0.3,
    fit_range_g: tuple[float, float] = (0.1, 0.375),
) -> float:
    """Characterisation angle A [rad] from a slowly increasing steer run (FMVSS 126 S7.6).

    ``t`` (n,) [s], ``steering_wheel_angle`` [rad], ``lateral_acceleration`` [m/s^2] (n,).
    The standard defines A as the steering-wheel angle that produces a lateral acceleration of
    0.3 g in the 13.5 deg/s ramp at 80 km/h, read off a straight line fitted over 0.1-0.375 g
    (NHTSA TP-126). The ramp is quasi-steady only: at 80 km/h the yaw lag puts A above the
    steady-state angle for 0.3 g, as the procedure intends. Here the filtered |steering
    angle| (10 Hz) is regressed on the filtered |ay| (6 Hz) [g] over ``fit_range_g`` while ay
    still rises (up to its peak), and the fitted line is read at ``target_g``. Sensor offsets
    are assumed removed (the standard zeroes with static pre-test data). Returns a positive
    magnitude."""
    t = _series("t", t)
    fs = _sample_rate(t)
    lo, hi = fit_range_g
    if not 0 <= lo < hi or not target_g > 0:
        raise ValueError(f"need 0 <= fit_range_g[0] < fit_range_g[1] and target_g > 0, got {fit_range_g}, {target_g}")
    steer = np.abs(
        phaseless_butterworth(_series("steering_wheel_angle", steering_wheel_angle, len(t)), fs, STEERING_CUTOFF)
    )
    ay_g = (
        np.abs(
            phaseless_butterworth(_series("lateral_acceleration", lateral_acceleration, len(t)), fs, RESPONSE_CUTOFF)
        )
        / G_UNIT
    )
    rising = slice(0, int(np.argmax(ay_g)) + 1)
    fit = np.flatnonzero((ay_g[rising] >= lo) & (ay_g[rising] <= hi))
    if fit.size < 10:
        raise ValueError(f"lateral acceleration never spans {lo}-{hi} g (peak {ay_g.max():.3f} g): cannot find A")
    slope, intercept = np.polyfit(ay_g[fit], steer[fit], 1)
    return float(slope * target_g + intercept)


def cone_hits(
    x, y, psi, cones, width: float, front_extent: float, rear_extent: float, cone_radius: float = CONE_RADIUS
) -> int:
    """Number of distinct cones touched by the car's footprint (ISO 3888 counts displaced cones).

    ``x, y`` (n,) CG path [m], ``psi`` (n,) heading [rad]; ``cones`` (M, 2) cone centres [m].
    The footprint is the rectangle ``width`` [m] wide from ``rear_extent`` [m] behind to
    ``front_extent`` [m] ahead of the CG along the heading; a cone is a disc of ``cone_radius``
    [m] (0.15 m: the ~300 mm base of a road cone, its widest part — a conservative count).
    The test is made at the samples, so the step must be short against the cone size."""
    x = _series("x", x)
    y, psi = _series("y", y, len(x)), _series("psi", psi, len(x))
    cones = np.asarray(cones, dtype=float)
    if cones.ndim != 2 or cones.shape[1] != 2 or not np.all(np.isfinite(cones)):
        raise ValueError(f"cones must be a finite (M, 2) array, got shape {cones.shape}")
    for name, value in (
        ("width", width),
        ("front_extent + rear_extent", front_extent + rear_extent),
        ("cone_radius", cone_radius),
    ):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be positive [m], got {value!r}")
    dx, dy = cones[:, None, 0] - x, cones[:, None, 1] - y  # (M, n)
    cos_psi, sin_psi = np.cos(psi), np.sin(psi)
    lon = dx * cos_psi + dy * sin_psi
    lat = -dx * sin_psi + dy * cos_psi
    out_lon = np.maximum(np.maximum(lon - front_extent, -rear_extent - lon), 0.0)
    out_lat = np.maximum(np.abs(lat) - 0.5 * width, 0.0)
    return int(np.sum(np.any(np.hypot(out_lon, out_lat) < cone_radius, axis=1)))


def alongside_path(x, path) -> np.ndarray:
    """Whether the positions X [m] (n,) lie within the X extent of the course's ``path`` (N, 2),
    which runs along +X: where path deviations count (before its start and on the straight
    run-out past its end the distance to the polyline's end points is no deviation). ``path``
    may carry leading axes matching ``x``'s (each car its own path; NaN: none)."""
    x = np.asarray(x, dtype=float)
    return (x >= path[..., 0, 0]) & (x <= path[..., -1, 0])


def path_deviation(x, y, path) -> tuple[float, float]:
    """RMS and largest distance [m] of the points ``x, y`` (n,) [m] from the polyline ``path``
    (N >= 2, 2) [m]: each point's distance to its nearest segment."""
    x = _series("x", x)
    y = _series("y", y, len(x))
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or path.shape[1] != 2 or len(path) < 2 or not np.all(np.isfinite(path)):
        raise ValueError(f"path must be a finite (N >= 2, 2) polyline, got shape {path.shape}")
    if len(x) == 0:
        raise ValueError("x, y are empty")
    distance = np.empty(len(x))
    _distances_to_polyline(x, y, np.ascontiguousarray(path), distance)
    return float(np.sqrt(np.mean(distance**2))), float(distance.max())


class CoursePaths:
    """The reference paths of a batch of B cars (None: no course), for their distance from
    them sample by sample (the env's per-step path deviation): one compiled call over the batch.
    """

    def __init__(self, paths: list[np.ndarray | None]):
        self.paths = list(paths)
        self._stack()

    def replace(self, members, paths: list[np.ndarray | None]) -> None:
        """Cars ``members`` get the new ``paths`` (one each, in order)."""
        for b, path in zip(members, paths):
            self.paths[b] = path
        self._stack()

    def _stack(self) -> None:
        self.points, self.offsets = stack_polylines(self.paths)
        self.ends = np.full((len(self.paths), 2, 2), np.nan)  # each path's first and last point
        for b, path in enumerate(self.paths):
            if path is not None:
                self.ends[b] = np.asarray(path, dtype=float)[[0, -1]]

    def deviation(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distance [m] (B,) of the cars at ``x, y`` (B,) [m] from their paths where they are
        alongside them (:func:`alongside_path`), else 0."""
        out = np.zeros(len(self.paths))
        cars = np.flatnonzero(alongside_path(x, self.ends))
        if len(cars):
            _batch_distances(
                np.ascontiguousarray(x, dtype=float),
                np.ascontiguousarray(y, dtype=float),
                self.points,
                self.offsets,
                cars,
                out,
            )
        return out


@numba.njit(**JIT)
def _distance_to_polyline(x, y, path):
    """Distance [m] of the point (x, y) from the polyline ``path`` (N >= 2, 2): to its nearest
    segment."""
    nearest = math.inf
    for k in range(path.shape[0] - 1):
        ab_x, ab_y = path[k + 1, 0] - path[k, 0], path[k + 1, 1] - path[k, 1]
        q_x, q_y = x - path[k, 0], y - path[k, 1]
        s = min(max((q_x * ab_x + q_y * ab_y) / max(ab_x * ab_x + ab_y * ab_y, TINY), 0.0), 1.0)
        d_x, d_y = q_x - s * ab_x, q_y - s * ab_y
        nearest = min(nearest, math.sqrt(d_x * d_x + d_y * d_y))
    return nearest


@numba.njit(**JIT)
def _distances_to_polyline(x, y, path, out):
    for i in range(x.shape[0]):
        out[i] = _distance_to_polyline(x[i], y[i], path)


@numba.njit(**JIT)
def _batch_distances(x, y, points, offsets, cars, out):
    for b in cars:
        out[b] = _distance_to_polyline(x[b], y[b], points[offsets[b] : offsets[b + 1]])


def kinematic_sideslip(delta_f, delta_r, cg_to_front: float, cg_to_rear: float) -> np.ndarray:
    """Sideslip [rad] of a car rolling without tyre slip at road-wheel angles ``delta_f``,
    ``delta_r`` [rad] (same shapes; left positive, rear in phase positive): atan((b tan
    delta_f + a tan delta_r) / L), the low-speed geometry (Rajamani 2012, sec. 2.2). At full
    lock (0.6 rad) this car's is 18.9 deg: at walking pace a plain turn has that sideslip."""
    delta_f, delta_r = np.asarray(delta_f, dtype=float), np.asarray(delta_r, dtype=float)
    return np.arctan((cg_to_rear * np.tan(delta_f) + cg_to_front * np.tan(delta_r)) / (cg_to_front + cg_to_rear))


def rolling_sideslip(speed, delta_f, delta_r, cg_to_front: float, cg_to_rear: float) -> np.ndarray:
    """:func:`kinematic_sideslip` where a car could roll round the turn its road-wheel angles
    make at ``speed`` [m/s] (the turn asks at most ROLLING_LATERAL_ACCELERATION, u^2 |tan
    delta_f - tan delta_r| cos(beta) / L), NaN where it could not (at speed, a sideslip near the
    geometry's is a counter-steered slide: 13 m/s near the lock asks ~5 g). Same shapes."""
    speed, delta_f, delta_r = (np.asarray(x, dtype=float) for x in (speed, delta_f, delta_r))
    geometry = kinematic_sideslip(delta_f, delta_r, cg_to_front, cg_to_rear)
    demand = speed**2 * np.abs(np.tan(delta_f) - np.tan(delta_r)) * np.cos(geometry) / (cg_to_front + cg_to_rear)
    return np.where(demand <= ROLLING_LATERAL_ACCELERATION, geometry, np.nan)


def spun_sideslip(beta, rolling=None, threshold_beta: float = SPIN_OUT_SIDESLIP, speed=None):
    """Per sample: |beta| > ``threshold_beta``, unless it lies within ROLLING_SIDESLIP_TOLERANCE
    (5 deg) of the ``rolling`` sideslip (:func:`rolling_sideslip`, same shape; NaN: none): a car
    whose sideslip the geometry explains is rolling round a slow full-lock turn, not sliding (at
    walking pace the plant stays within 1.3 deg of it, its parallel-steered wheels scrubbing);
    nor where the ground speed ``speed`` (same shape, [m/s], optional) is below
    SPIN_OUT_MIN_SPEED: a stopped car has no sideslip to speak of."""
    beta = np.asarray(beta, dtype=float)
    spun = np.abs(beta) > threshold_beta
    if rolling is not None:
        spun &= ~(np.abs(beta - rolling) <= ROLLING_SIDESLIP_TOLERANCE)
    if speed is not None:
        spun &= np.asarray(speed, dtype=float) >= SPIN_OUT_MIN_SPEED
    return spun


def spin_out(
    beta, psi=None, course_heading=None, threshold_beta: float = SPIN_OUT_SIDESLIP, rolling=None, speed=None
) -> bool:
    """Whether the car spun out.

    ``beta`` (n,) sideslip [rad]: spin-out once |beta| > ``threshold_beta`` (default 20 deg;
    not a regulation value: normal driving stays within a few degrees, atan(0.02 mu g)
    (Rajamani), and ESC studies treat 10-20 deg as beyond a driver's recovery).
    ``rolling`` (n,) [rad], optional: the sideslip of a car rolling round the turn its wheels
    make (:func:`rolling_sideslip`); a sample within 5 deg of it does not count
    (:func:`spun_sideslip`): a turn at walking pace near full lock is no spin.
    ``speed`` (n,) ground speed [m/s], optional: a sample below SPIN_OUT_MIN_SPEED (1 m/s) does
    not count (a stopped car's atan(v / u) is any angle).
    ``psi`` (n,) heading [rad], optional: spin-out also when the heading deviates more than
    90 deg from ``course_heading`` [rad] (scalar or (n,): the direction of travel the
    course asks for; None: the initial heading psi[0]); NHTSA's ESC research counted a
    heading change of 90 deg or more as a spinout."""
    beta = _series("beta", beta)
    if not (math.isfinite(threshold_beta) and threshold_beta > 0):
        raise ValueError(f"threshold_beta must be a positive angle [rad], got {threshold_beta!r}")
    if rolling is not None:
        rolling = np.asarray(rolling, dtype=float)
        if rolling.shape != beta.shape:
            raise ValueError(f"rolling has {rolling.size} samples, expected {len(beta)} (the length of beta)")
    if speed is not None:
        speed = _series("speed", speed, len(beta))
    spun = bool(np.any(spun_sideslip(beta, rolling, threshold_beta, speed)))
    if psi is not None:
        psi = _series("psi", psi, len(beta))
        course = psi[0] if course_heading is None else np.asarray(course_heading, dtype=float)
        if course.ndim > 1 or (course.ndim == 1 and len(course) != len(psi)) or not np.all(np.isfinite(course)):
            raise ValueError(f"course_heading must be finite, scalar or ({len(psi)},), got shape {course.shape}")
        deviation = np.angle(np.exp(1j * (psi - course)))
        spun = spun or bool(np.max(np.abs(deviation)) > SPIN_OUT_HEADING)
    return spun


def peak_abs(x) -> float:
    """Largest |x| over all samples (e.g. peak sideslip [rad])."""
    x = np.asarray(x, dtype=float)
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise ValueError(f"x must be finite and non-empty, got shape {x.shape}")
    return float(np.max(np.abs(x)))


def rms(x) -> float:
    """Root mean square over all samples."""
    x = np.asarray(x, dtype=float)
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise ValueError(f"x must be finite and non-empty, got shape {x.shape}")
    return float(np.sqrt(np.mean(x**2)))


def rmse(estimate, truth) -> float:
    """Root-mean-square error over all samples of equally shaped arrays (the paper's Table 2)."""
    estimate, truth = _same_shape("estimate", estimate, "truth", truth)
    return float(np.sqrt(np.mean((estimate - truth) ** 2)))


def mae(estimate, truth) -> float:
    """Mean absolute error over all samples of equally shaped arrays (the paper's Table 2)."""
    estimate, truth = _same_shape("estimate", estimate, "truth", truth)
    return float(np.mean(np.abs(estimate - truth)))


def yaw_rate_tracking_rms(r, r_ref) -> float:
    """RMS [rad/s] of the yaw-rate tracking error r - r_ref (equal shapes)."""
    return rmse(r, r_ref)


#: UN R13-H Annex 6 judges wheel lock only above 15 km/h [m/s]
WHEEL_LOCK_SPEED = 15.0 / 3.6
#: a wheel turning slower than this fraction of the car's speed counts as locked [-] (slip < -0.9)
LOCKED_SPEED_RATIO = 0.1


@dataclass(frozen=True)
class BrakingResult:
    """A straight-line stop: distance [m] and time [s] from the brake application to standstill
    (None if the car does not stop), the speed at the application [m/s], and the longest time [s]
    any wheel stayed locked (turning below LOCKED_SPEED_RATIO of the car's speed) while the car was
    faster than WHEEL_LOCK_SPEED."""

    stopping_distance: float | None
    stopping_time: float | None
    initial_speed: float
    longest_lock: float


def braking_metrics(t, x, u, wheel_speeds, brake_at: float) -> BrakingResult:
    """:class:`BrakingResult` of a run: times ``t`` (T,) [s], the CG's travel ``x`` (T,) [m] and
    forward speed ``u`` (T,) [m/s], the wheels' rim speeds R omega (T, 4) [m/s], brakes applied at
    ``brake_at`` [s]."""
    t = _series("t", t)
    x, u = _series("x", x, len(t)), _series("u", u, len(t))
    wheel_speeds = np.asarray(wheel_speeds, dtype=float)
    if wheel_speeds.shape != (len(t), 4) or not np.all(np.isfinite(wheel_speeds)):
        raise ValueError(f"wheel_speeds must be finite with shape ({len(t)}, 4), got {wheel_speeds.shape}")
    if not (is_number(brake_at) and t[0] <= brake_at < t[-1]):
        raise ValueError(f"brake_at must lie within the run [{t[0]}, {t[-1]}) s, got {brake_at!r}")
    start = int(np.searchsorted(t, brake_at))
    stopped = np.flatnonzero(u[start:] <= 0.0)
    distance = time = None
    if len(stopped):
        end = start + int(stopped[0])
        distance, time = float(x[end] - x[start]), float(t[end] - t[start])
    dt = float(np.mean(np.diff(t)))
    locked = (wheel_speeds < LOCKED_SPEED_RATIO * u[:, None]) & (u[:, None] > WHEEL_LOCK_SPEED)
    longest = 0
    for w in range(4):
        run = 0
        for flag in locked[start:, w]:
            run = run + 1 if flag else 0
            longest = max(longest, run)
    return BrakingResult(distance, time, float(u[start]), longest * dt)

"""Driver models: steering inputs (open-loop profiles and a path follower) and speed holding.

A driver sees the true pose and speed (it looks at the road and the speedometer); only the
stability controller is restricted to the estimator's output. Steering outputs are
steering-wheel angles [rad]; the scenario divides by the steering ratio.

The open-loop profiles and the speed holder are :class:`VectorisedDriver` s: a compiled
kernel over a table of their parameters (``row``), which a single driver's call runs with one
row; :class:`DriverBatch` evaluates a batch of drivers (the closed loop's B vehicles) with one
kernel call per class, and any other callable one by one.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np
from scipy.linalg import expm

from fourwis.control.reference import bicycle_state_matrix
from fourwis.core.constants import GRAVITY
from fourwis.core.kernels import JIT, scratch
from fourwis.envs.courses import stack_polylines
from fourwis.envs.layout import S_PSI, S_R, S_U, S_V, S_X, S_Y
from fourwis.envs.vehicle import VehicleParams

SWD_FREQUENCY = 0.7  #: FMVSS 126 sine-with-dwell frequency [Hz]
SWD_DWELL = 0.5  #: FMVSS 126 dwell at the second peak [s]


class VectorisedDriver:
    """A driver given by its parameters (:meth:`row`, a record of the fields ``COLUMNS``) and its
    class's compiled ``kernel``: ``kernel(table (B,) records, members (M,) int64, t (B,) [s],
    states (B, NX), out (B,))`` writes the output of the drivers b in ``members``, whose
    parameters are ``table[b]``, at time ``t[b]`` and plant state ``states[b]`` into ``out[b]``."""

    kernel: Callable[..., None]
    COLUMNS: tuple[str, ...] = ()  #: the fields of the kernel's records, in :meth:`row`'s order

    def row(self) -> tuple:
        """This driver's parameters, in the order of ``COLUMNS``."""
        raise NotImplementedError

    @classmethod
    def table_dtype(cls) -> np.dtype:
        """The record type of this class's parameter table (float64 fields ``COLUMNS``)."""
        return np.dtype([(name, np.float64) for name in cls.COLUMNS])

    def __call__(self, t: float, state: np.ndarray) -> float:
        out = np.zeros(1)
        self.kernel(
            np.array([self.row()], dtype=self.table_dtype()),
            np.zeros(1, dtype=np.int64),
            np.array([t], dtype=np.float64),
            np.ascontiguousarray(state, dtype=np.float64)[None],
            out,
        )
        return float(out[0])


@numba.njit(**JIT)
def _constant(table, members, t, states, out):
    for b in members:
        out[b] = table[b]["angle"] if t[b] >= table[b]["start"] else 0.0


@numba.njit(**JIT)
def _step(table, members, t, states, out):
    for b in members:
        d = table[b]
        out[b] = d["angle"] * min(max((t[b] - d["start"]) / d["rise_time"], 0.0), 1.0)


@numba.njit(**JIT)
def _sine(table, members, t, states, out):
    for b in members:
        d = table[b]
        phase = (t[b] - d["start"]) * d["frequency"]
        out[b] = 0.0 if phase < 0.0 or phase > d["cycles"] else d["amplitude"] * math.sin(2.0 * math.pi * phase)


@numba.njit(**JIT)
def _ramp(table, members, t, states, out):
    for b in members:
        d = table[b]
        out[b] = math.copysign(min(abs(d["rate"] * max(t[b] - d["start"], 0.0)), d["limit"]), d["rate"])


@numba.njit(**JIT)
def _sine_with_dwell(table, members, t, states, out):
    omega, three_quarters = 2.0 * math.pi * SWD_FREQUENCY, 0.75 / SWD_FREQUENCY
    for b in members:
        amplitude, tau = table[b]["amplitude"], t[b] - table[b]["start"]
        if tau > three_quarters + SWD_DWELL:
            tau -= SWD_DWELL  # the last quarter cycle, after the dwell
        elif tau > three_quarters:
            out[b] = -amplitude
            continue
        out[b] = amplitude * math.sin(omega * tau) if 0.0 < tau <= 1.0 / SWD_FREQUENCY else 0.0


@numba.njit(**JIT)
def _speed_hold(table, members, t, states, out):
    for b in members:
        d = table[b]
        u = states[b, S_U]
        force = (
            d["mass"] * d["gain"] * (d["target_speed"] - u)
            + d["rolling_resistance"] * d["mass"] * GRAVITY
            + 0.5 * d["air_density"] * d["drag_area"] * u * abs(u)
        )
        peak = d["motor_peak_torque"]
        if t[b] >= d["brake_after"]:
            out[b] = -d["brake_torque"]
        elif t[b] >= d["coast_after"]:
            out[b] = 0.0
        else:
            out[b] = min(max(force * d["wheel_radius"] / 4.0, -peak), peak)


@dataclass(frozen=True)
class Constant(VectorisedDriver):
    """A fixed steering-wheel angle [rad] from ``start`` [s]."""

    angle: float
    start: float = 0.0

    kernel = staticmethod(_constant)
    COLUMNS = ("angle", "start")

    def row(self) -> tuple[float, ...]:
        return self.angle, self.start


@dataclass(frozen=True)
class Step(VectorisedDriver):
    """Step of ``angle`` [rad] at ``start`` [s] with a linear rise over ``rise_time`` [s]
    (ISO 7401 asks for a steering rate of 200-500 deg/s; 0.1 s for 1 rad is ~570 deg/s)."""

    angle: float
    start: float
    rise_time: float = 0.1

    kernel = staticmethod(_step)
    COLUMNS = ("angle", "start", "rise_time")

    def row(self) -> tuple[float, ...]:
        return self.angle, self.start, self.rise_time


@dataclass(frozen=True)
class Sine(VectorisedDriver):
    """``amplitude * sin(2 pi f (t - start))`` [rad] for ``cycles`` full periods from ``start``."""

    amplitude: float
    frequency: float
    start: float = 0.0
    cycles: float = math.inf

    kernel = staticmethod(_sine)
    COLUMNS = ("amplitude", "frequency", "start", "cycles")

    def row(self) -> tuple[float, ...]:
        return self.amplitude, self.frequency, self.start, self.cycles


@dataclass(frozen=True)
class Ramp(VectorisedDriver):
    """Slowly increasing steer: ``rate`` [rad/s] from ``start`` up to ``limit`` [rad]."""

    rate: float
    start: float = 0.0
    limit: float = math.inf

    kernel = staticmethod(_ramp)
    COLUMNS = ("rate", "start", "limit")

    def row(self) -> tuple[float, ...]:
        return self.rate, self.start, self.limit


@dataclass(frozen=True)
class SineWithDwell(VectorisedDriver):
    """FMVSS 126 / UN R13-H steering: a 0.7 Hz sine, held for 500 ms at its second peak.

    Starts at ``start`` [s] in the direction of ``amplitude``'s sign [rad]: the first peak at
    0.357 s, the second (opposite) peak reached at 1.0714 s and held until 1.5714 s, the
    last quarter cycle back to zero at 1.9286 s.
    """

    amplitude: float
    start: float = 1.0

    kernel = staticmethod(_sine_with_dwell)
    COLUMNS = ("amplitude", "start")

    def row(self) -> tuple[float, ...]:
        return self.amplitude, self.start

    @property
    def end(self) -> float:
        """Time [s] at which the steering is back at zero (completion of steer)."""
        return self.start + 1.0 / SWD_FREQUENCY + SWD_DWELL


MAX_SINES = 8  #: most terms a SumOfSines has (its table's records hold this many, unused ones zero)


@numba.njit(**JIT)
def _sum_of_sines(table, members, t, states, out):
    for b in members:
        d = table[b]
        total = 0.0
        for i in range(MAX_SINES):
            total += d["amplitudes"][i] * math.sin(2 * math.pi * d["frequencies"][i] * t[b] + d["phases"][i])
        out[b] = min(t[b], 1.0) * total  # faded in over the first second


@dataclass(frozen=True)
class SumOfSines(VectorisedDriver):
    """``min(t, 1) * sum_i amplitudes[i] sin(2 pi frequencies[i] t + phases[i])`` [rad]: a sum
    of sines faded in over the first second (the ``random`` scenario's steering)."""

    amplitudes: tuple[float, ...]
    frequencies: tuple[float, ...]
    phases: tuple[float, ...]

    kernel = staticmethod(_sum_of_sines)
    COLUMNS = ("amplitudes", "frequencies", "phases")

    def __post_init__(self) -> None:
        if not len(self.amplitudes) == len(self.frequencies) == len(self.phases) <= MAX_SINES:
            raise ValueError(
                f"a SumOfSines takes as many amplitudes, frequencies and phases, at most {MAX_SINES}, got "
                f"{len(self.amplitudes)}, {len(self.frequencies)} and {len(self.phases)}"
            )

    @classmethod
    def table_dtype(cls) -> np.dtype:
        return np.dtype([(name, np.float64, (MAX_SINES,)) for name in cls.COLUMNS])

    def row(self) -> tuple:
        pad = (0.0,) * (MAX_SINES - len(self.amplitudes))  # (zero terms add nothing)
        return self.amplitudes + pad, self.frequencies + pad, self.phases + pad


@functools.lru_cache(maxsize=4096)
def _preview_responses(
    params: VehicleParams, speed: float, preview_time: float, points: int
) -> tuple[np.ndarray, np.ndarray]:
    """Lateral-position responses of the linear single-track model at ``speed`` [m/s] at the
    ``points`` preview instants: (free (P, 4) rows mapping [y, psi, v, r] at t = 0 to y(t_k),
    step (P,) y(t_k) per radian of road-wheel steer held from t = 0), in the car's own frame."""
    c_f = params.axle_cornering_stiffness[0]
    m, iz, a, u = params.mass, params.yaw_inertia, params.cg_to_front, speed
    a11, a12, a21, a22 = bicycle_state_matrix(u, params)  # [beta, r] rows; here v = u beta
    A = np.array([[0.0, u, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, a11, u * a12], [0.0, 0.0, a21 / u, a22]])
    augmented = np.zeros((5, 5))
    augmented[:4, :4] = A * preview_time / points
    augmented[:4, 4] = np.array([0.0, 0.0, c_f / m, a * c_f / iz]) * preview_time / points
    transition = expm(augmented)  # zero-order hold over one preview interval
    phi, gamma = transition[:4, :4], transition[:4, 4]
    free, step = np.empty((points, 4)), np.empty(points)
    power, held = np.eye(4), np.zeros(4)
    for k in range(points):
        power, held = phi @ power, phi @ held + gamma
        free[k], step[k] = power[0], held[0]
    return free, step


@dataclass(frozen=True)
class PathFollower:
    """Optimal-preview path-following driver on a polyline ``path`` (N, 2) global (X, Y) [m]
    (MacAdam, "Application of an optimal preview control for simulation of closed-loop
    automobile driving", IEEE Trans. SMC 11(6), 1981; the driver model of CarSim).

    At each instant the driver predicts, with the linear single-track model at the current
    speed (per-axle cornering stiffness at static load), where the car's CG will be at
    ``points`` instants over the next ``preview_time`` seconds if it held a road-wheel angle
    delta, starting from the current lateral velocity and yaw rate; it steers the delta that
    minimises the summed squared distance of those points from the path, seen in the car's
    own frame (closed form: the prediction is linear in delta). The preview anticipates the
    car's own yaw and sideslip lag, so the driver neither lags nor overshoots on a course
    that asks for ~0.7 g (ISO 3888-2 at 60 km/h). Responses are cached per 0.1 m/s of speed.

    Returns the steering-wheel angle ``ratio * delta`` [rad], delta within the steering limit.
    Beyond the path's end the driver follows the last segment's line. The path must not turn
    back on itself: the driver aims at the first stretch ahead of the car counting from the
    path's start, so on a U-turn's return leg it would find the outbound leg (every course of
    envs.courses runs forward along X). The default 0.4 s preview (MacAdam: 0.5-1.5 s for
    normal drivers; shorter previews track tighter, longer ones cut the corners) clears ISO 3888-2
    at 60 km/h on mu 1.0 and 50 km/h on mu 0.6 (tested; docs/decisions/0009-courses-and-path-following-driver.md).
    """

    path: np.ndarray
    params: VehicleParams = field(default_factory=VehicleParams)
    preview_time: float = 0.4
    points: int = 20
    spacing: float = 0.25  #: path resampling step [m]
    _alone: PathFollowerBatch | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        path = np.asarray(self.path, dtype=np.float64)
        if path.ndim != 2 or path.shape[1] != 2 or path.shape[0] < 2 or not np.all(np.isfinite(path)):
            raise ValueError(f"path must be a finite (N >= 2, 2) polyline, got shape {path.shape}")
        for name in ("preview_time", "points", "spacing"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"PathFollower.{name} must be finite and > 0, got {getattr(self, name)!r}")
        if int(self.points) != self.points:
            raise ValueError(f"PathFollower.points must be a whole number, got {self.points!r}")
        segment = np.hypot(*np.diff(path, axis=0).T)
        if np.any(segment <= 0):
            raise ValueError("path has repeated points")
        arclength = np.concatenate([[0.0], np.cumsum(segment)])
        s = np.append(np.arange(0.0, arclength[-1], self.spacing), arclength[-1])
        resampled = np.column_stack([np.interp(s, arclength, path[:, 0]), np.interp(s, arclength, path[:, 1])])
        far = path[-1] + (path[-1] - path[-2]) / segment[-1] * 1e4  # the last segment's line, continued
        object.__setattr__(self, "path", np.vstack([resampled, far]))

    def __call__(self, t: float, state: np.ndarray) -> float:
        if self._alone is None:
            object.__setattr__(self, "_alone", PathFollowerBatch(self.params, self.preview_time, int(self.points)))
            self._alone.replace({0: self})
        out = np.zeros(1)
        self._alone(np.ascontiguousarray(state, dtype=np.float64)[None], _FIRST, out)
        return float(out[0])


_FIRST = np.zeros(1, dtype=np.int64)


class PathFollowerBatch:
    """The :class:`PathFollower` s of vehicles driving one car (``params``) with one preview
    (``preview_time``, ``points``), evaluated by one compiled call: their resampled paths in
    one array, their preview responses in a table by speed (0.1 m/s steps), filled as speeds
    come up."""

    def __init__(self, params: VehicleParams, preview_time: float, points: int):
        self.params, self.preview_time, self.points = params, float(preview_time), int(points)
        self.paths, self.offsets = np.zeros((0, 2)), np.zeros(1, dtype=np.int64)
        self.response_row = np.full(1000, -1, dtype=np.int64)  # table row by speed in 0.1 m/s; -1: not yet
        self.free, self.step = np.zeros((0, self.points, 4)), np.zeros((0, self.points))

    def replace(self, followers: dict[int, PathFollower]) -> None:
        """Drive vehicle b by ``followers[b]`` (vehicles 0..max(b)); the batch's vehicles without
        one must not be called."""
        rows = max(followers, default=-1) + 1
        self.paths, self.offsets = stack_polylines([followers[b].path if b in followers else None for b in range(rows)])

    def __call__(self, states: np.ndarray, members: np.ndarray, out: np.ndarray) -> None:
        """Write the steering-wheel angles [rad] of vehicles ``members`` (M,) int64 at plant
        states (B, NX) (float64, C-contiguous) into ``out[members]``."""
        while True:
            code, value = _follow_paths(self.kernel(), members, states, out)
            if code == DRIVEN:
                return
            if code == BAD_DRIVER_STATE:
                raise bad_follower_state(value, states[value])
            self.add_responses(value)

    def add_responses(self, tenths: int) -> None:
        """Put the preview responses at a speed of ``tenths`` x 0.1 m/s in the table."""
        if tenths >= len(self.response_row):  # beyond the table: grow it
            self.response_row = np.concatenate([self.response_row, np.full(tenths + 1, -1, dtype=np.int64)])
        free, step = _preview_responses(self.params, tenths / 10.0, self.preview_time, self.points)
        self.response_row[tenths] = len(self.free)
        self.free, self.step = np.concatenate([self.free, free[None]]), np.concatenate([self.step, step[None]])

    def kernel(self) -> FollowerKernel:
        """These path followers as :func:`_follow_paths` takes them (the arrays themselves)."""
        p = self.params
        return FollowerKernel(
            self.paths, self.offsets, self.response_row, self.free, self.step, self.preview_time,
            float(p.steering_ratio), float(p.max_front_steer),
        )  # fmt: skip


class FollowerKernel(NamedTuple):
    """A :class:`PathFollowerBatch` as its kernel takes it: the resampled paths of its vehicles
    stacked (N, 2) [m] with each vehicle's first row (B + 1,) int64, the preview-response table's
    row by speed in 0.1 m/s (-1: not yet), the responses free (R, P, 4) and step (R, P), the
    preview time [s], steering ratio [-] and front steer limit [rad]."""

    paths: np.ndarray
    offsets: np.ndarray
    response_row: np.ndarray
    free: np.ndarray
    step: np.ndarray
    preview_time: float
    ratio: float
    max_steer: float


#: statuses of a driver kernel: done, needs preview responses at a new speed, cannot steer from the state
DRIVEN, NEEDS_PREVIEW, BAD_DRIVER_STATE = 0, 1, 2
MAX_FOLLOW_SPEED = 150.0  #: fastest speed the path follower steers at [m/s] (its response table grows with it)


def bad_follower_state(b: int, state: np.ndarray) -> ValueError:
    """The error for vehicle b, whose plant state (NX,) the path follower cannot steer from."""
    return ValueError(
        f"vehicle {b}'s pose or speed is not finite or its speed beyond {MAX_FOLLOW_SPEED:g} m/s: "
        f"{state[[S_X, S_Y, S_PSI, S_U, S_V, S_R]]!r}"
    )


@numba.njit(**JIT)
def _follow_paths(follower: FollowerKernel, members, states, out):
    """:class:`PathFollowerBatch`'s kernel: (DRIVEN, 0) once every member's steering-wheel angle
    is in ``out``, (NEEDS_PREVIEW, tenths) if the preview responses at a speed of ``tenths`` x 0.1 m/s
    are not in the table yet (the speed is |u| floored at 1 m/s, rounded as np.round(u, 1)), or
    (BAD_DRIVER_STATE, vehicle) for a pose or speed that is not finite or beyond MAX_FOLLOW_SPEED."""
    paths, offsets, response_row, free, step, preview_time, ratio, max_steer = follower
    for b in members:
        speed = max(abs(states[b, S_U]), 1.0)
        pose = states[b, S_X] + states[b, S_Y] + states[b, S_PSI] + states[b, S_V] + states[b, S_R]
        if not (speed <= MAX_FOLLOW_SPEED and math.isfinite(pose)):
            return BAD_DRIVER_STATE, b
        tenths = int(np.rint(speed * 10.0))
        if tenths >= response_row.shape[0] or response_row[tenths] < 0:
            return NEEDS_PREVIEW, tenths
        row = response_row[tenths]
        delta = _preview_steer(paths[offsets[b] : offsets[b + 1]], free[row], step[row], states[b], speed, preview_time)
        out[b] = ratio * min(max(delta, -max_steer), max_steer)
    return DRIVEN, 0


@numba.njit(inline="always", **JIT)
def _ahead(path, k, x, y, cos_psi, sin_psi):
    """Distance [m] of path point k ahead of the car at (x, y) heading (cos_psi, sin_psi)."""
    return cos_psi * (path[k, 0] - x) + sin_psi * (path[k, 1] - y)


@numba.njit(inline="always", **JIT)
def _left(path, k, x, y, cos_psi, sin_psi):
    """Distance [m] of path point k to the left of the car at (x, y) heading (cos_psi, sin_psi)."""
    return -sin_psi * (path[k, 0] - x) + cos_psi * (path[k, 1] - y)


@numba.njit(**JIT)
def _nearest(path, x, y):
    """Index of the path point nearest to (x, y) [m] (the first of equals)."""
    nearest, nearest_squared = 0, math.inf
    for k in range(path.shape[0]):
        dx, dy = path[k, 0] - x, path[k, 1] - y
        if dx * dx + dy * dy < nearest_squared:
            nearest, nearest_squared = k, dx * dx + dy * dy
    return nearest


@numba.njit(**JIT)
def _preview_steer(path, free, step, state, speed, preview_time):
    """:class:`PathFollower`'s road-wheel angle [rad] (not yet limited) for the car at ``state``
    (NX,) moving at ``speed`` [m/s]: the preview ``free`` (P, 4) / ``step`` (P,) responses
    steered onto the resampled ``path`` (N, 2) seen in the car's frame over the next
    ``preview_time`` [s]. Scans the path from its start to the car's first point ahead and on
    to the first one beyond the horizon, interpolating as np.interp does; only a car facing
    away from the path (spun) looks at every point, for the nearest."""
    n, points = path.shape[0], step.shape[0]
    cos_psi, sin_psi = math.cos(state[S_PSI]), math.sin(state[S_PSI])
    x, y = state[S_X], state[S_Y]
    horizon = speed * preview_time
    first = 0  # first path point ahead of the car (0 if none is)
    for k in range(n):
        if _ahead(path, k, x, y, cos_psi, sin_psi) > 0.0:
            first = k
            break
    start = max(first - 1, 0)  # from the last point behind it through the first beyond the horizon
    stop = first + 1
    for k in range(first, n):
        if _ahead(path, k, x, y, cos_psi, sin_psi) > horizon:
            stop = k + 1
            break
    increasing = _ahead(path, first, x, y, cos_psi, sin_psi) > 0.0
    previous = -math.inf
    for k in range(start, stop):
        ahead = _ahead(path, k, x, y, cos_psi, sin_psi)
        increasing = increasing and ahead > previous
        previous = ahead
    gain, norm, segment = 0.0, 0.0, start
    # facing away from the path (spun): aim back at its nearest point, at every preview instant
    target = 0.0 if increasing else _left(path, _nearest(path, x, y), x, y, cos_psi, sin_psi)
    for k in range(points):
        if increasing:  # the path's lateral offset at the preview distance, as np.interp has it
            distance = horizon * (k + 1) / points
            while segment < stop - 1 and _ahead(path, segment + 1, x, y, cos_psi, sin_psi) <= distance:
                segment += 1
            if segment == stop - 1:
                target = _left(path, stop - 1, x, y, cos_psi, sin_psi)
            else:
                x0 = _ahead(path, segment, x, y, cos_psi, sin_psi)
                x1 = _ahead(path, segment + 1, x, y, cos_psi, sin_psi)
                y0 = _left(path, segment, x, y, cos_psi, sin_psi)
                y1 = _left(path, segment + 1, x, y, cos_psi, sin_psi)
                target = y0 if distance < x0 else (y1 - y0) / (x1 - x0) * (distance - x0) + y0
        error = free[k, 2] * state[S_V] + free[k, 3] * state[S_R] - target
        gain += step[k] * error
        norm += step[k] * step[k]
    return -gain / norm


@dataclass(frozen=True)
class SpeedHold(VectorisedDriver):
    """Speed-holding longitudinal driver: equal torques on all four wheels [N m].

    Proportional control on speed error with a feed-forward of rolling resistance and drag:
    ``F = m k (v_target - u) + f m g + 0.5 rho CdA u^2``, split equally and limited to the
    motors. From ``coast_after`` [s] on, the driver lifts off (zero torque: coasting, as FMVSS
    126 and ISO 3888-2 prescribe once the manoeuvre starts); from ``brake_after`` [s] on, the
    driver brakes, asking ``brake_torque`` [N m] of each wheel (a net torque of -brake_torque: the
    wheel actuators split it between motor and friction brake).
    """

    target_speed: float
    params: VehicleParams = field(default_factory=VehicleParams)
    gain: float = 1.0  #: [1/s]
    coast_after: float = math.inf
    brake_after: float = math.inf
    brake_torque: float = 0.0

    kernel = staticmethod(_speed_hold)
    COLUMNS = (
        "target_speed", "gain", "coast_after", "brake_after", "brake_torque", "mass", "rolling_resistance",
        "air_density", "drag_area", "wheel_radius", "motor_peak_torque",
    )  # fmt: skip

    def row(self) -> tuple[float, ...]:
        p = self.params
        return (
            self.target_speed,
            self.gain,
            self.coast_after,
            self.brake_after,
            self.brake_torque,
            p.mass,
            p.rolling_resistance,
            p.air_density,
            p.drag_area,
            p.wheel_radius,
            p.motor_peak_torque,
        )


class DriverKind(enum.IntEnum):
    """Which driver a vehicle has, in a :class:`DriverTables` (a compiled driver class, or a path follower)."""

    CONSTANT = 0
    STEP = 1
    SINE = 2
    RAMP = 3
    SINE_WITH_DWELL = 4
    SUM_OF_SINES = 5
    SPEED_HOLD = 6
    PATH_FOLLOWER = 7


#: the driver classes the compiled closed loop evaluates, by their DriverKind
COMPILED_DRIVERS = {
    Constant: DriverKind.CONSTANT,
    Step: DriverKind.STEP,
    Sine: DriverKind.SINE,
    Ramp: DriverKind.RAMP,
    SineWithDwell: DriverKind.SINE_WITH_DWELL,
    SumOfSines: DriverKind.SUM_OF_SINES,
    SpeedHold: DriverKind.SPEED_HOLD,
}


class DriverTables(NamedTuple):
    """The drivers of B vehicles as :func:`drive` takes them: each vehicle's :class:`DriverKind`
    (B,) int64, each compiled class's parameter records (B,) (rows of the vehicles of that kind;
    empty if none has it) and the path followers."""

    kind: np.ndarray
    constant: np.ndarray
    step: np.ndarray
    sine: np.ndarray
    ramp: np.ndarray
    sine_with_dwell: np.ndarray
    sum_of_sines: np.ndarray
    speed_hold: np.ndarray
    follower: FollowerKernel


@numba.njit(**JIT)
def drive(drivers: DriverTables, b, t, states, out) -> tuple[int, int]:
    """The output of vehicle b's driver into ``out[b]``, as its class's kernel writes it at the
    times t (B,) [s] and plant states (B, NX). Returns the path follower's (status, value)
    (:func:`_follow_paths`), (DRIVEN, 0) for the others."""
    members = scratch((1,), np.int64)
    members[0] = b
    kind = drivers.kind[b]
    if kind == DriverKind.CONSTANT:
        _constant(drivers.constant, members, t, states, out)
    elif kind == DriverKind.STEP:
        _step(drivers.step, members, t, states, out)
    elif kind == DriverKind.SINE:
        _sine(drivers.sine, members, t, states, out)
    elif kind == DriverKind.RAMP:
        _ramp(drivers.ramp, members, t, states, out)
    elif kind == DriverKind.SINE_WITH_DWELL:
        _sine_with_dwell(drivers.sine_with_dwell, members, t, states, out)
    elif kind == DriverKind.SUM_OF_SINES:
        _sum_of_sines(drivers.sum_of_sines, members, t, states, out)
    elif kind == DriverKind.SPEED_HOLD:
        _speed_hold(drivers.speed_hold, members, t, states, out)
    else:
        return _follow_paths(drivers.follower, members, states, out)
    return DRIVEN, 0


#: each compiled class's table of a batch in which no vehicle has it (no rows)
_NO_ROWS = {cls: np.zeros(0, dtype=cls.table_dtype()) for cls in COMPILED_DRIVERS}
#: the path followers' kernel of a batch without any (never read: no vehicle has PATH_FOLLOWER)
_NO_FOLLOWERS = FollowerKernel(
    np.zeros((0, 2)), np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 1, 4)), np.zeros((0, 1)),
    1.0, 1.0, 1.0,
)  # fmt: skip


class DriverBatch:
    """The drivers of B vehicles (steering profiles, path followers or speed holders), evaluated
    together: the :class:`VectorisedDriver` s of one class (and parameter count) by one kernel
    call over a (B, k) parameter table that :meth:`replace` keeps up to date, the
    :class:`PathFollower` s of one car and preview by one :class:`PathFollowerBatch` call; any
    other callable (a user's function) one vehicle at a time."""

    def __init__(self, drivers: Sequence[Callable[[float, np.ndarray], float]]):
        self.drivers = list(drivers)
        self._keys: list[tuple | None] = [None] * len(self.drivers)  # None: called one by one
        self._tables: dict[tuple[type, int], np.ndarray] = {}
        self._followers: dict[tuple, PathFollowerBatch] = {}
        self.replace(range(len(self.drivers)), self.drivers)

    def replace(self, members: Sequence[int], drivers: Sequence[Callable[[float, np.ndarray], float]]) -> None:
        """Vehicles ``members`` get the new ``drivers`` (one each, in order)."""
        for b, driver in zip(members, drivers):
            self.drivers[b] = driver
            self._keys[b] = None
            if isinstance(driver, VectorisedDriver):
                self._keys[b] = key = (type(driver),)
                if key not in self._tables:
                    self._tables[key] = np.zeros(len(self.drivers), dtype=driver.table_dtype())
                self._tables[key][b] = driver.row()
            elif isinstance(driver, PathFollower):
                self._keys[b] = key = (PathFollower, driver.params, float(driver.preview_time), int(driver.points))
                if key not in self._followers:
                    self._followers[key] = PathFollowerBatch(*key[1:])
        self._members = {
            key: np.array([b for b, k in enumerate(self._keys) if k == key], dtype=np.int64)
            for key in [*self._tables, *self._followers]
        }
        for key, batch in self._followers.items():
            batch.replace({int(b): self.drivers[b] for b in self._members[key]})
        self._looped = np.array([b for b, k in enumerate(self._keys) if k is None], dtype=np.int64)
        self.compiled = self._compiled()
        if self.compiled:  # (the kinds and tables change only here; the path followers' responses as speeds come up)
            self._kind = np.array(
                [
                    DriverKind.PATH_FOLLOWER if key[0] is PathFollower else COMPILED_DRIVERS[key[0]]
                    for key in self._keys
                ],
                dtype=np.int64,
            )
            self._class_tables = [self._tables.get((cls,), _NO_ROWS[cls]) for cls in COMPILED_DRIVERS]

    def _compiled(self) -> bool:
        """Whether :meth:`kernel` has a form for this batch: every driver one of COMPILED_DRIVERS or
        a path follower, the followers of one preview."""
        classes = {key[0] for key in self._tables}
        return not len(self._looped) and len(self._followers) <= 1 and classes <= set(COMPILED_DRIVERS)

    def kernel(self) -> DriverTables:
        """This batch as :func:`drive` takes it (the tables themselves; the path followers' as they
        are now: their response table grows as speeds come up); only where :attr:`compiled`."""
        follower = next(iter(self._followers.values()), None)
        return DriverTables(self._kind, *self._class_tables, _NO_FOLLOWERS if follower is None else follower.kernel())

    def follower_lacking(self, b: int, tenths: int) -> PathFollowerBatch | None:
        """Vehicle b's path follower if it has no preview responses at ``tenths`` x 0.1 m/s (None
        if it has them, or vehicle b has no path follower)."""
        key = self._keys[b]
        follower = self._followers.get(key) if key is not None and key[0] is PathFollower else None
        if follower is None:
            return None
        rows = follower.response_row
        return follower if tenths >= len(rows) or rows[tenths] < 0 else None

    def __call__(self, t: np.ndarray, states: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Outputs (R,) of the drivers of vehicles ``rows`` (R,) (default: all B) from every
        vehicle's time t (B,) [s] and plant state (B, NX) (float64, C-contiguous)."""
        out = np.zeros(len(self.drivers))
        for key, members in self._members.items():
            if len(members):
                if key in self._followers:
                    self._followers[key](states, members, out)
                else:
                    key[0].kernel(self._tables[key], members, t, states, out)
        if len(self._looped):
            for b in self._looped if rows is None else np.intersect1d(self._looped, rows):
                out[b] = self.drivers[b](t[b], states[b])
        return out if rows is None else out[rows]

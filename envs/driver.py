"""Driver models: steering inputs (open-loop profiles and a path follower) and speed holding.

A driver sees the true pose and speed (it looks at the road and the speedometer); only the
stability controller is restricted to the estimator's output. Steering outputs are
steering-wheel angles [rad]; the scenario divides by the steering ratio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from envs.vehicle import GRAVITY, S_PSI, S_U, S_X, S_Y, VehicleParams

SWD_FREQUENCY = 0.7  #: FMVSS 126 sine-with-dwell frequency [Hz]
SWD_DWELL = 0.5  #: FMVSS 126 dwell at the second peak [s]


@dataclass(frozen=True)
class Constant:
    """A fixed steering-wheel angle [rad] from ``start`` [s]."""

    angle: float
    start: float = 0.0

    def __call__(self, t: float, state: np.ndarray) -> float:
        return self.angle if t >= self.start else 0.0


@dataclass(frozen=True)
class Step:
    """Step of ``angle`` [rad] at ``start`` [s] with a linear rise over ``rise_time`` [s]
    (ISO 7401 asks for a steering rate of 200-500 deg/s; 0.1 s for 1 rad is ~570 deg/s)."""

    angle: float
    start: float
    rise_time: float = 0.1

    def __call__(self, t: float, state: np.ndarray) -> float:
        return self.angle * min(max((t - self.start) / self.rise_time, 0.0), 1.0)


@dataclass(frozen=True)
class Sine:
    """``amplitude * sin(2 pi f (t - start))`` [rad] for ``cycles`` full periods from ``start``."""

    amplitude: float
    frequency: float
    start: float = 0.0
    cycles: float = math.inf

    def __call__(self, t: float, state: np.ndarray) -> float:
        phase = (t - self.start) * self.frequency
        if phase < 0.0 or phase > self.cycles:
            return 0.0
        return self.amplitude * math.sin(2.0 * math.pi * phase)


@dataclass(frozen=True)
class Ramp:
    """Slowly increasing steer: ``rate`` [rad/s] from ``start`` up to ``limit`` [rad]."""

    rate: float
    start: float = 0.0
    limit: float = math.inf

    def __call__(self, t: float, state: np.ndarray) -> float:
        value = self.rate * max(t - self.start, 0.0)
        return math.copysign(min(abs(value), self.limit), self.rate)


@dataclass(frozen=True)
class SineWithDwell:
    """FMVSS 126 / UN R13-H steering: a 0.7 Hz sine, held for 500 ms at its second peak.

    Starts at ``start`` [s] in the direction of ``amplitude``'s sign [rad]: the first peak at
    0.357 s, the second (opposite) peak reached at 1.0714 s and held until 1.5714 s, the
    last quarter cycle back to zero at 1.9286 s.
    """

    amplitude: float
    start: float = 1.0

    def __call__(self, t: float, state: np.ndarray) -> float:
        tau = t - self.start
        omega = 2.0 * math.pi * SWD_FREQUENCY
        three_quarters = 0.75 / SWD_FREQUENCY
        if tau <= 0.0:
            return 0.0
        if tau <= three_quarters:
            return self.amplitude * math.sin(omega * tau)
        if tau <= three_quarters + SWD_DWELL:
            return -self.amplitude
        tau -= SWD_DWELL
        if tau <= 1.0 / SWD_FREQUENCY:
            return self.amplitude * math.sin(omega * tau)
        return 0.0

    @property
    def end(self) -> float:
        """Time [s] at which the steering is back at zero (completion of steer)."""
        return self.start + 1.0 / SWD_FREQUENCY + SWD_DWELL


@dataclass(frozen=True)
class PathFollower:
    """Preview path-following driver on a polyline ``path`` (N, 2) global (X, Y) [m].

    Steering (road-wheel) angle = curvature feed-forward + error feedback on the kinematic
    bicycle model of the rear-axle point (Rajamani, *Vehicle Dynamics and Control*, 2nd ed.,
    2012, sec. 3.2; Snider, CMU-RI-TR-09-08, 2009):

    * feed-forward ``L * kappa(s + u * feedforward_time)``: the Ackermann angle of the path
      curvature a short preview ahead (covers the steering servo and tyre relaxation lag);
    * feedback ``-L * (e_y / l^2 + 2 zeta e_psi / l)`` with ``l = max(min_lookahead,
      preview_time * u)``: on the kinematic bicycle the lateral error ``e_y`` then obeys
      ``e_y'' + 2 zeta e_y' / l + e_y / l^2 = 0`` in distance travelled, a damped response
      over about one preview length (a pure-pursuit-like law without its corner cutting).

    Returns the steering-wheel angle ``ratio * delta`` [rad]. Beyond the path's end it holds
    the last segment's line. Defaults (4 m look-ahead up to 40 m/s, 50 ms feed-forward
    preview, damping 0.8) were chosen on the paper's lane change and slalom; the tight
    ISO 3888-2 course uses a 1.5 m look-ahead and 0.1 s preview (see envs.scenarios).
    """

    path: np.ndarray
    params: VehicleParams = field(default_factory=VehicleParams)
    preview_time: float = 0.1
    min_lookahead: float = 4.0
    feedforward_time: float = 0.05
    damping: float = 0.8
    _arclength: np.ndarray = field(init=False, repr=False, compare=False)
    _heading: np.ndarray = field(init=False, repr=False, compare=False)
    _curvature: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        path = np.asarray(self.path, dtype=np.float64)
        if path.ndim != 2 or path.shape[1] != 2 or path.shape[0] < 3 or not np.all(np.isfinite(path)):
            raise ValueError(f"path must be a finite (N >= 3, 2) polyline, got shape {path.shape}")
        for name in ("preview_time", "min_lookahead", "damping"):
            if not getattr(self, name) > 0:
                raise ValueError(f"PathFollower.{name} must be > 0, got {getattr(self, name)!r}")
        seg = np.hypot(*np.diff(path, axis=0).T)
        if np.any(seg <= 0):
            raise ValueError("path has repeated points")
        arclength = np.concatenate([[0.0], np.cumsum(seg)])
        heading = np.unwrap(np.arctan2(np.gradient(path[:, 1], arclength), np.gradient(path[:, 0], arclength)))
        object.__setattr__(self, "path", path)
        object.__setattr__(self, "_arclength", arclength)
        object.__setattr__(self, "_heading", heading)
        object.__setattr__(self, "_curvature", np.gradient(heading, arclength))

    def __call__(self, t: float, state: np.ndarray) -> float:
        p = self.params
        psi = state[S_PSI]
        rear = np.array([state[S_X] - p.cg_to_rear * math.cos(psi), state[S_Y] - p.cg_to_rear * math.sin(psi)])
        nearest = int(np.argmin(np.sum((self.path - rear) ** 2, axis=1)))
        # project onto the neighbouring segment for a smooth arclength and lateral error
        k = min(max(nearest, 0), len(self.path) - 2)
        chord = self.path[k + 1] - self.path[k]
        along = float(np.dot(rear - self.path[k], chord) / np.dot(chord, chord))
        s = self._arclength[k] + along * (self._arclength[k + 1] - self._arclength[k])
        heading = float(np.interp(s, self._arclength, self._heading))
        foot = self.path[k] + along * chord
        offset = rear - foot
        e_y = -math.sin(heading) * offset[0] + math.cos(heading) * offset[1]
        e_psi = math.remainder(psi - heading, 2 * math.pi)
        speed = abs(state[S_U])
        lookahead = max(self.min_lookahead, self.preview_time * speed)
        kappa = float(np.interp(s + speed * self.feedforward_time, self._arclength, self._curvature,
                                right=0.0))
        delta = p.wheelbase * (kappa - e_y / lookahead**2 - 2 * self.damping * e_psi / lookahead)
        return p.steering_ratio * delta


@dataclass(frozen=True)
class SpeedHold:
    """Speed-holding longitudinal driver: equal torques on all four wheels [N m].

    Proportional control on speed error with a feed-forward of rolling resistance and drag:
    ``F = m k (v_target - u) + f m g + 0.5 rho CdA u^2``, split equally and limited to the
    motors. From ``coast_after`` [s] on, the driver lifts off (zero torque: coasting, as FMVSS
    126 and ISO 3888-2 prescribe once the manoeuvre starts).
    """

    target_speed: float
    params: VehicleParams = field(default_factory=VehicleParams)
    gain: float = 1.0  #: [1/s]
    coast_after: float = math.inf

    def __call__(self, t: float, state: np.ndarray) -> float:
        if t >= self.coast_after:
            return 0.0
        p = self.params
        u = state[S_U]
        force = (p.mass * self.gain * (self.target_speed - u) + p.rolling_resistance * p.mass * GRAVITY
                 + 0.5 * p.air_density * p.drag_area * u * abs(u))
        torque = force * p.wheel_radius / 4.0
        return min(max(torque, -p.motor_peak_torque), p.motor_peak_torque)

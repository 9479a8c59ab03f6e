"""Vehicle sensors: IMU, wheel speeds, steering angles and motor torques, with seeded noise,
turn-on bias and injectable faults.

All channels are sampled at 500 Hz (every 2 ms plant step). Noise is white Gaussian; each
run draws a constant turn-on bias per channel from N(0, bias_std). Default magnitudes:

* accelerometers: noise 0.02 m/s^2 std at 500 Hz, bias 0.03 m/s^2 std. Automotive ESC-grade
  MEMS accelerometers list a noise density of ~100-150 ug/sqrt(Hz), i.e. ~0.015-0.023 m/s^2 over
  a 250 Hz bandwidth; the residual offset after the ESC's zero-point learning is a few mg;
* gyro: noise 0.004 rad/s std (0.23 deg/s) at 500 Hz, bias 0.002 rad/s std (0.1 deg/s): a
  rate noise density of ~0.01 deg/s/sqrt(Hz) and ~0.1 deg/s offset after on-line compensation;
* wheel speeds: 0.05 rad/s std (active Hall sensor on a 48-tooth tone wheel: period
  measurement jitter of ~0.2% at 80 km/h), no bias;
* road-wheel steering angles: front 1.1e-4 rad std (0.1 deg steering-wheel resolution over a
  ratio of 16), rear actuator encoder 1e-4 rad std, no bias;
* motor torques (estimated from phase currents by the inverter): 2 N m std, 2 N m bias std.

These are the DESIGN's reference magnitudes; :meth:`SensorParams.scaled` scales all of them.

Faults (:class:`Fault`) act on one channel over a time window: ``spike`` outliers (Poisson
arrivals at ``rate`` [1/s], +/-``magnitude``), ``dropout`` (no data: ``valid`` is False and
the last valid value is held so no NaN ever leaves the sensor), ``stuck`` (the value freezes
at the window start; the sensor still reports valid), ``bias_step`` (``magnitude`` added).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

#: Channel order of every reading (13 channels).
CHANNELS = ("ax", "ay", "yaw_rate", "omega_fl", "omega_fr", "omega_rl", "omega_rr", "delta_f", "delta_r",
            "torque_fl", "torque_fr", "torque_rl", "torque_rr")
FAULT_KINDS = ("spike", "dropout", "stuck", "bias_step")


def _per_channel(accel: float, gyro: float, wheel: float, steer_f: float, steer_r: float, torque: float) -> tuple:
    return (accel, accel, gyro, wheel, wheel, wheel, wheel, steer_f, steer_r, torque, torque, torque, torque)


@dataclass(frozen=True)
class SensorParams:
    """Noise std and turn-on bias std per channel (units of each channel: m/s^2, rad/s, rad, N m)."""

    noise_std: tuple[float, ...] = field(
        default=_per_channel(accel=0.02, gyro=0.004, wheel=0.05, steer_f=1.1e-4, steer_r=1e-4, torque=2.0))
    bias_std: tuple[float, ...] = field(
        default=_per_channel(accel=0.03, gyro=0.002, wheel=0.0, steer_f=0.0, steer_r=0.0, torque=2.0))
    sample_time: float = 0.002  #: sampling period [s] (500 Hz)

    def __post_init__(self) -> None:
        for name in ("noise_std", "bias_std"):
            values = np.asarray(getattr(self, name), dtype=float)
            if values.shape != (len(CHANNELS),) or not np.all(np.isfinite(values)) or np.any(values < 0):
                raise ValueError(f"SensorParams.{name} must be {len(CHANNELS)} finite values >= 0, got {values}")
        if not (math.isfinite(self.sample_time) and self.sample_time > 0):
            raise ValueError(f"SensorParams.sample_time must be > 0, got {self.sample_time!r}")

    def scaled(self, factor: float) -> "SensorParams":
        """These sensors with noise and bias scaled by ``factor`` (0 gives perfect sensors)."""
        if not (math.isfinite(factor) and factor >= 0):
            raise ValueError(f"noise scale factor must be >= 0, got {factor!r}")
        return SensorParams(tuple(factor * s for s in self.noise_std), tuple(factor * s for s in self.bias_std),
                            self.sample_time)


@dataclass(frozen=True)
class Fault:
    """A fault of ``kind`` on ``channel`` during ``start`` <= t < ``end`` [s].

    ``magnitude``: spike size or bias step (channel units); ``rate``: spike arrivals [1/s]."""

    channel: str
    kind: str
    start: float = 0.0
    end: float = math.inf
    magnitude: float = 0.0
    rate: float = 0.0

    def __post_init__(self) -> None:
        if self.channel not in CHANNELS:
            raise ValueError(f"unknown sensor channel {self.channel!r}; known: {list(CHANNELS)}")
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}; known: {list(FAULT_KINDS)}")
        if not (math.isfinite(self.start) and self.start >= 0 and self.end > self.start):
            raise ValueError(f"fault window must satisfy 0 <= start < end, got [{self.start!r}, {self.end!r})")
        if not math.isfinite(self.magnitude):
            raise ValueError(f"fault magnitude must be finite, got {self.magnitude!r}")
        if not (math.isfinite(self.rate) and self.rate >= 0):
            raise ValueError(f"fault rate must be >= 0 [1/s], got {self.rate!r}")
        if self.kind == "spike" and (self.rate == 0 or self.magnitude == 0):
            raise ValueError("a spike fault needs rate > 0 and magnitude != 0")

    @property
    def index(self) -> int:
        return CHANNELS.index(self.channel)


class SensorReading(NamedTuple):
    """One sample for B vehicles: ``values`` (B, 13), ``valid`` (B, 13) bool, time ``t`` [s]."""

    values: np.ndarray
    valid: np.ndarray
    t: float


class SensorModel:
    """Seeded sensors for a batch of ``batch_size`` vehicles; call :meth:`measure` once per sample."""

    def __init__(self, params: SensorParams, faults: tuple[Fault, ...], batch_size: int, rng: np.random.Generator):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size!r}")
        self.params = params
        self.faults = tuple(faults)
        self.batch_size = batch_size
        self.rng = rng
        self._noise = np.asarray(params.noise_std, dtype=float)
        self.bias = rng.standard_normal((batch_size, len(CHANNELS))) * np.asarray(params.bias_std, dtype=float)
        self._held = np.zeros((batch_size, len(CHANNELS)))
        self._frozen: dict[int, np.ndarray] = {}

    def measure(self, truth: np.ndarray, t: float) -> SensorReading:
        """Readings of the true quantities ``truth`` (B, 13) in :data:`CHANNELS` order at time ``t`` [s]."""
        truth = np.asarray(truth, dtype=float)
        if truth.shape != (self.batch_size, len(CHANNELS)):
            raise ValueError(f"sensor truth must have shape {(self.batch_size, len(CHANNELS))}, got {truth.shape}")
        if not np.all(np.isfinite(truth)):
            bad = CHANNELS[int(np.argwhere(~np.isfinite(truth))[0, 1])]
            raise ValueError(f"non-finite true value on sensor channel {bad!r}")
        values = truth + self.bias + self.rng.standard_normal(truth.shape) * self._noise
        valid = np.ones(truth.shape, dtype=bool)
        for n, fault in enumerate(self.faults):
            c = fault.index
            active = fault.start <= t < fault.end
            if fault.kind == "stuck":
                if not active:
                    self._frozen.pop(n, None)
                    continue
                values[:, c] = self._frozen.setdefault(n, values[:, c].copy())
            if not active:
                continue
            if fault.kind == "spike":
                hit = self.rng.random(self.batch_size) < fault.rate * self.params.sample_time
                values[:, c] += hit * fault.magnitude * self.rng.choice([-1.0, 1.0], self.batch_size)
            elif fault.kind == "bias_step":
                values[:, c] += fault.magnitude
            elif fault.kind == "dropout":
                values[:, c] = self._held[:, c]
                valid[:, c] = False
        self._held = np.where(valid, values, self._held)
        return SensorReading(values, valid, float(t))

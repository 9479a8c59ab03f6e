"""Vehicle sensors: IMU, wheel speeds, steering angles, motor torques and brake pressures, with
seeded noise, turn-on bias and injectable faults.

The simulated car has 17 sensors (:data:`SENSORS`); their readings fill the estimators' channel
layout (:data:`fourwis.core.types.CHANNELS`, 16 channels): each axle's one steering sensor
feeds the steer channels of both its wheels (the plant steers an axle's wheels in parallel),
each wheel's torque channel is its motor torque less the brake gain times its brake pressure
(:func:`fourwis.core.types.net_wheel_torque`, valid when both readings are), and the
forward-speed channel, for which the car has no sensor, is invalid (NaN).
All sensors are sampled at 500 Hz (every 2 ms plant step). Noise is white Gaussian; each
run draws a constant turn-on bias per channel from N(0, bias_std). Default magnitudes:

* accelerometers: noise 0.02 m/s^2 std at 500 Hz, bias 0.03 m/s^2 std. Automotive ESC-grade
  MEMS accelerometers list a noise density of ~100-150 ug/sqrt(Hz), i.e. ~0.015-0.023 m/s^2 over
  a 250 Hz bandwidth, and an offset of a few mg; the estimators learn what of it stays constant
  during a run in steady driving (estimation/joint.py, ZERO_POINT_*);
* gyro: noise 0.004 rad/s std (0.23 deg/s) at 500 Hz, bias 0.002 rad/s std (0.1 deg/s): a
  rate noise density of ~0.01 deg/s/sqrt(Hz) and ~0.1 deg/s offset after on-line compensation;
* wheel speeds: 0.05 rad/s std (active Hall sensor on a 48-tooth tone wheel: period
  measurement jitter of ~0.2% at 80 km/h), no bias;
* road-wheel steering angles: front 1.1e-4 rad std (0.1 deg steering-wheel resolution over a
  ratio of 16), rear actuator encoder 1e-4 rad std, no bias;
* motor torques (estimated from phase currents by the inverter): 2 N m std, 2 N m bias std;
* brake pressures (the hydraulic unit's pressure sensors, ~250 bar full scale at ~0.5%
  accuracy): 1e4 Pa (0.1 bar) std, 5e3 Pa bias std, i.e. 1.8 and 0.9 N m of brake torque; a
  reading below :data:`BRAKE_RELEASED_PRESSURE` counts as a released brake in the net torque.

The first 13 sensors (the car's before it had brakes) draw their turn-on biases and noise from
the vehicle's generator exactly as they did then; the brake pressures draw theirs from a second
stream, the vehicle's generator jumped ahead (``bit_generator.jumped()``), so a run that never
brakes reads bit for bit what it read without the brake sensors.

These are the package's reference magnitudes (SensorParams' defaults); :meth:`SensorParams.scaled` scales
all of them.

Faults (:class:`Fault`) act on one channel over a time window: ``spike`` outliers (Poisson
arrivals at ``rate`` [1/s], +/-``magnitude``; each spike fault draws its own arrivals and
signs, so spikes on two channels are independent), ``dropout`` (no data: ``valid`` is False and
the last valid value is held so no NaN ever leaves the sensor), ``stuck`` (the value freezes
at the window start; the sensor still reports valid), ``bias_step`` (``magnitude`` added)
(docs/decisions/0019-frozen-sensor-check.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np

from fourwis.core.checks import member_rows  # (the readings' layout, which the estimators read)
from fourwis.core.kernels import JIT
from fourwis.core.types import CH_TORQUE, CHANNELS, N_CHANNELS, SensorReading
from fourwis.envs.layout import A_AX, A_AY, S_BRAKE, S_DELTA_F, S_DELTA_R, S_OMEGA, S_R, S_TORQUE
from fourwis.envs.vehicle import VehicleParams

FAULT_KINDS = ("spike", "dropout", "stuck", "bias_step")
#: the simulated car's sensors (noise, biases and faults are per sensor): accelerometers [m/s^2],
#: gyro [rad/s], wheel speeds [rad/s], the front and rear axles' road-wheel steer angles [rad],
#: motor torques [N m], brake pressures [Pa]
SENSORS = (
    "ax",
    "ay",
    "yaw_rate",
    "omega_fl",
    "omega_fr",
    "omega_rl",
    "omega_rr",
    "delta_f",
    "delta_r",
    "torque_fl",
    "torque_fr",
    "torque_rl",
    "torque_rr",
    "brake_fl",
    "brake_fr",
    "brake_rl",
    "brake_rr",
)
N_SENSORS = len(SENSORS)
S_TORQUE_SENSOR, S_BRAKE_SENSOR = SENSORS.index("torque_fl"), SENSORS.index("brake_fl")  #: first of each group
#: a brake-pressure reading below this [Pa] (1 bar, ~18 N m of brake torque) counts as a released
#: brake, no torque, in the net torque channel: an ECU's zero-offset deadband, ~9 std of a released
#: brake's reading (noise 0.1 bar, bias 0.05 bar), so its sensor noise never reaches the estimators
BRAKE_RELEASED_PRESSURE = 1.0e5
#: the sensor (index into SENSORS) whose reading fills each channel of CHANNELS, -1 for none
SENSOR_OF_CHANNEL = np.array(
    [SENSORS.index(c) if c in SENSORS else SENSORS.index(f"delta_{c[-2]}") if c.startswith("delta_") else -1
     for c in CHANNELS],
    dtype=np.int64,
)  # fmt: skip
CHANNEL_PRESENT = SENSOR_OF_CHANNEL >= 0  #: the channels the simulated car has a sensor for (N_CHANNELS,) bool
#: the channel each sensor's reading appears in first (for the steer sensors: their axle's left
#: wheel; for the brake pressures: their wheel's net torque)
CHANNEL_OF_SENSOR = np.array(
    [int(np.flatnonzero(SENSOR_OF_CHANNEL == s)[0]) if s < S_BRAKE_SENSOR else CH_TORQUE + s - S_BRAKE_SENSOR
     for s in range(N_SENSORS)]
)  # fmt: skip


def _per_channel(
    accel: float, gyro: float, wheel: float, steer_f: float, steer_r: float, torque: float, brake: float
) -> tuple:
    return (accel, accel, gyro, *(wheel,) * 4, steer_f, steer_r, *(torque,) * 4, *(brake,) * 4)


@numba.njit(inline="always", **JIT)
def to_channels(sensed: np.ndarray, values: np.ndarray, valid: np.ndarray, brake_gain: float) -> None:
    """One car's valid sensor readings ``sensed`` (N_SENSORS,) into its channel row ``values``
    and ``valid`` (N_CHANNELS,) (the :data:`SENSOR_OF_CHANNEL` map; a channel without a sensor:
    NaN, invalid; the torque channels net of ``brake_gain`` [N m/Pa] x the brake pressure where it
    reads at least :data:`BRAKE_RELEASED_PRESSURE`)."""
    for c in range(values.shape[0]):
        s = SENSOR_OF_CHANNEL[c]
        if s < 0:
            values[c], valid[c] = math.nan, False
        else:
            values[c], valid[c] = sensed[s], True
    for w in range(4):
        pressure = sensed[S_BRAKE_SENSOR + w]
        if pressure >= BRAKE_RELEASED_PRESSURE:
            values[CH_TORQUE + w] -= brake_gain * pressure


@numba.njit(**JIT)
def _channel_rows(sensed: np.ndarray, values: np.ndarray, valid: np.ndarray, brake_gain: float) -> None:
    """:func:`to_channels` of each row of ``sensed`` (M, N_SENSORS) into ``values``, ``valid`` (M, N_CHANNELS)."""
    for i in range(sensed.shape[0]):
        to_channels(sensed[i], values[i], valid[i], brake_gain)


@dataclass(frozen=True)
class SensorParams:
    """Noise std and turn-on bias std per sensor of :data:`SENSORS` (units of each: m/s^2, rad/s,
    rad, N m, Pa)."""

    noise_std: tuple[float, ...] = field(
        default=_per_channel(accel=0.02, gyro=0.004, wheel=0.05, steer_f=1.1e-4, steer_r=1e-4, torque=2.0, brake=1e4)
    )
    bias_std: tuple[float, ...] = field(
        default=_per_channel(accel=0.03, gyro=0.002, wheel=0.0, steer_f=0.0, steer_r=0.0, torque=2.0, brake=5e3)
    )
    sample_time: float = 0.002  #: sampling period [s] (500 Hz)

    def __post_init__(self) -> None:
        for name in ("noise_std", "bias_std"):
            values = np.asarray(getattr(self, name), dtype=float)
            if values.shape != (N_SENSORS,) or not np.all(np.isfinite(values)) or np.any(values < 0):
                raise ValueError(f"SensorParams.{name} must be {N_SENSORS} finite values >= 0, got {values}")
        if not (math.isfinite(self.sample_time) and self.sample_time > 0):
            raise ValueError(f"SensorParams.sample_time must be > 0, got {self.sample_time!r}")

    def scaled(self, factor: float) -> SensorParams:
        """These sensors with noise and bias scaled by ``factor`` (0 gives perfect sensors)."""
        if not (math.isfinite(factor) and factor >= 0):
            raise ValueError(f"noise scale factor must be >= 0, got {factor!r}")
        return SensorParams(
            tuple(factor * s for s in self.noise_std), tuple(factor * s for s in self.bias_std), self.sample_time
        )


@dataclass(frozen=True)
class Fault:
    """A fault of ``kind`` on the sensor ``channel`` (a name of :data:`SENSORS`) during
    ``start`` <= t < ``end`` [s].

    ``magnitude``: spike size or bias step (channel units); ``rate``: spike arrivals [1/s]."""

    channel: str
    kind: str
    start: float = 0.0
    end: float = math.inf
    magnitude: float = 0.0
    rate: float = 0.0

    def __post_init__(self) -> None:
        if self.channel not in SENSORS:
            raise ValueError(f"unknown sensor channel {self.channel!r}; known: {list(SENSORS)}")
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
        """The sensor's index in :data:`SENSORS`."""
        return SENSORS.index(self.channel)


#: where each sensor's true value sits in the plant's diagnostics (sensors 0-1: ax, ay) and
#: state (sensors 2-16)
TRUE_AUX_COLUMNS = (A_AX, A_AY)
TRUE_STATE_COLUMNS = (
    S_R,
    S_OMEGA,
    S_OMEGA + 1,
    S_OMEGA + 2,
    S_OMEGA + 3,
    S_DELTA_F,
    S_DELTA_R,
    S_TORQUE,
    S_TORQUE + 1,
    S_TORQUE + 2,
    S_TORQUE + 3,
    S_BRAKE,
    S_BRAKE + 1,
    S_BRAKE + 2,
    S_BRAKE + 3,
)


class SensorSample(NamedTuple):
    """The car's sensors' readings for M vehicles: ``values`` (M, N_SENSORS) in :data:`SENSORS`
    order and units, ``valid`` (M, N_SENSORS) bool (False: a dropout, holding the last valid value)."""

    values: np.ndarray
    valid: np.ndarray


NOISE_BLOCK = 256  #: samples of noise each vehicle draws from its generator at a time


def brake_stream(rng: np.random.Generator) -> np.random.Generator:
    """The brake-pressure sensors' generator of a vehicle whose sensors draw from ``rng``: ``rng``'s
    bit generator jumped ahead (its state left as it was), so the other sensors' draws are the
    same as without brake sensors; a bit generator that cannot jump raises ValueError naming it."""
    bit_generator = rng.bit_generator
    if not hasattr(bit_generator, "jumped"):
        raise ValueError(
            f"sensor generators need a bit generator with jumped() (PCG64, PCG64DXSM, Philox, MT19937), "
            f"got {type(bit_generator).__name__}"
        )
    return np.random.Generator(bit_generator.jumped())


SENSED, BLOCK_USED_UP = -1, -2  #: statuses of noisy_readings (>= 0: a non-finite channel)


class SensorKernel(NamedTuple):
    """A :class:`SensorModel` as its compiled kernel takes it (the arrays themselves, updated in
    place): each vehicle's turn-on bias (B, N_SENSORS), its block of standard normal draws (B,
    NOISE_BLOCK, N_SENSORS), the noise standard deviation per sensor (N_SENSORS,), each
    vehicle's cursor into its block (B,) int64 and the brakes' gain [N m/Pa] (the net torque
    channels)."""

    bias: np.ndarray
    normal: np.ndarray
    noise_std: np.ndarray
    cursor: np.ndarray
    brake_gain: float


@numba.njit(**JIT)
def noisy_readings(sensors: SensorKernel, truth: np.ndarray, rows: np.ndarray, values: np.ndarray) -> int:
    """values[i] = truth[i] + bias[rows[i]] + normal[rows[i], cursor[rows[i]]] * noise_std, advancing
    each row's cursor: truth, values (M, N_SENSORS), per sensor. Returns SENSED; or, writing
    nothing, the first sensor of a non-finite truth value, or BLOCK_USED_UP when a row's noise
    block is exhausted (refill and call again)."""
    bias, normal, noise, cursor, _ = sensors
    for i in range(truth.shape[0]):
        for c in range(truth.shape[1]):
            if not np.isfinite(truth[i, c]):
                return c
        if cursor[rows[i]] >= NOISE_BLOCK:
            return BLOCK_USED_UP
    for i in range(truth.shape[0]):
        b = rows[i]
        k = cursor[b]
        for c in range(truth.shape[1]):
            values[i, c] = truth[i, c] + bias[b, c] + normal[b, k, c] * noise[c]
        cursor[b] = k + 1
    return SENSED


class SensorModel:
    """Seeded sensors for a batch of ``batch_size`` vehicles; call :meth:`measure` once per sample.

    Every vehicle has its own random stream (``rng``: one generator per vehicle, or one
    generator that is used as is for a single vehicle and spawned into ``batch_size``
    children otherwise), drawn in blocks of :data:`NOISE_BLOCK` samples, so a vehicle's
    readings do not depend on the batch it runs in: a vector env of N cars reproduces N
    single-car runs bit for bit. :meth:`reset_members` restarts chosen vehicles. ``brake_gain``
    [N m/Pa]: the car's (:attr:`fourwis.envs.vehicle.VehicleParams.brake_gain`), for the net torque
    channels.
    """

    def __init__(
        self,
        params: SensorParams,
        faults: tuple[Fault, ...],
        batch_size: int,
        rng: np.random.Generator | Sequence[np.random.Generator],
        brake_gain: float = VehicleParams.brake_gain,
    ):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size!r}")
        if not (math.isfinite(brake_gain) and brake_gain >= 0):
            raise ValueError(f"brake_gain must be a finite number >= 0 [N m/Pa], got {brake_gain!r}")
        self.brake_gain = float(brake_gain)
        self.params = params
        self.faults = tuple(faults)
        for fault in self.faults:
            if not isinstance(fault, Fault):
                raise ValueError(f"faults must be envs.sensors.Fault objects, got {fault!r}")
        self.batch_size = batch_size
        self._noise = np.asarray(params.noise_std, dtype=float)
        self._bias_std = np.asarray(params.bias_std, dtype=float)
        n = N_SENSORS
        self.bias = np.zeros((batch_size, n))
        self._normal = np.zeros((batch_size, NOISE_BLOCK, n))
        # per sample, an (arrival, sign) draw for each spike fault (one pair with none, so that
        # the stream of a run with at most one spike fault does not depend on its faults)
        self._spike_column = {n: k for k, n in enumerate(n for n, f in enumerate(self.faults) if f.kind == "spike")}
        self._uniform = np.zeros((batch_size, NOISE_BLOCK, max(1, len(self._spike_column)), 2))
        self._cursor = np.zeros(batch_size, dtype=np.int64)
        self._held = np.zeros((batch_size, n))
        self._frozen = np.zeros((len(self.faults), batch_size))
        self._is_frozen = np.zeros((len(self.faults), batch_size), dtype=bool)
        if isinstance(rng, np.random.Generator):
            rng = [rng] if batch_size == 1 else rng.spawn(batch_size)
        self.rngs: list[np.random.Generator] = [None] * batch_size  # type: ignore[list-item]
        #: each vehicle's brake-pressure stream (module docstring)
        self.brake_rngs: list[np.random.Generator] = [None] * batch_size  # type: ignore[list-item]
        self.reset_members(np.ones(batch_size, dtype=bool), list(rng))

    def reset_members(self, mask: np.ndarray, rngs: Sequence[np.random.Generator]) -> None:
        """Restart the vehicles selected by ``mask`` (B,) bool with new generators (one per
        selected vehicle, in order): new turn-on bias, no held or frozen values."""
        members = np.flatnonzero(mask)
        if len(rngs) != len(members):
            raise ValueError(f"need one generator per reset vehicle ({len(members)}), got {len(rngs)}")
        for b, rng in zip(members, rngs):
            self.rngs[b], self.brake_rngs[b] = rng, brake_stream(rng)
            self.bias[b, :S_BRAKE_SENSOR] = rng.standard_normal(S_BRAKE_SENSOR) * self._bias_std[:S_BRAKE_SENSOR]
            self.bias[b, S_BRAKE_SENSOR:] = (
                self.brake_rngs[b].standard_normal(N_SENSORS - S_BRAKE_SENSOR) * self._bias_std[S_BRAKE_SENSOR:]
            )
            self.refill(b)
        self._held[members] = 0.0
        self._is_frozen[:, members] = False

    def kernel(self) -> SensorKernel:
        """These sensors as :func:`noisy_readings` takes them (the arrays themselves)."""
        return SensorKernel(self.bias, self._normal, self._noise, self._cursor, self.brake_gain)

    def refill(self, b: int) -> None:
        """Draw vehicle b's next block of NOISE_BLOCK samples from its generator."""
        rng = self.rngs[b]
        self._normal[b, :, :S_BRAKE_SENSOR] = rng.standard_normal((NOISE_BLOCK, S_BRAKE_SENSOR))
        self._uniform[b] = rng.random(self._uniform.shape[1:])
        self._normal[b, :, S_BRAKE_SENSOR:] = self.brake_rngs[b].standard_normal(
            (NOISE_BLOCK, N_SENSORS - S_BRAKE_SENSOR)
        )
        self._cursor[b] = 0

    def measure(self, truth: np.ndarray, t: float | np.ndarray, members: np.ndarray | None = None) -> SensorReading:
        """Readings (M, N_CHANNELS) in :data:`CHANNELS` order of the true quantities ``truth``
        (M, N_SENSORS) in :data:`SENSORS` order at time ``t`` [s] (scalar, or (M,) when the
        vehicles' clocks differ) for the vehicles ``members`` (M,) indices (all B vehicles if
        None): :meth:`channels` of :meth:`read`. Each vehicle's stream advances by one sample."""
        return self.channels(self.read(truth, t, members), t)

    def channels(self, sensed: SensorSample, t: float | np.ndarray) -> SensorReading:
        """The channel layout (:data:`CHANNELS`) of the sensors' readings ``sensed`` (M rows) at
        time ``t`` [s] (scalar or (M,))."""
        values, valid = sensed
        t = np.full(len(values), t, dtype=float) if np.ndim(t) == 0 else np.asarray(t, dtype=float)
        channels, present = np.empty((len(values), N_CHANNELS)), np.empty((len(values), N_CHANNELS), dtype=bool)
        _channel_rows(np.ascontiguousarray(values, dtype=float), channels, present, self.brake_gain)
        present &= valid[:, np.maximum(SENSOR_OF_CHANNEL, 0)]
        present[:, CH_TORQUE : CH_TORQUE + 4] &= valid[:, S_BRAKE_SENSOR : S_BRAKE_SENSOR + 4]
        return SensorReading(channels, present, t)

    def read(self, truth: np.ndarray, t: float | np.ndarray, members: np.ndarray | None = None) -> SensorSample:
        """The sensors' readings (M, N_SENSORS) in :data:`SENSORS` order, with faults, of the true
        quantities ``truth`` (M, N_SENSORS) at time ``t`` [s] for the vehicles ``members`` (as
        :meth:`measure`). Each vehicle's stream advances by one sample."""
        rows = member_rows(members, self.batch_size)
        truth = np.ascontiguousarray(truth, dtype=np.float64)
        if truth.shape != (len(rows), N_SENSORS):
            raise ValueError(f"sensor truth must have shape {(len(rows), N_SENSORS)}, got {truth.shape}")
        t = np.full(len(rows), t, dtype=float) if np.ndim(t) == 0 else np.asarray(t, dtype=float)
        if t.shape != (len(rows),):
            raise ValueError(f"time must be a scalar or have shape ({len(rows)},), got {t.shape}")
        values = np.empty(truth.shape)
        status = noisy_readings(self.kernel(), truth, rows, values)
        if status == BLOCK_USED_UP:
            for b in rows[self._cursor[rows] >= NOISE_BLOCK]:
                self.refill(b)
            status = noisy_readings(self.kernel(), truth, rows, values)
        if status >= 0:
            raise ValueError(f"non-finite true value on sensor channel {SENSORS[status]!r}")
        valid = np.ones(truth.shape, dtype=bool)
        if self.faults:  # the fault draws of the sample just taken (the cursor has moved past it)
            self._inject_faults(rows, t, values, valid, self._uniform[rows, self._cursor[rows] - 1])
        return SensorSample(values, valid)

    def _inject_faults(
        self, rows: np.ndarray, t: np.ndarray, values: np.ndarray, valid: np.ndarray, uniform: np.ndarray
    ) -> None:
        """Apply the faults active at ``t`` to the readings ``values``/``valid`` of ``rows`` in place;
        ``uniform`` (M, spike faults, 2): this sample's (arrival, sign) draws."""
        held = self._held[rows]
        for n, fault in enumerate(self.faults):
            c = fault.index
            active = (fault.start <= t) & (t < fault.end)
            if fault.kind == "stuck":
                frozen = np.where(active & ~self._is_frozen[n, rows], values[:, c], self._frozen[n, rows])
                self._frozen[n, rows], self._is_frozen[n, rows] = frozen, active
                values[:, c] = np.where(active, frozen, values[:, c])
            elif fault.kind == "spike":
                arrival, sign = uniform[:, self._spike_column[n]].T
                hit = active & (arrival < fault.rate * self.params.sample_time)
                values[:, c] += hit * fault.magnitude * np.where(sign < 0.5, -1.0, 1.0)
            elif fault.kind == "bias_step":
                values[:, c] += active * fault.magnitude
            elif fault.kind == "dropout":
                values[:, c] = np.where(active, held[:, c], values[:, c])
                valid[:, c] = ~active
        self._held[rows] = np.where(valid, values, held)

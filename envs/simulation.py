"""Closed-loop simulation of one scenario: driver, plant, sensors, estimator, controller.

Each 2 ms step (the paper's sample time): the sensors measure the plant, the estimator turns
the readings into an :class:`estimation.types.Estimate`, the driver gives steering and base
torques (from the true pose and speed), the stability controller (if any) corrects the
torques and rear steer using the estimate only, and the plant advances one RK4 step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from tqdm import tqdm

from fourwis.control import StabilityController
from fourwis.core.checks import check_command, check_controller, check_estimate, check_estimator, is_integer
from fourwis.core.types import Controller, Estimate, Estimator, SensorReading
from fourwis.envs import compiled_loop
from fourwis.envs.driver import DriverBatch
from fourwis.envs.road import RoadTables, contact_points
from fourwis.envs.scenarios import Scenario, make_scenario
from fourwis.envs.sensors import TRUE_AUX_COLUMNS, TRUE_STATE_COLUMNS, Fault, SensorModel, SensorParams
from fourwis.envs.vehicle import (
    A_AX,
    A_AY,
    A_FZ,
    A_MU,
    C_DELTA_F,
    C_DELTA_R,
    C_TORQUE,
    NU,
    S_R,
    S_U,
    S_V,
    check_lag_step,
    check_plant_step,
    derivatives,
    sideslip_angles,
    step,
)

DT = 0.002  #: physics, sensor and estimator step [s] (the paper samples at 2 ms)
SIMULATE_CHUNK = 250  #: steps :func:`simulate` advances per call (its progress bar moves by as many)


_MEASURED_AUX = np.array(TRUE_AUX_COLUMNS)  #: sensor channels 0-1 from the plant diagnostics
_MEASURED_STATE = np.array(TRUE_STATE_COLUMNS)  #: sensor channels 2-12 from the plant state


def front_steer_command(steering_wheel: np.ndarray, params) -> np.ndarray:
    """The front road-wheel angle (B,) [rad] the driver's steering-wheel angle commands, within
    the steering's lock (``max_front_steer``): the angle the servo is sent, and what the
    controller, its allocator's lever arms and the references see (a steering wheel turned
    past the lock does not steer the wheels further)."""
    delta = np.asarray(steering_wheel, dtype=float) / params.steering_ratio
    return np.minimum(np.maximum(delta, -params.max_front_steer), params.max_front_steer)  # (np.clip: 2x the time)


def sensor_truth(state: np.ndarray, aux: np.ndarray) -> np.ndarray:
    """The 13 measured quantities (B, 13) in :data:`envs.sensors.CHANNELS` order from plant state/aux."""
    truth = np.empty((len(state), 13))
    truth[:, :2] = aux[:, _MEASURED_AUX]
    truth[:, 2:] = state[:, _MEASURED_STATE]
    return truth


_TRUTH_STATE = np.array([S_U, S_V, S_R])
_TRUTH_AUX = np.array([A_AX, A_AY, *range(A_MU, A_MU + 4), *range(A_FZ, A_FZ + 4)])


def true_estimate(state: np.ndarray, aux: np.ndarray) -> Estimate:
    """The truth in estimator form: what a perfect estimator would report (fields are views of
    two fresh arrays, never of ``state`` or ``aux``)."""
    body, diag = state[:, _TRUTH_STATE], aux[:, _TRUTH_AUX]
    u, v = body[:, 0], body[:, 1]
    zeros = np.zeros((len(state), 5))
    return Estimate(
        u=u,
        v=v,
        beta=sideslip_angles(u, v),
        r=body[:, 2],
        ax=diag[:, 0],
        ay=diag[:, 1],
        mu=diag[:, 2:6],
        fz=diag[:, 6:10],
        beta_std=zeros[:, 0],
        mu_std=zeros[:, 1:],
    )


class Trajectory(NamedTuple):
    """Time series of one run (time-major, no batch axis).

    t (T,) [s]; state (T, NX) and aux (T, NAUX) of the plant (see envs.vehicle names);
    controls (T, NU) applied commands; steering_wheel (T,) driver's angle [rad];
    sensors (T, 13) and sensor_valid (T, 13) readings; truth and estimate: Estimate of (T,...)
    arrays; scenario: the Scenario run.
    """

    t: np.ndarray
    state: np.ndarray
    aux: np.ndarray
    controls: np.ndarray
    steering_wheel: np.ndarray
    sensors: np.ndarray
    sensor_valid: np.ndarray
    truth: Estimate
    estimate: Estimate
    scenario: Scenario


def _merged(full: np.ndarray, part: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """A copy of ``full`` with ``rows`` replaced by ``part``."""
    out = full.copy()
    out[rows] = part
    return out


def _rows(estimate: Estimate, rows: np.ndarray) -> Estimate:
    return Estimate(*(field[rows] for field in estimate))


class Sample(NamedTuple):
    """What a closed loop knows at its current time, before the controller acts (B vehicles).

    t (B,) [s]; reading: the sensors' :class:`envs.sensors.SensorReading`; truth and estimate
    (:class:`Estimate` of (B, ...)); steering_wheel (B,) driver's angle [rad]; front_steer (B,)
    the road-wheel angle it commands, within the lock (:func:`front_steer_command`) [rad];
    base_torques (B, 4) the speed-holding driver's wheel torques [N m].
    """

    t: np.ndarray
    reading: SensorReading
    truth: Estimate
    estimate: Estimate
    steering_wheel: np.ndarray
    front_steer: np.ndarray
    base_torques: np.ndarray


class StepRecord(NamedTuple):
    """One 2 ms sample of a closed loop of B vehicles, taken before the plant advances:
    t (B,), state (B, NX), aux (B, NAUX), controls (B, NU) applied, steering_wheel (B,),
    reading, truth, estimate. :meth:`ClosedLoop.advance_steps` returns n of them stacked in
    one: every array then has the leading axes (n, B) (the reading's and the Estimates' too)."""

    t: np.ndarray
    state: np.ndarray
    aux: np.ndarray
    controls: np.ndarray
    steering_wheel: np.ndarray
    reading: SensorReading
    truth: Estimate
    estimate: Estimate


def _stacked(records: list[StepRecord]) -> StepRecord:
    """One StepRecord of a list of them, stacked (leading axes (n, B))."""

    def stack(field: str, group: str | None = None) -> np.ndarray:
        return np.stack([getattr(getattr(r, group) if group else r, field) for r in records])

    return StepRecord(
        stack("t"),
        stack("state"),
        stack("aux"),
        stack("controls"),
        stack("steering_wheel"),
        SensorReading(*(stack(f, "reading") for f in SensorReading._fields)),
        Estimate(*(stack(f, "truth") for f in Estimate._fields)),
        Estimate(*(stack(f, "estimate") for f in Estimate._fields)),
    )


class ClosedLoop:
    """Driver + sensors + estimator + controller + plant for B vehicles, advanced 2 ms at a time.

    ``scenarios``: one :class:`Scenario` (B = 1) or a sequence (one per vehicle, all with the
    same vehicle parameters); each vehicle keeps its own clock, so :meth:`reset_members` can
    restart some of them mid-run (the vector env's autoreset). ``rng``: sensor noise and
    fault generators (see :class:`envs.sensors.SensorModel`). Used by :func:`simulate` (B = 1,
    records every sample) and the Gymnasium envs (an agent's command enters through
    ``controller``, which must then handle the batch; it is reset once, at construction).

    Each time instant is sensed once: :meth:`sample` measures and estimates (cached until
    the plant moves), :meth:`advance` applies the controller and integrates;
    :meth:`advance_steps` does both for several steps, compiled where it can.
    """

    def __init__(
        self,
        scenarios: Scenario | Sequence[Scenario],
        controller: Controller | str | None,
        estimator: Estimator | str | None,
        rng: np.random.Generator | Sequence[np.random.Generator],
        sensor_params: SensorParams | None = None,
        faults: Sequence[Fault] = (),
        dt: float = DT,
    ):
        try:
            self.scenarios = [scenarios] if isinstance(scenarios, Scenario) else list(scenarios)
        except TypeError:  # not iterable
            self.scenarios = []
        if not self.scenarios or not all(isinstance(s, Scenario) for s in self.scenarios):
            raise ValueError(f"scenarios must be a Scenario or a non-empty sequence of them, got {scenarios!r}")
        dt = check_plant_step(dt)
        sensor_params = SensorParams() if sensor_params is None else sensor_params
        if not isinstance(sensor_params, SensorParams):
            raise ValueError(f"sensor_params must be an envs.sensors.SensorParams or None, got {sensor_params!r}")
        if not math.isclose(sensor_params.sample_time, dt, rel_tol=1e-6):  # (a float32 dt too)
            raise ValueError(
                f"the sensors sample every {sensor_params.sample_time!r} s, the simulation steps at "
                f"dt = {dt!r} s: they are sampled once per step (give SensorParams(sample_time=dt))"
            )
        try:
            fault_list = tuple(faults)
        except TypeError:
            fault_list = (None,)
        if not all(isinstance(f, Fault) for f in fault_list):
            raise ValueError(f"faults must be a sequence of envs.sensors.Fault (empty for none), got {faults!r}")
        self.batch_size = len(self.scenarios)
        self.params = params = self.scenarios[0].vehicle_params
        self._check_params(self.scenarios)
        self._labels = (estimator, controller)  # how errors name a user's estimator and controller: as given
        if isinstance(estimator, str) or estimator is None:
            from fourwis.estimation import make_estimator

            estimator = make_estimator(estimator or "oracle", params, dt)
        else:
            check_estimator(estimator, estimator)
        from fourwis.estimation import Oracle, StateEstimator

        # fourwis's own estimators and controllers guard their outputs; anyone else's are
        # checked every step
        self._check_estimates = type(estimator) not in (Oracle, StateEstimator)
        self._needs_truth = bool(getattr(estimator, "needs_truth", False))
        if isinstance(controller, str):
            from fourwis.control import make_controller

            controller = make_controller(controller, params, dt)
        elif controller is not None:
            check_controller(controller, controller)
        ours = type(controller).__module__.startswith("fourwis.")
        self._check_commands = not ours
        # an estimator integrates over its dt; our controllers count their dt too (the DYC integrates over it, a
        # trained policy holds each action for control_dt / dt steps); a user's controller's dt is its own business
        for kind, part in (("estimator", estimator), ("controller", controller if ours else None)):
            part_dt = getattr(part, "dt", None)
            if part_dt is not None and not math.isclose(part_dt, dt, rel_tol=1e-12):
                raise ValueError(
                    f"the {kind} steps at dt = {part_dt!r} s, the simulation at {dt!r} s: build it with "
                    "the simulation's dt (it counts its own steps in it: the DYC integrates over them, "
                    "a trained policy holds each action for control_dt / dt of them)"
                )
        if getattr(controller, "rear_steer", False) and any(
            s.vehicle_params.rear_steer_feedforward for s in self.scenarios
        ):
            raise ValueError(
                "the controller steers the rear axle (eq. 20) and the scenario's "
                "rear_steer_feedforward would add the same law again: use one of them"
            )
        self.controller, self.estimator, self.dt = controller, estimator, dt
        self.sensors = SensorModel(sensor_params, fault_list, self.batch_size, rng)
        self.state = np.concatenate([s.initial_state() for s in self.scenarios])
        self.steering_drivers = DriverBatch([s.steering for s in self.scenarios])
        self.speed_drivers = DriverBatch([s.speed_driver() for s in self.scenarios])
        self.k = np.zeros(self.batch_size, dtype=np.int64)
        self._fresh = np.ones(self.batch_size, dtype=bool)  # estimator needs a reset
        self._stale = np.ones(self.batch_size, dtype=bool)  # needs sensing at the current time
        self._sample: Sample | None = None
        self._update_road()
        self.aux = self._diagnostics(np.arange(self.batch_size))
        if controller is not None:
            controller.reset()

    @property
    def scenario(self) -> Scenario:
        """The scenario of a single-vehicle loop."""
        if self.batch_size != 1:
            raise AttributeError("a batched loop has one scenario per vehicle: use .scenarios")
        return self.scenarios[0]

    @property
    def t(self) -> np.ndarray:
        """Each vehicle's time since its (re)start (B,) [s]."""
        return self.k * self.dt

    def _check_params(self, scenarios: Sequence[Scenario]) -> None:
        for s in scenarios:
            if s.vehicle_params != self.params:
                raise ValueError(
                    f"all vehicles of a batch need the same vehicle parameters; scenario {s.name!r} "
                    "differs (e.g. its rear-steer feed-forward switch)"
                )

    def _update_road(self) -> None:
        roads = [s.road for s in self.scenarios]
        self.road = (
            RoadTables.from_roads(roads, self.batch_size) if all(r.table() is not None for r in roads) else roads
        )

    def _diagnostics(self, rows: np.ndarray) -> np.ndarray:
        """Plant diagnostics (len(rows), NAUX) of vehicles ``rows`` at rest controls (the initial sample)."""
        state = self.state[rows]
        gx, gy = contact_points(state, self.params)
        mu = np.stack([self.scenarios[b].road.mu_at(gx[i], gy[i]) for i, b in enumerate(rows)])
        return derivatives(state, np.zeros((len(rows), NU)), mu, self.params)[1]

    def reset_members(
        self, mask: np.ndarray, scenarios: Sequence[Scenario], rngs: Sequence[np.random.Generator]
    ) -> None:
        """Restart the vehicles selected by ``mask`` (B,) bool on new ``scenarios`` with new sensor
        generators (one each, in order): fresh plant state, clock, sensors and estimator (and
        fourwis's DYC's memory of them). The other vehicles' current sample stands (each time
        instant is sensed once)."""
        members = np.flatnonzero(mask)
        if len(scenarios) != len(members):
            raise ValueError(f"need one scenario per reset vehicle ({len(members)}), got {len(scenarios)}")
        self._check_params(scenarios)
        for b, scenario in zip(members, scenarios):
            self.scenarios[b] = scenario
            self.state[b] = scenario.initial_state()[0]
        self.steering_drivers.replace(members, [s.steering for s in scenarios])
        self.speed_drivers.replace(members, [s.speed_driver() for s in scenarios])
        self.sensors.reset_members(mask, rngs)
        if isinstance(self.controller, StabilityController):
            self.controller.reset(mask)
        self.k[members] = 0
        self._fresh[members] = True
        self._stale[members] = True
        self._update_road()
        self.aux[members] = self._diagnostics(members)

    def sample(self) -> Sample:
        """Measure, estimate and drive at the current time: once per time instant and vehicle
        (cached; after :meth:`reset_members` only the restarted vehicles are sensed)."""
        n_stale = np.count_nonzero(self._stale)  # (count_nonzero: ~10x cheaper than .any() on small arrays)
        if not n_stale:
            return self._sample
        now = self.t
        if n_stale == self.batch_size:
            part, t, state, aux = None, now, self.state, self.aux
        else:
            rows = part = np.flatnonzero(self._stale)
            t, state, aux = now[rows], self.state[rows], self.aux[rows]
        reading = self.sensors.measure(sensor_truth(state, aux), t, part)
        truth = true_estimate(state, aux)
        steering = self.steering_drivers(now, self.state, part)
        base = np.repeat(self.speed_drivers(now, self.state, part)[:, None], 4, axis=1)
        if part is not None:  # merge into copies: records handed out earlier stay intact
            old = self._sample
            reading = SensorReading(*(_merged(full, new, rows) for full, new in zip(old.reading, reading)))
            truth = Estimate(*(_merged(full, new, rows) for full, new in zip(old.truth, truth)))
            steering, base = _merged(old.steering_wheel, steering, rows), _merged(old.base_torques, base, rows)
        if np.count_nonzero(self._fresh):
            speeds = np.array([s.speed for s in self.scenarios])
            self.estimator.reset(reading, speeds, None if self._fresh.all() else self._fresh.copy())
            self._fresh[:] = False
        if part is not None:
            estimate = self.estimator.step(reading, _rows(truth, rows) if self._needs_truth else None, rows)
        else:
            estimate = self.estimator.step(reading, truth if self._needs_truth else None)
        if self._check_estimates:  # and copied: records handed out earlier stay intact if it reuses its arrays
            check_estimate(estimate, self.batch_size if part is None else len(rows), self._labels[0])
            estimate = Estimate(*(np.array(field, dtype=float) for field in estimate))
        if part is not None:
            estimate = Estimate(*(_merged(full, new, rows) for full, new in zip(self._sample.estimate, estimate)))
        self._sample = Sample(now, reading, truth, estimate, steering, front_steer_command(steering, self.params), base)
        self._stale[:] = False
        return self._sample

    def _checked_moving(self, moving) -> np.ndarray | None:
        """``moving`` as an array if it is None or a bool array (B,); else ValueError naming it."""
        if moving is None:
            return None
        array = np.asarray(moving)
        if array.dtype != np.bool_ or array.shape != (self.batch_size,):
            raise ValueError(f"moving must be a bool array of shape ({self.batch_size},), got {moving!r}")
        return array

    def advance(self, integrate: bool = True, moving: np.ndarray | None = None) -> StepRecord:
        """Control at the current time from :meth:`sample`; then (if ``integrate``) advance the
        plant one step: every vehicle, or those selected by ``moving`` (B,) bool (the others
        keep their time, state and sample). Returns the sample taken before the plant moved."""
        moving = self._checked_moving(moving)
        s = self.sample()
        controls = np.zeros((self.batch_size, NU))
        controls[:, C_TORQUE : C_TORQUE + 4] = s.base_torques
        controls[:, C_DELTA_F] = s.front_steer
        if isinstance(self.controller, StabilityController):  # (held vehicles keep its memory, as when compiled)
            command = self.controller(s.t, s.estimate, controls[:, C_DELTA_F].copy(), s.base_torques.copy(), moving)
        elif self.controller is not None:
            command = self.controller(s.t, s.estimate, controls[:, C_DELTA_F].copy(), s.base_torques.copy())
            if self._check_commands:
                check_command(command, self.batch_size, self._labels[1])
        if self.controller is not None:
            controls[:, C_TORQUE : C_TORQUE + 4] = command.torques
            controls[:, C_DELTA_R] = command.rear_steer
        record = StepRecord(
            s.t, self.state.copy(), self.aux.copy(), controls, s.steering_wheel, s.reading, s.truth, s.estimate
        )
        if integrate:
            state, aux = step(self.state, controls, self.params, self.road, self.dt)
            if moving is None:
                self.state, self.aux = state, aux
                self.k += 1
                self._stale[:] = True
            else:
                self.state = np.where(moving[:, None], state, self.state)
                self.aux = np.where(moving[:, None], aux, self.aux)
                self.k += moving
                self._stale |= moving
        return record

    def advance_steps(self, n: int, moving: np.ndarray | None = None, records: bool = True) -> StepRecord | None:
        """:meth:`advance` ``n`` times (every vehicle, or those selected by ``moving`` (B,) bool),
        then :meth:`sample`; returns the steps' records, stacked (None if not ``records``). In one
        compiled call where the loop has a compiled form (:func:`envs.compiled_loop.supports`:
        fourwis's estimators, no controller, the envs' agent or fourwis's DYC, no sensor faults,
        table roads, built-in drivers, up to 32 cars), else step by step in Python; the two agree
        bit for bit, but for the rows of held vehicles, which the compiled path leaves NaN, and
        for errors: the compiled path skips held vehicles (the Python loop also allocates and
        integrates them, and discards the result; the DYC's memory of them stays in both) and
        raises the lowest failing vehicle's error, leaving the vehicles at different steps (reset
        them after an error)."""
        if not (is_integer(n) and n >= 1):
            raise ValueError(f"n must be a positive integer, got {n!r}")
        if not isinstance(records, (bool, np.bool_)):
            raise ValueError(f"records must be True or False, got {records!r}")
        moving = self._checked_moving(moving)
        if not compiled_loop.supports(self):
            steps = [self.advance(moving=moving) for _ in range(n)]
            self.sample()
            return _stacked(steps) if records else None
        check_lag_step(self.params, self.dt)
        old = self.sample()
        arrays = compiled_loop.Arrays(
            old.t.copy(),
            old.reading.values.copy(),
            old.reading.valid.copy(),
            compiled_loop.estimate_rows(old.truth),
            compiled_loop.estimate_rows(old.estimate),
            old.steering_wheel.copy(),
            old.front_steer.copy(),
            old.base_torques.copy(),
        )
        oracle = compiled_loop.reports_truth(self.estimator)
        try:
            rows = compiled_loop.advance(self, n, moving, arrays)
        except (ValueError, FloatingPointError):
            self._stale[:] = True  # (the next sample senses every vehicle where it stopped)
            raise
        truth = compiled_loop.rows_estimate(arrays.truth)
        estimate = truth if oracle else compiled_loop.rows_estimate(arrays.estimate)
        self._sample = Sample(
            arrays.t,
            SensorReading(arrays.readings, arrays.valid, arrays.t),
            truth,
            estimate,
            arrays.steering_wheel,
            arrays.front_steer,
            arrays.base_torques,
        )
        return compiled_loop.step_records(rows, oracle) if records else None


def simulate(
    scenario: Scenario | str,
    controller: Controller | str | None = None,
    estimator: Estimator | str | None = None,
    seed: int = 0,
    sensor_params: SensorParams | None = None,
    faults: Sequence[Fault] = (),
    dt: float = DT,
    progress: bool = False,
) -> Trajectory:
    """Run ``scenario`` once; returns the :class:`Trajectory`.

    ``controller``: a controller object, a name for :func:`control.make_controller`, or None
    (no stability control). ``estimator``: an estimator object, a name for
    :func:`estimation.make_estimator`, or None (the oracle: the controller sees the truth).
    ``seed`` seeds the sensor noise and faults. ``dt`` [s] at most :data:`envs.vehicle.MAX_DT`
    (10 ms); the sensors sample once per step, so another ``dt`` than 2 ms needs
    ``SensorParams(sample_time=dt)``. With fourwis's own estimators and controllers (or none),
    no sensor faults and a table friction map, the steps run compiled (:mod:`envs.compiled_loop`),
    with the same result.
    """
    if isinstance(scenario, str):
        scenario = make_scenario(scenario)
    if not (is_integer(seed) and seed >= 0):
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if not isinstance(progress, (bool, np.bool_)):
        raise ValueError(f"progress must be True or False, got {progress!r}")
    loop = ClosedLoop(scenario, controller, estimator, np.random.default_rng(seed), sensor_params, faults, dt)
    n = int(math.ceil(scenario.duration / dt - 1e-9))
    chunks = []
    with tqdm(total=n + 1, disable=not progress, desc=scenario.name, unit="step", mininterval=0.5) as bar:
        for start in range(0, n, SIMULATE_CHUNK):
            chunks.append(loop.advance_steps(min(SIMULATE_CHUNK, n - start)))
            bar.update(len(chunks[-1].t))
        chunks.append(_stacked([loop.advance(integrate=False)]))  # the last sample, where the run ends
        bar.update(1)

    def joined(part) -> np.ndarray:
        """The single vehicle's series of ``part`` (a function of a chunk) over the run."""
        return np.concatenate([part(chunk)[:, 0] for chunk in chunks])

    def estimates(group: str) -> Estimate:
        return Estimate(*(joined(lambda c, f=f: getattr(getattr(c, group), f)) for f in Estimate._fields))

    return Trajectory(
        np.arange(n + 1) * dt,
        joined(lambda c: c.state),
        joined(lambda c: c.aux),
        joined(lambda c: c.controls),
        joined(lambda c: c.steering_wheel),
        joined(lambda c: c.reading.values),
        joined(lambda c: c.reading.valid),
        estimates("truth"),
        estimates("estimate"),
        scenario,
    )

"""Closed-loop simulation: driver, plant, sensors, estimator and controller of B vehicles.

Each 2 ms step (the paper's sample time) runs the stages of :mod:`fourwis.envs.loop` in their
one order: the stability controller (if any) corrects the driver's torques and rear steer using
the estimate only, the plant advances one RK4 step, the sensors measure it, the estimator turns
the readings into an :class:`fourwis.core.types.Estimate`, and the drivers give steering and
base torques (from the true pose and speed). :class:`ClosedLoop` hands its components to that
loop (compiled bundles, or Python for a user's own) and serves the stages that run in Python.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from fourwis.control import StabilityController
from fourwis.control.allocation import allocation_error
from fourwis.control.dyc import inputs_row
from fourwis.control.esc import BrakeESC, outside_stable
from fourwis.control.wheel_slip import wheel_actuators
from fourwis.core.checks import check_command, check_controller, check_estimate, check_estimator, is_integer
from fourwis.core.progress import progress as progress_bar
from fourwis.core.types import Controller, Estimate, Estimator, SensorReading
from fourwis.envs import loop as compiled
from fourwis.envs.driver import DriverBatch, bad_follower_state
from fourwis.envs.layout import C_DELTA_F, C_DELTA_R, C_TORQUE, NAUX, NU, NX
from fourwis.envs.loop import (
    Call,
    Cars,
    HeldAction,
    NoControl,
    Parts,
    PlantStage,
    PythonStage,
    Sample,
    Stage,
    Status,
    StepRecord,
    measure_truths,
    new_records,
)
from fourwis.envs.road import RoadTables, contact_points
from fourwis.envs.scenarios import Scenario, make_scenario
from fourwis.envs.sensors import CHANNEL_PRESENT, N_SENSORS, SENSORS, Fault, SensorModel, SensorParams
from fourwis.envs.vehicle import (
    RK4_REAL_LIMIT,
    check_lag_step,
    check_plant_step,
    check_relaxation_step,
    derivatives,
    plant_error,
    step,
)
from fourwis.estimation.joint import StateEstimator, empty_estimate
from fourwis.estimation.oracle import Oracle

DT = 0.002  #: physics, sensor and estimator step [s] (the paper samples at 2 ms)
SIMULATE_CHUNK = 250  #: steps :func:`simulate` advances per call (its progress bar moves by as many)
#: largest batch whose plant steps car by car inside the compiled loop; beyond it the plant steps
#: the whole batch at once between the loop's other stages, in SIMD lanes of cars, at the price of
#: leaving the loop every 2 ms (car by car is faster up to 256 cars, slower at 1,024:
#: docs/decisions/0008-compiled-closed-loop-and-dyc.md)
PER_CAR_PLANT_MAX = 256


def truth_of(state: np.ndarray, aux: np.ndarray) -> tuple[np.ndarray, Estimate]:
    """The true measured quantities (B, N_SENSORS) in the order of the car's sensors
    (:data:`fourwis.envs.sensors.SENSORS`) and the truth in estimator form (what a perfect
    estimator would report) of plant states (B, NX) and their diagnostics (B, NAUX): the loop's
    own computation (:func:`fourwis.envs.loop.measure_truth`)."""
    state, aux = np.ascontiguousarray(state, dtype=float), np.ascontiguousarray(aux, dtype=float)
    sensed, truth = np.empty((len(state), N_SENSORS)), empty_estimate(len(state))
    measure_truths(state, aux, sensed, truth)
    return sensed, truth


class Trajectory(NamedTuple):
    """Time series of one run (time-major, no batch axis).

    t (T,) [s]; state (T, NX) and aux (T, NAUX) of the plant (:mod:`fourwis.envs.layout`);
    controls (T, NU) applied commands; steering_wheel (T,) driver's angle [rad];
    sensors (T, N_CHANNELS) and sensor_valid (T, N_CHANNELS) readings in the estimators' channel
    layout (:data:`fourwis.core.types.CHANNELS`); truth and estimate: Estimate of (T,...)
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


def kernel_parts(loop: ClosedLoop) -> Parts:
    """``loop``'s components as the compiled loop runs them: each one's own bundle where it has a
    compiled form (fourwis's estimators and controllers, the envs' agent, sensors without faults,
    table friction maps, the built-in drivers), else its :class:`fourwis.envs.loop.PythonStage`."""
    python = loop.python_stages
    estimator, controller = loop.estimator, loop.controller
    if type(estimator) is Oracle or (type(estimator) is StateEstimator and estimator.state is not None):
        estimator_part = (
            estimator.kernel()
        )  # (before its first reset a StateEstimator has no state: no vehicle reads it)
    else:
        estimator_part = python[Stage.ESTIMATE]
    kind = type(controller)  # (a subclass that changes the call but inherits kernel(): Python)
    if controller is None:
        controller_part = NoControl()
    elif kind in (StabilityController, BrakeESC):
        controller_part = controller.kernel(loop.batch_size)
    elif "kernel" in vars(kind) and "__call__" in vars(kind):
        controller_part = controller.kernel()
    else:
        controller_part = python[Stage.CONTROL]
    if isinstance(loop.road, RoadTables) and loop.batch_size <= PER_CAR_PLANT_MAX:
        params = loop.params
        speed = RK4_REAL_LIMIT * params.min_relaxation_length / loop.dt
        plant_part = PlantStage(params.kernel, loop.road, speed, params.contact_point_reach)
    else:
        plant_part = python[Stage.PLANT]
    sensors = python[Stage.SENSE] if loop.sensors.faults else loop.sensors.kernel()
    steering = loop.steering_drivers.kernel() if loop.steering_drivers.compiled else python[Stage.STEER]
    speed_part = loop.speed_drivers.kernel() if loop.speed_drivers.compiled else python[Stage.SPEED]
    return Parts(controller_part, plant_part, sensors, estimator_part, steering, speed_part, loop.actuators)


class ClosedLoop:
    """Driver + sensors + estimator + controller + plant for B vehicles, advanced 2 ms at a time.

    ``scenarios``: one :class:`Scenario` (B = 1) or a sequence (one per vehicle, all with the
    same vehicle parameters); each vehicle keeps its own clock, so :meth:`reset_members` can
    restart some of them mid-run (the vector env's autoreset). ``rng``: sensor noise and
    fault generators (see :class:`fourwis.envs.sensors.SensorModel`). Used by :func:`simulate`
    (B = 1, records every sample) and the Gymnasium envs (an agent's command enters through
    ``controller``, which must then handle the batch; it is reset once, at construction).

    Every step runs in :mod:`fourwis.envs.loop`, compiled, with the stages whose component is
    Python (a user's estimator or controller, sensor faults, a callable friction map, a user's
    driver, and the plant of batches beyond PER_CAR_PLANT_MAX) served here in one batched call
    each. Each time instant is sensed once: :meth:`sample` returns the current sample,
    :meth:`advance_steps` advances.
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
        slip_control: bool = True,
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
        if not isinstance(slip_control, (bool, np.bool_)):
            raise ValueError(f"slip_control must be True or False, got {slip_control!r}")
        #: the wheels' motors and brakes, with ABS and traction control if ``slip_control``
        self.actuators = wheel_actuators(params, self.batch_size, dt, abs=bool(slip_control), tcs=bool(slip_control))
        self._labels = (estimator, controller)  # how errors name a user's estimator and controller: as given
        if isinstance(estimator, str) or estimator is None:
            from fourwis.estimation import make_estimator

            estimator = make_estimator(estimator or "oracle", params, dt)
        else:
            check_estimator(estimator, estimator)
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
        self._check_estimates = type(estimator) not in (Oracle, StateEstimator)
        self._needs_truth = bool(getattr(estimator, "needs_truth", False))
        B = self.batch_size
        self.sensors = SensorModel(sensor_params, fault_list, B, rng, self.params.brake_gain)
        self.steering_drivers = DriverBatch([s.steering for s in self.scenarios])
        self.speed_drivers = DriverBatch([s.speed_driver() for s in self.scenarios])
        state = np.concatenate([s.initial_state() for s in self.scenarios])
        self.cars = Cars(
            state, np.zeros((B, NAUX)), np.zeros((B, NU)), np.zeros(B, dtype=np.int64), np.full(B, Stage.SENSE),
            np.ones(B, dtype=bool), np.zeros((B, N_SENSORS)), np.zeros(B),
        )  # fmt: skip
        reading = SensorReading(
            np.where(CHANNEL_PRESENT, 0.0, np.nan) * np.ones((B, 1)), np.tile(CHANNEL_PRESENT, (B, 1)), np.zeros(B)
        )
        self._sample = Sample(
            np.zeros(B), reading, empty_estimate(B), empty_estimate(B), np.zeros(B), np.zeros(B), np.zeros((B, 4))
        )
        #: the stages this loop serves in Python, each with its vehicles' served marks
        self.python_stages = {stage: PythonStage(np.zeros(B, dtype=bool)) for stage in compiled.STAGES}
        self._timing = compiled.Timing(dt, float(params.steering_ratio), float(params.max_front_steer))
        self._update_road()
        self.cars.aux[:] = self._diagnostics(np.arange(B))
        if controller is not None:
            controller.reset()

    @property
    def scenario(self) -> Scenario:
        """The scenario of a single-vehicle loop."""
        if self.batch_size != 1:
            raise AttributeError("a batched loop has one scenario per vehicle: use .scenarios")
        return self.scenarios[0]

    @property
    def state(self) -> np.ndarray:
        """Each vehicle's plant state (B, NX) (the loop's own array)."""
        return self.cars.state

    @property
    def aux(self) -> np.ndarray:
        """Each vehicle's plant diagnostics (B, NAUX) at its state."""
        return self.cars.aux

    @property
    def k(self) -> np.ndarray:
        """Each vehicle's steps since its (re)start (B,)."""
        return self.cars.k

    @property
    def fresh(self) -> np.ndarray:
        """Which vehicles' estimators are yet to be reset (B,) bool."""
        return self.cars.fresh

    @property
    def t(self) -> np.ndarray:
        """Each vehicle's time since its (re)start (B,) [s]."""
        return self.cars.k * self.dt

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
        state = self.cars.state[rows]
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
            self.cars.state[b] = scenario.initial_state()[0]
        self.steering_drivers.replace(members, [s.steering for s in scenarios])
        self.speed_drivers.replace(members, [s.speed_driver() for s in scenarios])
        self.sensors.reset_members(mask, rngs)
        if isinstance(self.controller, (StabilityController, BrakeESC)):
            self.controller.reset(mask)
        self.cars.k[members] = 0
        self._sample.t[members] = 0.0
        self.actuators.reference[members] = 0.0
        self.cars.fresh[members] = True
        self.cars.stage[members] = Stage.SENSE
        self._update_road()
        self.cars.aux[members] = self._diagnostics(members)

    def sample(self) -> compiled.Sample:
        """What the loop knows at the current time (a copy): measured, estimated and driven once
        per time instant and vehicle (after :meth:`reset_members` only the restarted vehicles)."""
        if np.any(self.cars.stage != Stage.CONTROL):
            self._run(0, None, final=False, keep=False)
        return _copied(self._sample)

    def _checked_moving(self, moving) -> np.ndarray | None:
        """``moving`` as an array if it is None or a bool array (B,); else ValueError naming it."""
        if moving is None:
            return None
        array = np.asarray(moving)
        if array.dtype != np.bool_ or array.shape != (self.batch_size,):
            raise ValueError(f"moving must be a bool array of shape ({self.batch_size},), got {moving!r}")
        return array

    def advance(self, integrate: bool = True, moving: np.ndarray | None = None) -> StepRecord:
        """One step: control at the current time and (if ``integrate``) advance the plant, every
        vehicle or those selected by ``moving`` (B,) bool (the others keep their time, state and
        sample). Returns the step's record (leading axis B), taken before the plant moved; without
        ``integrate`` the loop stays at this time instant (and controls it again next time)."""
        moving = self._checked_moving(moving)
        records = self._run(1 if integrate else 0, moving, final=not integrate, keep=True)
        return _index(records, 0)

    def advance_steps(self, n: int, moving: np.ndarray | None = None, records: bool = True) -> StepRecord | None:
        """:meth:`advance` ``n`` times (every vehicle, or those selected by ``moving`` (B,) bool);
        returns the steps' records, stacked (leading axes (n, B); a held vehicle's rows are NaN),
        or None if not ``records``. A failing vehicle raises the error of its failure (the
        lowest failing vehicle's of a batch); the vehicles then stand at different steps: reset
        them."""
        if not (is_integer(n) and n >= 1):
            raise ValueError(f"n must be a positive integer, got {n!r}")
        if not isinstance(records, (bool, np.bool_)):
            raise ValueError(f"records must be True or False, got {records!r}")
        moving = self._checked_moving(moving)
        out = self._run(int(n), moving, final=False, keep=bool(records))
        return out if records else None

    # ---- the loop ------------------------------------------------------------------------
    def _run(self, n: int, moving: np.ndarray | None, final: bool, keep: bool) -> StepRecord:
        """Run the vehicles selected by ``moving`` (all if None) ``n`` steps (and with ``final`` a
        control and record at the end); returns the records (empty unless ``keep``)."""
        B = self.batch_size
        check_lag_step(self.params, self.dt)
        call = Call(n, final, np.zeros(B, np.int64), np.zeros(B, np.int64), np.zeros(B, np.int64), np.zeros((B, NX)))
        cars = np.arange(B) if moving is None else np.flatnonzero(moving)
        records = new_records(n + final if keep else 0, B)
        while len(cars):
            compiled.run(cars, call, self.cars, self._sample, kernel_parts(self), self._timing, records)
            cars = cars[call.status[cars] != 0]  # (Status.DONE)
            self._serve(cars, call)
        return records

    def _serve(self, cars: np.ndarray, call: Call) -> None:
        """What Python does for the stopped vehicles ``cars``: refill noise, add preview responses,
        reset estimators and serve the Python stages, in the stages' order; or raise a failure."""
        status = call.status[cars]
        if (status >= _BAD_TRUTH).any():
            raise self._failure(int(cars[status >= _BAD_TRUTH].min()), call)
        for b in cars[status == _NEEDS_NOISE]:
            self.sensors.refill(b)
        for b in cars[status == _NEEDS_PREVIEW]:
            drivers = self.steering_drivers if self.cars.stage[b] == Stage.STEER else self.speed_drivers
            follower = drivers.follower_lacking(b, int(call.value[b]))
            if follower is not None:  # (None: added for another vehicle just now)
                follower.add_responses(int(call.value[b]))
        resets = status == _NEEDS_RESET
        if resets.any():
            self._reset_estimator(cars[resets])
        waiting = cars[status == _WAITING]
        if not len(waiting):
            return
        stages = self.cars.stage[waiting]
        for stage in np.unique(stages):  # (in the stages' order: Stage values are their places in STAGES)
            rows = waiting[stages == stage]
            _SERVERS[stage](self, rows)
            self.python_stages[stage].served[rows] = True

    def _reading(self) -> SensorReading:
        return SensorReading(*(field.copy() for field in self._sample.reading))

    def _reset_estimator(self, rows: np.ndarray) -> None:
        speeds = np.array([s.speed for s in self.scenarios])
        fresh = self.cars.fresh
        self.estimator.reset(self._reading(), speeds, None if fresh.all() else fresh.copy())
        fresh[:] = False

    def _serve_control(self, rows: np.ndarray) -> None:
        s = self._sample
        controls = self.cars.controls
        controls[rows] = 0.0
        controls[rows, C_TORQUE : C_TORQUE + 4] = s.base_torques[rows]
        controls[rows, C_DELTA_F] = s.front_steer[rows]
        if self.controller is None:
            return
        command = self.controller(s.t.copy(), _copied_estimate(s.estimate), s.front_steer.copy(), s.base_torques.copy())
        if self._check_commands:
            check_command(command, self.batch_size, self._labels[1])
        controls[rows, C_TORQUE : C_TORQUE + 4] = command.torques[rows]
        controls[rows, C_DELTA_R] = command.rear_steer[rows]

    def _serve_plant(self, rows: np.ndarray) -> None:
        road = self.road if isinstance(self.road, RoadTables) else [self.road[b] for b in rows]
        if isinstance(road, RoadTables) and len(rows) < self.batch_size:
            road = RoadTables(road.base_mu[rows], road.rects[rows], road.mu_given[rows], road.use_map)
        result = step(self.cars.state[rows], self.cars.controls[rows], self.params, road, self.dt)
        self.cars.state[rows], self.cars.aux[rows] = result.state, result.aux

    def _serve_sensors(self, rows: np.ndarray) -> None:
        partial = len(rows) < self.batch_size
        reading = self.sensors.measure(self.cars.sensed[rows], self._sample.t[rows], rows if partial else None)
        self._sample.reading.values[rows], self._sample.reading.valid[rows] = reading.values, reading.valid

    def _serve_estimator(self, rows: np.ndarray) -> None:
        partial = len(rows) < self.batch_size
        truth = _rows(self._sample.truth, rows) if self._needs_truth else None
        estimate = self.estimator.step(self._reading(), truth, rows if partial else None)
        if self._check_estimates:
            check_estimate(estimate, len(rows), self._labels[0])
        for target, value in zip(self._sample.estimate, estimate):
            target[rows] = value

    def _serve_steering(self, rows: np.ndarray) -> None:
        self._sample.steering_wheel[rows] = self.steering_drivers(self._sample.t, self.cars.state, rows)

    def _serve_speed(self, rows: np.ndarray) -> None:
        self.cars.drive_torque[rows] = self.speed_drivers(self._sample.t, self.cars.state, rows)

    def _failure(self, b: int, call: Call) -> Exception:
        """The error of vehicle b's failed stage (its status and value in ``call``)."""
        code, value = Status(call.status[b]), int(call.value[b])
        if code == Status.BAD_TRUTH:
            return ValueError(f"non-finite true value on sensor channel {SENSORS[value]!r}")
        if code == Status.ESTIMATOR_FAILED:
            return self.estimator.step_error(b, value, self._sample.reading.values[b])
        if code == Status.ALLOCATION_FAILED and isinstance(self.controller, StabilityController):
            return allocation_error(value, inputs_row(self.controller.kernel(self.batch_size).memory.inputs, b))
        if code == Status.ALLOCATION_FAILED:
            return allocation_error(value, _held_action_inputs(self.controller.kernel(), self._sample, b))
        if code == Status.TOO_FAST_FOR_RELAXATION:
            check_relaxation_step(self.cars.state[b : b + 1], self.params, self.dt)
        if code == Status.PLANT_FAILED:
            return plant_error(b, value, self.cars.state[b], self.cars.controls[b], call.reached[b])
        if code == Status.BAD_FOLLOWER_STATE:
            return bad_follower_state(b, self.cars.state[b])
        return RuntimeError(f"vehicle {b}: closed-loop status {code!r} ({value})")


#: the statuses :meth:`ClosedLoop._serve` reads, as plain integers (an enum's lookups cost on every step)
_WAITING, _NEEDS_NOISE, _NEEDS_PREVIEW, _NEEDS_RESET, _BAD_TRUTH = (
    int(s) for s in (Status.WAITING, Status.NEEDS_NOISE, Status.NEEDS_PREVIEW, Status.NEEDS_RESET, Status.BAD_TRUTH)
)
#: the Python server of each stage
_SERVERS = {
    Stage.CONTROL: ClosedLoop._serve_control,
    Stage.PLANT: ClosedLoop._serve_plant,
    Stage.SENSE: ClosedLoop._serve_sensors,
    Stage.ESTIMATE: ClosedLoop._serve_estimator,
    Stage.STEER: ClosedLoop._serve_steering,
    Stage.SPEED: ClosedLoop._serve_speed,
}


def _held_action_inputs(action: HeldAction, sample: Sample, b: int):
    """The allocator's inputs of a held yaw-moment action's failed step (vehicle b)."""
    from fourwis.control.allocation import AllocationInputs

    e, row = sample.estimate, slice(b, b + 1)
    rear = action.action[row, 1] * action.max_rear_steer if action.action.shape[1] == 2 else np.zeros(1)
    first = outside_stable(action.esc.settings, _rows(e, np.array([b])), sample.front_steer[row])
    return AllocationInputs(
        sample.base_torques[row], action.action[row, 0] * action.max_yaw_moment, e.fz[row], e.mu[row],
        np.zeros((1, 4)), e.u[row], sample.front_steer[row], rear, first,
    )  # fmt: skip


def _rows(estimate: Estimate, rows: np.ndarray) -> Estimate:
    return Estimate(*(field[rows] for field in estimate))


def _copied_estimate(estimate: Estimate) -> Estimate:
    return Estimate(*(field.copy() for field in estimate))


def _copied(sample: Sample) -> Sample:
    """A copy of ``sample`` (records and samples handed out stay as they were)."""
    return Sample(
        sample.t.copy(), SensorReading(*(field.copy() for field in sample.reading)), _copied_estimate(sample.truth),
        _copied_estimate(sample.estimate), sample.steering_wheel.copy(), sample.front_steer.copy(),
        sample.base_torques.copy(),
    )  # fmt: skip


def _index(records: StepRecord, i: int) -> StepRecord:
    """Step i of stacked ``records`` (leading axis B)."""
    return StepRecord(
        records.t[i], records.state[i], records.aux[i], records.controls[i], records.steering_wheel[i],
        SensorReading(*(field[i] for field in records.reading)), Estimate(*(field[i] for field in records.truth)),
        Estimate(*(field[i] for field in records.estimate)),
    )  # fmt: skip


def _stacked(records: list[StepRecord]) -> StepRecord:
    """One StepRecord of stacked records (leading axes (n, B)), along their first axis."""

    def join(parts):
        return np.concatenate(parts)

    return StepRecord(
        join([r.t for r in records]), join([r.state for r in records]), join([r.aux for r in records]),
        join([r.controls for r in records]), join([r.steering_wheel for r in records]),
        SensorReading(*(join([getattr(r.reading, f) for r in records]) for f in SensorReading._fields)),
        Estimate(*(join([getattr(r.truth, f) for r in records]) for f in Estimate._fields)),
        Estimate(*(join([getattr(r.estimate, f) for r in records]) for f in Estimate._fields)),
    )  # fmt: skip


def simulate(
    scenario: Scenario | str,
    controller: Controller | str | None = None,
    estimator: Estimator | str | None = None,
    seed: int = 0,
    sensor_params: SensorParams | None = None,
    faults: Sequence[Fault] = (),
    dt: float = DT,
    progress: bool = False,
    slip_control: bool = True,
) -> Trajectory:
    """Run ``scenario`` once; returns the :class:`Trajectory`.

    ``controller``: a controller object, a name for :func:`control.make_controller`, or None
    (no stability control). ``estimator``: an estimator object, a name for
    :func:`estimation.make_estimator`, or None (the oracle: the controller sees the truth).
    ``seed`` seeds the sensor noise and faults. ``dt`` [s] at most :data:`envs.vehicle.MAX_DT`
    (10 ms); the sensors sample once per step, so another ``dt`` than 2 ms needs
    ``SensorParams(sample_time=dt)``. ``slip_control`` switches ABS and traction control
    (:mod:`fourwis.control.wheel_slip`). With fourwis's own estimators and controllers (or none),
    no sensor faults and a table friction map, every stage runs compiled (:mod:`fourwis.envs.loop`).
    """
    if isinstance(scenario, str):
        scenario = make_scenario(scenario)
    if not (is_integer(seed) and seed >= 0):
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if not isinstance(progress, (bool, np.bool_)):
        raise ValueError(f"progress must be True or False, got {progress!r}")
    loop = ClosedLoop(
        scenario, controller, estimator, np.random.default_rng(seed), sensor_params, faults, dt, slip_control
    )
    n = int(math.ceil(scenario.duration / dt - 1e-9))
    chunks = []
    with progress_bar(n + 1, scenario.name, "step", disable=not progress, mininterval=0.5) as bar:
        for start in range(0, n, SIMULATE_CHUNK):
            chunks.append(loop.advance_steps(min(SIMULATE_CHUNK, n - start)))
            bar.update(len(chunks[-1].t))
        chunks.append(loop._run(0, None, final=True, keep=True))  # the last sample, where the run ends
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

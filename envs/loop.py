"""The closed loop's stages, in the one order every step runs them, as one compiled loop.

Each 2 ms step of each vehicle runs :data:`STAGES` in order: the controller's command (its net
wheel torques then turned into motor and brake commands by the wheels' actuators, with slip
control; and the step's record), one RK4 step of the plant, the sensors' reading (with the truth), the
estimator's step, the steering driver and the speed driver. Between two steps the vehicle rests
at CONTROL with its sample complete (what :meth:`fourwis.envs.simulation.ClosedLoop.sample`
returns).

Each stage is written once, here, and runs the component it is handed: a component with a
compiled form hands itself over as a named bundle (``component.kernel()``: the plant's
:class:`PlantStage`, the sensors' :class:`fourwis.envs.sensors.SensorKernel`, the estimator's
:class:`fourwis.estimation.joint.FilterKernel` or the oracle's, the controller's
:class:`fourwis.control.dyc.DycKernel`, :class:`fourwis.control.esc.EscKernel` or
:class:`HeldAction`, the drivers'
:class:`fourwis.envs.driver.DriverTables`); a component without one (a user's Python estimator
or controller, sensor faults, a callable friction map, a user's driver) is :class:`PythonStage`,
and the vehicle stops there: Python serves every vehicle waiting at that stage in one batched
call to the component and the loop resumes. A stage dispatches on its component's bundle type
when the loop compiles (:func:`fourwis.core.kernels.bundle_dispatch`), so the loop has no branch
on kinds at run time and compiles only the combinations a run uses.

Vehicles run one after another through their stages (shared among numba's thread count of
Python threads for batches of 2 or more); a vehicle also stops for Python to refill its sensor
noise, to add a path follower's preview responses, or to reset its estimator.
"""

from __future__ import annotations

import enum
import functools
import math
from typing import NamedTuple

import numba
import numpy as np
from numba.extending import register_jitable

from fourwis.control.allocation import Allocation, AllocationInputs, AllocatorLimits, allocation_kernel
from fourwis.control.dyc import DycKernel, stability_command
from fourwis.control.esc import EscKernel, esc_torques, unstable
from fourwis.control.wheel_slip import WheelActuators, actuate, reference_speeds
from fourwis.core.kernels import JIT, borrowed, bundle_dispatch, run_parallel, scratch
from fourwis.core.types import CH_AX, CH_OMEGA, N_CHANNELS, Estimate, SensorReading
from fourwis.envs.driver import DRIVEN, NEEDS_PREVIEW, DriverTables, drive
from fourwis.envs.layout import (
    A_AX,
    A_AY,
    A_FZ,
    A_MU,
    C_BRAKE,
    C_DELTA_F,
    C_DELTA_R,
    C_TORQUE,
    NAUX,
    NU,
    NX,
    S_R,
    S_U,
    S_V,
)
from fourwis.envs.road import RoadTables
from fourwis.envs.sensors import (
    BLOCK_USED_UP,
    N_SENSORS,
    TRUE_AUX_COLUMNS,
    TRUE_STATE_COLUMNS,
    SensorKernel,
    noisy_readings,
    to_channels,
)
from fourwis.envs.vehicle import BLOCK, Plant, advance_block, sideslip
from fourwis.estimation.joint import OK, FilterKernel, step_vehicles
from fourwis.estimation.oracle import TruthKernel


class Stage(enum.IntEnum):
    """The stages of a step, in their order (:data:`STAGES`)."""

    CONTROL = 0  #: the controller's command into the controls; the step's record
    PLANT = 1  #: one RK4 step of the plant; the clock advances
    SENSE = 2  #: the truth and the sensors' reading at the new state
    ESTIMATE = 3  #: the estimator's step on the reading (its reset first, for a new vehicle)
    STEER = 4  #: the steering driver: steering-wheel angle, and the front road-wheel angle it commands
    SPEED = 5  #: the speed driver: the base wheel torques


STAGES = tuple(Stage)  #: the one stage order
#: vehicles the loop runs stage by stage together (its blocks: each stage steps them in turn)
LOOP_BLOCK = 64
#: vehicles per call of the plant's block kernel (envs.vehicle.BLOCK: its wheel lanes)
PLANT_BLOCK = BLOCK


class Status(enum.IntEnum):
    """Why a vehicle's run through its stages stopped."""

    DONE = 0  #: it has run its steps (it rests at CONTROL)
    WAITING = 1  #: its component at this stage is Python's (:class:`PythonStage`)
    NEEDS_NOISE = 2  #: its sensors' noise block is used up
    NEEDS_PREVIEW = 3  #: its path follower needs preview responses at a new speed (value: 0.1 m/s)
    NEEDS_RESET = 4  #: its estimator is to be reset (a new vehicle)
    BAD_TRUTH = 5  #: a true value is not finite (value: the channel)
    ESTIMATOR_FAILED = 6  #: value: the estimator's status
    ALLOCATION_FAILED = 7  #: value: the allocator's status
    TOO_FAST_FOR_RELAXATION = 8  #: the tyres relax too fast for RK4 at this step
    PLANT_FAILED = 9  #: value: the plant's status
    BAD_FOLLOWER_STATE = 10  #: the path follower cannot steer from the state


class PythonStage(NamedTuple):
    """A stage whose component runs in Python: ``served`` (B,) bool marks the vehicles Python has
    served at this stage since they stopped there."""

    served: np.ndarray


class NoControl(NamedTuple):
    """No stability controller: the driver's commands go to the car as they are."""


class HeldAction(NamedTuple):
    """A held agent action (B, n) in [-1, 1] as a controller: with ``yaw_moment``, action 0 scaled
    by ``max_yaw_moment`` [N m] is a corrective yaw moment allocated over the wheels' motors and
    brakes, before the driver's drive force while the car is outside its stable region
    (:func:`fourwis.control.esc.unstable`, on ``esc``'s settings), and action 1, if there is one,
    scaled by ``max_rear_steer`` [rad], the rear steer; else the actions are corrective net wheel
    torques added to the base wheel torques (:func:`wheel_torque_action`, braking up to
    ``brake_peak_torque`` [N m] beyond the motors). With ``esc_on`` the car's brake-based ESC
    ``esc`` acts beneath the agent's command."""

    action: np.ndarray
    yaw_moment: bool
    max_yaw_moment: float
    max_rear_steer: float
    limits: AllocatorLimits
    brake_peak_torque: float
    esc: EscKernel
    esc_on: bool


class PlantStage(NamedTuple):
    """The plant as the loop runs it per vehicle: the car, each vehicle's road, and the speed
    [m/s] beyond which its tyres relax too fast for RK4 at this step (contact-point speeds
    bounded with ``reach`` [m], the farthest contact point's distance from the CG)."""

    plant: Plant
    road: RoadTables
    relaxation_speed: float
    reach: float


class Sample(NamedTuple):
    """What a closed loop knows at its current time, before the controller acts (B vehicles):
    t (B,) [s]; the sensors' reading; the truth and the estimate (:class:`Estimate` of B rows);
    the driver's steering-wheel angle (B,) [rad], the front road-wheel angle it commands within
    the steering's lock (B,) [rad], and the speed-holding driver's wheel torques (B, 4) [N m]."""

    t: np.ndarray
    reading: SensorReading
    truth: Estimate
    estimate: Estimate
    steering_wheel: np.ndarray
    front_steer: np.ndarray
    base_torques: np.ndarray


class StepRecord(NamedTuple):
    """Samples of a closed loop, taken before the plant advances: t, state (NX), aux (NAUX),
    controls (NU) applied, steering_wheel, reading, truth, estimate, each with the leading axes
    (n, B) of n steps of B vehicles (or (B,) for one step)."""

    t: np.ndarray
    state: np.ndarray
    aux: np.ndarray
    controls: np.ndarray
    steering_wheel: np.ndarray
    reading: SensorReading
    truth: Estimate
    estimate: Estimate


class Cars(NamedTuple):
    """Each vehicle's place in the loop (B rows): plant state (B, NX), diagnostics at it (B, NAUX)
    and the controls last applied (B, NU); steps since its start k (B,); the stage it runs next
    (B,) (:class:`Stage`); whether its estimator is to be reset (B,) bool; its true measured
    quantities (B, N_SENSORS) in the order of its sensors (:data:`fourwis.envs.sensors.SENSORS`)
    and its speed driver's wheel torque (B,)."""

    state: np.ndarray
    aux: np.ndarray
    controls: np.ndarray
    k: np.ndarray
    stage: np.ndarray
    fresh: np.ndarray
    sensed: np.ndarray
    drive_torque: np.ndarray


class Call(NamedTuple):
    """One run of the loop: the steps to go ``n`` and, with ``final``, a control and record at the
    end without a plant step; each vehicle's steps done (B,), status (B,) (:class:`Status`) and
    its value (B,), and the state a failed plant step reached (B, NX)."""

    n: int
    final: bool
    progress: np.ndarray
    status: np.ndarray
    value: np.ndarray
    reached: np.ndarray


class Parts(NamedTuple):
    """The loop's components, each its compiled bundle or :class:`PythonStage`, and the car's wheel
    actuators (:class:`fourwis.control.wheel_slip.WheelActuators`: every command's net wheel
    torques to motors and brakes, with the slip control)."""

    controller: object
    plant: object
    sensors: object
    estimator: object
    steering: object
    speed: object
    actuators: WheelActuators


class Timing(NamedTuple):
    """The loop's step dt [s], the steering ratio [-] and the front steer limit [rad]."""

    dt: float
    steering_ratio: float
    max_front_steer: float


#: the stages' compiled forms: each returns Status.DONE or why the vehicle stops (``value`` in
#: ``call.value[b]``)
command = bundle_dispatch("command", "controller, b, sample, cars, call")
#: the plant and the estimator step the block's cars at their stage together (``rows[:count]``),
#: each car's status into ``statuses[:count]``: blocks of cars run in SIMD lanes
integrate = bundle_dispatch("integrate", "plant, rows, count, cars, call, dt, statuses")
sense = bundle_dispatch("sense", "sensors, b, cars, sample, call")
estimate_stage = bundle_dispatch("estimate_stage", "estimator, rows, count, sample, call, statuses")
steer = bundle_dispatch("steer", "drivers, b, sample, cars, call")
speed_hold = bundle_dispatch("speed_hold", "drivers, b, sample, cars, call")


@numba.njit(inline="always", **JIT)
def _served(stage: PythonStage, b: int) -> int:
    """A Python stage's status for vehicle b: done once served (and the mark used up), else waiting."""
    if stage.served[b]:
        stage.served[b] = False
        return Status.DONE
    return Status.WAITING


@command.register(PythonStage)
def _python_control(controller, b, sample, cars, call):
    return _served(controller, b)


@numba.njit(**JIT)
def _served_rows(stage: PythonStage, rows, count, statuses) -> None:
    """:func:`_served` of the vehicles ``rows[:count]`` into ``statuses``. (The block stages' loops
    live in functions of their own, not in the inlined stage implementations: numba's inliner
    warns about loops in them.)"""
    for j in range(count):
        statuses[j] = _served(stage, rows[j])


@integrate.register(PythonStage)
def _python_plant(plant, rows, count, cars, call, dt, statuses):
    _served_rows(plant, rows, count, statuses)


@sense.register(PythonStage)
def _python_sensors(sensors, b, cars, sample, call):
    return _served(sensors, b)


@estimate_stage.register(PythonStage)
def _python_estimator(estimator, rows, count, sample, call, statuses):
    _served_rows(estimator, rows, count, statuses)


@steer.register(PythonStage)
@speed_hold.register(PythonStage)
def _python_driver(drivers, b, sample, cars, call):
    return _served(drivers, b)


@numba.njit(inline="always", **JIT)
def base_controls(b: int, sample: Sample, controls: np.ndarray) -> None:
    """Vehicle b's controls (NU,) as the driver gives them: base torques and front steer."""
    controls[:] = 0.0
    for w in range(4):
        controls[C_TORQUE + w] = sample.base_torques[b, w]
    controls[C_DELTA_F] = sample.front_steer[b]


@command.register(NoControl)
def _no_control(controller, b, sample, cars, call):
    base_controls(b, sample, cars.controls[b])
    return Status.DONE


@register_jitable
def wheel_torque_action(base, action, motor_peak: float, brake_peak: float):
    """The net torque [N m] a ``wheel_torques`` action in [-1, 1] asks of a wheel with the driver's
    ``base`` torque [N m]: a positive action adds up to the motor's peak ``motor_peak`` [N m], a
    negative one brakes by up to the motor's and the friction brake's peaks together, within
    [-(motor_peak + brake_peak), motor_peak] (scalars, or numpy arrays of one shape)."""
    scale = np.where(action > 0.0, motor_peak, motor_peak + brake_peak)
    return np.minimum(np.maximum(base + action * scale, -(motor_peak + brake_peak)), motor_peak)


@command.register(HeldAction)
def _held_action(controller, b, sample, cars, call):
    controls = cars.controls[b]
    base_controls(b, sample, controls)
    action, limit = controller.action, controller.limits.motor_peak_torque
    torques, estimate = scratch((4,)), sample.estimate
    if controller.yaw_moment:
        row = slice(b, b + 1)
        rear, yaw, lateral, first = scratch((1,)), scratch((1,)), scratch((1, 4)), scratch((1,), np.bool_)
        yaw[0] = action[b, 0] * controller.max_yaw_moment
        rear[0] = action[b, 1] * controller.max_rear_steer if action.shape[1] == 2 else 0.0
        lateral[:, :] = 0.0
        first[0] = unstable(controller.esc.settings, b, estimate, sample.front_steer[b])
        out = Allocation(scratch((1, 4)), scratch((1,)), scratch((1,)), scratch((1,), np.bool_))
        bad = allocation_kernel(
            AllocationInputs(sample.base_torques[row], yaw, estimate.fz[row], estimate.mu[row], lateral,
                             estimate.u[row], sample.front_steer[row], rear, first),
            controller.limits,
            out,
        )  # fmt: skip
        if bad:
            call.value[b] = bad
            return Status.ALLOCATION_FAILED
        for w in range(4):
            torques[w] = out.torques[0, w]
        controls[C_DELTA_R] = rear[0]
    else:
        for w in range(4):
            torques[w] = wheel_torque_action(
                sample.base_torques[b, w], action[b, w], limit, controller.brake_peak_torque
            )
    if controller.esc_on:
        esc_torques(controller.esc, b, estimate, sample.front_steer[b], torques)
    controls[C_TORQUE : C_TORQUE + 4] = torques
    return Status.DONE


@command.register(EscKernel)
def _esc(controller, b, sample, cars, call):
    controls = cars.controls[b]
    base_controls(b, sample, controls)
    esc_torques(controller, b, sample.estimate, sample.front_steer[b], controls[C_TORQUE : C_TORQUE + 4])
    return Status.DONE


@command.register(DycKernel)
def _dyc(controller, b, sample, cars, call):
    controls = cars.controls[b]
    base_controls(b, sample, controls)
    bad = stability_command(controller, b, sample.estimate, sample.front_steer[b], sample.base_torques[b])
    if bad:
        call.value[b] = bad
        return Status.ALLOCATION_FAILED
    for w in range(4):
        controls[C_TORQUE + w] = controller.memory.allocation.torques[b, w]
    controls[C_DELTA_R] = controller.memory.rear[b]
    return Status.DONE


@numba.njit(inline="always", **JIT)
def _too_fast(plant: PlantStage, x: np.ndarray, b: int) -> bool:
    """Whether vehicle b's tyres relax too fast for RK4 at this step (PlantStage.relaxation_speed)."""
    return math.hypot(x[b, S_U], x[b, S_V]) + abs(x[b, S_R]) * plant.reach > plant.relaxation_speed


@numba.njit(**JIT)
def _plant_car(plant: PlantStage, b: int, cars: Cars, call: Call, dt: float) -> int:
    """One RK4 step of vehicle b alone; its status (and on a failure its value and reached state in ``call``)."""
    x = cars.state
    if _too_fast(plant, x, b):
        return Status.TOO_FAST_FOR_RELAXATION
    row = slice(b, b + 1)
    road = RoadTables(plant.road.base_mu[row], plant.road.rects[row], plant.road.mu_given[row], plant.road.use_map)
    state, status = x[row].copy(), scratch((1,), np.int64)
    status[0] = 0
    advance_block(state, cars.controls[row], plant.plant, road, dt, 1, cars.aux[row], status)
    if status[0]:
        call.reached[b, :] = state[0]
        call.value[b] = status[0]
        return Status.PLANT_FAILED
    x[b, :] = state[0]
    return Status.DONE


@integrate.register(PlantStage)
def _plant_step(plant, rows, count, cars, call, dt, statuses):
    _plant_rows(plant, rows, count, cars, call, dt, statuses)


@numba.njit(**JIT)
def _plant_rows(plant: PlantStage, rows, count, cars: Cars, call: Call, dt: float, statuses) -> None:
    """One RK4 step of the vehicles ``rows[:count]``, each one's status into ``statuses``."""
    # blocks of up to PLANT_BLOCK cars in wheel lanes (envs.vehicle.advance_block), each car's step
    # the same as alone; a block with a failing car is stepped again car by car, so that each car
    # fails (or not) as it would alone and the others of its block still step
    x, road = cars.state, plant.road
    chosen = scratch((PLANT_BLOCK,), np.int64)
    for lo in range(0, count, PLANT_BLOCK):
        n = 0
        for j in range(lo, min(lo + PLANT_BLOCK, count)):
            if _too_fast(plant, x, rows[j]):
                statuses[j] = Status.TOO_FAST_FOR_RELAXATION
            else:
                chosen[n] = j
                n += 1
        if n == 0:
            continue
        state, controls, aux = np.empty((n, NX)), np.empty((n, NU)), np.empty((n, NAUX))
        base_mu, mu_given = np.empty(n), np.empty((n, 4))
        rects = np.empty((n, road.rects.shape[1], road.rects.shape[2]))
        for i in range(n):
            b = rows[chosen[i]]
            state[i, :], controls[i, :] = x[b], cars.controls[b]
            base_mu[i], mu_given[i, :], rects[i, :, :] = road.base_mu[b], road.mu_given[b], road.rects[b]
        status, block_road = np.zeros(n, np.int64), RoadTables(base_mu, rects, mu_given, road.use_map)
        advance_block(state, controls, plant.plant, block_road, dt, 1, aux, status)
        failed = False
        for i in range(n):
            failed = failed or status[i] != 0
        for i in range(n):
            j = chosen[i]
            if failed:
                statuses[j] = _plant_car(plant, rows[j], cars, call, dt)
            else:
                x[rows[j], :] = state[i]
                cars.aux[rows[j], :] = aux[i]
                statuses[j] = Status.DONE


@sense.register(SensorKernel)
def _sensors(sensors, b, cars, sample, call):
    rows, sensed = scratch((1,), np.int64), scratch((1, N_SENSORS))
    rows[0] = b
    found = noisy_readings(sensors, cars.sensed[b : b + 1], rows, sensed)
    if found == BLOCK_USED_UP:
        return Status.NEEDS_NOISE
    if found >= 0:
        call.value[b] = found
        return Status.BAD_TRUTH
    to_channels(sensed[0], sample.reading.values[b], sample.reading.valid[b], sensors.brake_gain)
    return Status.DONE


@estimate_stage.register(FilterKernel)
def _filter(estimator, rows, count, sample, call, statuses):
    _filter_rows(estimator, rows, count, sample.reading, sample.estimate, call.value, statuses)


@numba.njit(**JIT)
def _filter_rows(estimator: FilterKernel, rows, count, reading: SensorReading, estimate: Estimate, value,
                 statuses) -> None:  # fmt: skip
    """The estimator's step of the vehicles ``rows[:count]`` on their ``reading`` into their rows of
    ``estimate``, each one's status into ``statuses`` (and the estimator's own into ``value``)."""
    codes = scratch((LOOP_BLOCK,), np.int64)  # (a federated kind's block in SIMD lanes)
    step_vehicles(estimator, rows, count, reading, estimate, rows, codes)
    for j in range(count):
        if codes[j] != OK:
            value[rows[j]] = codes[j]
            statuses[j] = Status.ESTIMATOR_FAILED
        else:
            statuses[j] = Status.DONE


@estimate_stage.register(TruthKernel)
def _truth(estimator, rows, count, sample, call, statuses):
    _truth_rows(rows, count, sample.truth, sample.estimate, statuses)


@numba.njit(**JIT)
def _truth_rows(rows, count, truth: Estimate, estimate: Estimate, statuses) -> None:
    """The truth as the estimate of the vehicles ``rows[:count]`` (the oracle)."""
    for j in range(count):
        copy_estimate_row(truth, rows[j], estimate, rows[j])
        statuses[j] = Status.DONE


@numba.njit(inline="always", **JIT)
def _driver(drivers, b, sample, cars, call, out):
    code, found = drive(drivers, b, sample.t, cars.state, out)
    if code == DRIVEN:
        return Status.DONE
    call.value[b] = found
    return Status.NEEDS_PREVIEW if code == NEEDS_PREVIEW else Status.BAD_FOLLOWER_STATE


@steer.register(DriverTables)
def _steering(drivers, b, sample, cars, call):
    return _driver(drivers, b, sample, cars, call, sample.steering_wheel)


@speed_hold.register(DriverTables)
def _speed(drivers, b, sample, cars, call):
    return _driver(drivers, b, sample, cars, call, cars.drive_torque)


@numba.njit(inline="always", **JIT)
def actuate_controls(actuators: WheelActuators, b: int, sample: Sample, controls: np.ndarray) -> None:
    """Vehicle b's commanded net wheel torques in ``controls`` (NU,) to its motor torque and brake
    pressure commands, slip-controlled on its measured wheel speeds and acceleration, estimated
    forward speed and friction."""
    demand, motor, pressure = scratch((4,)), scratch((4,)), scratch((4,))
    for w in range(4):
        demand[w] = controls[C_TORQUE + w]
    omega, estimate = sample.reading.values[b, CH_OMEGA : CH_OMEGA + 4], sample.estimate
    r = estimate.r[b]
    braking, drive = reference_speeds(actuators, b, omega, sample.reading.values[b, CH_AX], estimate.u[b], r)
    actuate(actuators, demand, omega, braking, drive, r, estimate.mu[b], motor, pressure)
    for w in range(4):
        controls[C_TORQUE + w], controls[C_BRAKE + w] = motor[w], pressure[w]


@numba.njit(inline="always", **JIT)
def copy_estimate_row(source: Estimate, i: int, target: Estimate, j: int) -> None:
    """Row i of ``source`` into row j of ``target``."""
    target.u[j], target.v[j], target.beta[j], target.r[j] = source.u[i], source.v[i], source.beta[i], source.r[i]
    target.ax[j], target.ay[j], target.beta_std[j] = source.ax[i], source.ay[i], source.beta_std[i]
    for w in range(4):
        target.mu[j, w], target.fz[j, w], target.mu_std[j, w] = source.mu[i, w], source.fz[i, w], source.mu_std[i, w]


@numba.njit(inline="always", **JIT)
def measure_truth(b: int, state: np.ndarray, aux: np.ndarray, sensed: np.ndarray, truth: Estimate) -> None:
    """Vehicle b's true measured quantities (N_SENSORS,) into ``sensed[b]`` (its sensors' order)
    and its true state in estimator form into row b of ``truth`` (zero sigmas)."""
    for c in range(2):
        sensed[b, c] = aux[b, TRUE_AUX_COLUMNS[c]]
    for c in range(len(TRUE_STATE_COLUMNS)):
        sensed[b, 2 + c] = state[b, TRUE_STATE_COLUMNS[c]]
    truth.u[b], truth.v[b], truth.r[b] = state[b, S_U], state[b, S_V], state[b, S_R]
    truth.beta[b] = sideslip(state[b, S_U], state[b, S_V])
    truth.ax[b], truth.ay[b], truth.beta_std[b] = aux[b, A_AX], aux[b, A_AY], 0.0
    for w in range(4):
        truth.mu[b, w], truth.fz[b, w], truth.mu_std[b, w] = aux[b, A_MU + w], aux[b, A_FZ + w], 0.0


@numba.njit(**JIT)
def measure_truths(state: np.ndarray, aux: np.ndarray, sensed: np.ndarray, truth: Estimate) -> None:
    """:func:`measure_truth` of every vehicle of ``state`` (B, NX) and ``aux`` (B, NAUX)."""
    for b in range(state.shape[0]):
        measure_truth(b, state, aux, sensed, truth)


@numba.njit(inline="always", **JIT)
def _record(records: StepRecord, s: int, b: int, sample: Sample, cars: Cars) -> None:
    """Vehicle b's sample, plant state, diagnostics and controls as step s of ``records``."""
    records.t[s, b], records.steering_wheel[s, b] = sample.t[b], sample.steering_wheel[b]
    records.state[s, b, :] = cars.state[b]
    records.aux[s, b, :] = cars.aux[b]
    records.controls[s, b, :] = cars.controls[b]
    records.reading.values[s, b, :] = sample.reading.values[b]
    records.reading.valid[s, b, :] = sample.reading.valid[b]
    records.reading.t[s, b] = sample.t[b]
    _record_estimate(sample.truth, b, records.truth, s)
    _record_estimate(sample.estimate, b, records.estimate, s)


@numba.njit(inline="always", **JIT)
def _record_estimate(source: Estimate, b: int, target: Estimate, s: int) -> None:
    """Row b of ``source`` as step s, vehicle b of the stacked ``target``."""
    target.u[s, b], target.v[s, b], target.beta[s, b], target.r[s, b] = (
        source.u[b],
        source.v[b],
        source.beta[b],
        source.r[b],
    )
    target.ax[s, b], target.ay[s, b], target.beta_std[s, b] = source.ax[b], source.ay[b], source.beta_std[b]
    target.mu[s, b, :], target.fz[s, b, :], target.mu_std[s, b, :] = source.mu[b], source.fz[b], source.mu_std[b]


#: a car's status from a stage that ends its run without moving on (the steps asked for are done)
FINISHED = -1


@numba.njit(**JIT)
def _run_block(members, call: Call, cars: Cars, sample: Sample, parts: Parts, timing: Timing, records: StepRecord):
    """The vehicles ``members`` (at most LOOP_BLOCK) from where each stands up to ``call.n`` steps
    (see the module docstring), stage by stage: each stage runs for the block's vehicles that stand
    at it (``rows[:count]``, each one's status into ``statuses``: DONE, on to the next stage,
    FINISHED, or why it stops), in the stages' order, so that a plant or an estimator with a
    block form steps them together; a vehicle leaves the block when it stops (``call.status[b]``,
    ``call.value[b]``). Each stage's code is written out here: a helper function taking the loop's
    bundles would have numba count the references of every array in them at each call."""
    M = members.shape[0]
    running, slots = scratch((LOOP_BLOCK,), np.bool_), scratch((LOOP_BLOCK,), np.int64)
    rows, statuses = scratch((LOOP_BLOCK,), np.int64), scratch((LOOP_BLOCK,), np.int64)
    for i in range(M):
        running[i] = True
    left = M
    while left:
        for stage in range(len(STAGES)):
            count = 0
            for i in range(M):
                if running[i] and cars.stage[members[i]] == stage:
                    slots[count], rows[count] = i, members[i]
                    count += 1
            if count == 0:
                continue
            if stage == Stage.CONTROL:
                for j in range(count):
                    b = rows[j]
                    if call.progress[b] >= call.n and not (call.final and call.progress[b] == call.n):
                        statuses[j] = FINISHED  # (its steps are done)
                        continue
                    status = command(parts.controller, b, sample, cars, call)
                    if status == Status.DONE:
                        actuate_controls(parts.actuators, b, sample, cars.controls[b])
                    if status == Status.DONE and records.t.shape[0]:
                        _record(records, call.progress[b], b, sample, cars)
                    if status == Status.DONE and call.progress[b] == call.n:  # (the final control: no plant step)
                        call.progress[b] += 1
                        status = FINISHED
                    statuses[j] = status
            elif stage == Stage.PLANT:
                integrate(parts.plant, rows, count, cars, call, timing.dt, statuses)
                for j in range(count):
                    b = rows[j]
                    if statuses[j] == Status.DONE:
                        cars.k[b] += 1
                        sample.t[b] = cars.k[b] * timing.dt
                        call.progress[b] += 1
            elif stage == Stage.SENSE:
                for j in range(count):
                    b = rows[j]
                    sample.reading.t[b] = sample.t[b]
                    measure_truth(b, cars.state, cars.aux, cars.sensed, sample.truth)
                    status = Status.DONE
                    for c in range(cars.sensed.shape[1]):
                        if not math.isfinite(cars.sensed[b, c]):
                            call.value[b] = c
                            status = Status.BAD_TRUTH
                            break
                    if status == Status.DONE:
                        status = sense(parts.sensors, b, cars, sample, call)
                    statuses[j] = status
            elif stage == Stage.ESTIMATE:
                ready, n = scratch((LOOP_BLOCK,), np.int64), 0  # (a new vehicle's estimator is reset first)
                for j in range(count):
                    if cars.fresh[rows[j]]:
                        statuses[j] = Status.NEEDS_RESET
                    else:
                        ready[n] = j
                        n += 1
                if n == count:
                    estimate_stage(parts.estimator, rows, count, sample, call, statuses)
                elif n:
                    going, going_statuses = scratch((LOOP_BLOCK,), np.int64), scratch((LOOP_BLOCK,), np.int64)
                    for i in range(n):
                        going[i] = rows[ready[i]]
                    estimate_stage(parts.estimator, going, n, sample, call, going_statuses)
                    for i in range(n):
                        statuses[ready[i]] = going_statuses[i]
            elif stage == Stage.STEER:
                for j in range(count):
                    b = rows[j]
                    statuses[j] = steer(parts.steering, b, sample, cars, call)
                    if statuses[j] == Status.DONE:
                        delta = sample.steering_wheel[b] / timing.steering_ratio
                        sample.front_steer[b] = min(max(delta, -timing.max_front_steer), timing.max_front_steer)
            else:
                for j in range(count):
                    b = rows[j]
                    statuses[j] = speed_hold(parts.speed, b, sample, cars, call)
                    if statuses[j] == Status.DONE:
                        for w in range(4):
                            sample.base_torques[b, w] = cars.drive_torque[b]
            for j in range(count):
                b, status = rows[j], statuses[j]
                if status == Status.DONE:
                    cars.stage[b] = (stage + 1) % len(STAGES)
                else:
                    call.status[b] = Status.DONE if status == FINISHED else status
                    running[slots[j]] = False
                    left -= 1


@numba.njit(nogil=True, **JIT)
def run_cars(cars_to_run, call: Call, cars: Cars, sample: Sample, parts: Parts, timing: Timing, records: StepRecord):
    """:func:`_run_block` for the vehicles of ``cars_to_run`` (M,) int64 in blocks of LOOP_BLOCK,
    without the GIL (every bundle :func:`fourwis.core.kernels.borrowed` for the call)."""
    call, cars, sample, parts, records = borrowed((call, cars, sample, parts, records))
    for lo in range(0, cars_to_run.shape[0], LOOP_BLOCK):
        _run_block(cars_to_run[lo : lo + LOOP_BLOCK], call, cars, sample, parts, timing, records)


def run(cars_to_run: np.ndarray, *args) -> None:
    """:func:`run_cars` over ``cars_to_run``, shared among numba's threads (the cars are
    independent: each writes only its own rows)."""
    run_parallel(run_cars, cars_to_run, *args)


def new_records(n: int, batch: int) -> StepRecord:
    """A :class:`StepRecord` of n steps of ``batch`` vehicles, NaN (a held vehicle's rows stay so);
    for n = 0 one shared, empty record (the loop writes no records into it)."""
    return _no_records(batch) if n == 0 else _records(n, batch)


@functools.lru_cache(maxsize=16)
def _no_records(batch: int) -> StepRecord:
    return _records(0, batch)


def _records(n: int, batch: int) -> StepRecord:

    def nan(*shape) -> np.ndarray:
        return np.full((n, batch, *shape), np.nan)

    def estimate() -> Estimate:
        return Estimate(*(nan(4) if name in ("mu", "fz", "mu_std") else nan() for name in Estimate._fields))

    reading = SensorReading(nan(N_CHANNELS), np.ones((n, batch, N_CHANNELS), dtype=bool), nan())
    return StepRecord(nan(), nan(NX), nan(NAUX), nan(NU), nan(), reading, estimate(), estimate())

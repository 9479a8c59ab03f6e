"""A closed loop's 2 ms steps in one compiled call: :meth:`envs.simulation.ClosedLoop.advance_steps`'
fast path, which the Gymnasium envs take for every control step and :func:`envs.simulation.simulate`
for every run it can (open-loop estimation, tuning, the comparison's rows with or without the DYC).

Each step of each vehicle runs, in order, what :meth:`ClosedLoop.advance` and
:meth:`ClosedLoop.sample` run from Python: the agent's command (``control.allocation``'s
minimum-workload allocator, or direct wheel torques) or the DYC's
(:func:`control.dyc.stability_command`, which :class:`control.StabilityController` calls from
Python too), one RK4 step of the plant
(``envs.vehicle``), the sensors' noisy reading (``envs.sensors``), the estimator's step
(``estimation.joint``'s compiled filters, or the truth for the oracle) and the drivers
(``envs.driver``). It calls the same compiled kernels and nothing else, so its results equal
the Python loop's bit for bit (tested); what it saves is the Python between them, ~80% of a
single car's step. Vehicles run one after another through all their steps (shared among
numba's thread count of Python threads for batches of 2 or more), stopping to let Python refill
a vehicle's sensor noise block or add a path follower's preview responses, and resuming where
they stopped.

The fast path applies when everything in the loop has a compiled form: fourwis's own
estimators (``StateEstimator`` of any kind, ``Oracle``), a controller with ``kernel_form``
(the envs' agent controller), fourwis's DYC (``StabilityController``, any law, with or without
4WS) or none, sensors without faults, table friction maps and drivers of
:data:`envs.driver.COMPILED_DRIVERS` or path followers, for batches up to :data:`MAX_BATCH` cars.
:func:`supports` says whether a loop takes it.
"""

from __future__ import annotations

import functools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numba
import numpy as np

from fourwis.control import StabilityController
from fourwis.control.allocation import allocation_error, allocation_kernel, allocator_limits
from fourwis.control.dyc import M_REAR, M_TORQUES, M_WIDTH, allocation_inputs, stability_command
from fourwis.core.kernels import JIT, scratch
from fourwis.core.types import CHANNELS, Estimate, SensorReading
from fourwis.envs.driver import DRIVEN, FOLLOWER, NEEDS_PREVIEW, bad_follower_state, drive, follower_form
from fourwis.envs.road import RoadTables
from fourwis.envs.sensors import NOISE_BLOCK, TRUE_AUX_COLUMNS, TRUE_STATE_COLUMNS, noisy_readings
from fourwis.envs.vehicle import (
    A_AX,
    A_AY,
    A_FZ,
    A_MU,
    C_DELTA_F,
    C_DELTA_R,
    C_TORQUE,
    NAUX,
    NU,
    NX,
    RK4_REAL_LIMIT,
    S_R,
    S_U,
    S_V,
    advance_block,
    check_relaxation_step,
    plant_error,
    sideslip,
)
from fourwis.estimation.joint import (
    N_OUT,
    O_AX,
    O_AY,
    O_BETA,
    O_BETA_STD,
    O_FZ,
    O_MU,
    O_MU_STD,
    O_R,
    O_U,
    O_V,
    OK,
    STATE_FIELDS,
    step_row,
)

#: statuses of a vehicle after a call: done, or stopped for Python to act (refill its noise, add
#: preview responses at ``value`` tenths of m/s), or failed (``value``: the part's own status)
DONE, NEEDS_NOISE, NEEDS_RESPONSES = 0, 1, 2
BAD_TRUTH, ESTIMATOR_FAILED, ALLOCATION_FAILED, TOO_FAST_FOR_RELAXATION, PLANT_FAILED, BAD_FOLLOWER_STATE = range(3, 9)
NO_CONTROLLER, YAW_MOMENT, WHEEL_TORQUES, STABILITY = range(4)  #: controller modes (STABILITY: the DYC)
ORACLE, STATE_ESTIMATOR = range(2)  #: estimator modes


@numba.njit(inline="always", **JIT)
def _control(b, base, front, est, controller, ctrl) -> int:
    """Vehicle b's controls (1, NU) from its sample (base torques, front steer, estimate row)
    and the agent's held action or the DYC's step; returns the allocator's status (0: fine)."""
    (
        mode,
        action,
        max_yaw_moment,
        max_rear_steer,
        positions,
        peak_torque,
        peak_power,
        radius,
        settings,
        speeds,
        gains,
        law,
        memory,
    ) = controller
    ctrl[0, :] = 0.0
    for w in range(4):
        ctrl[0, C_TORQUE + w] = base[b, w]
    ctrl[0, C_DELTA_F] = front[b]
    if mode == YAW_MOMENT:
        yaw, speed, front_steer, rear = scratch((1,)), scratch((1,)), scratch((1,)), scratch((1,))
        yaw[0] = action[b, 0] * max_yaw_moment
        rear[0] = action[b, 1] * max_rear_steer if action.shape[1] == 2 else 0.0
        speed[0], front_steer[0] = est[b, O_U], front[b]
        lateral, torques = scratch((1, 4)), scratch((1, 4))
        lateral[:, :] = 0.0
        moment, force, feasible = scratch((1,)), scratch((1,)), scratch((1,), np.bool_)
        bad = allocation_kernel(
            base[b : b + 1],
            yaw,
            est[b : b + 1, O_FZ : O_FZ + 4],
            est[b : b + 1, O_MU : O_MU + 4],
            lateral,
            speed,
            front_steer,
            rear,
            positions,
            peak_torque,
            peak_power,
            radius,
            torques,
            moment,
            force,
            feasible,
        )
        if bad:
            return bad
        for w in range(4):
            ctrl[0, C_TORQUE + w] = torques[0, w]
        ctrl[0, C_DELTA_R] = rear[0]
    elif mode == WHEEL_TORQUES:
        for w in range(4):
            ctrl[0, C_TORQUE + w] = min(max(base[b, w] + action[b, w] * peak_torque, -peak_torque), peak_torque)
    elif mode == STABILITY:
        bad = stability_command(
            est[b, O_U],
            est[b, O_BETA],
            est[b, O_R],
            est[b, O_AY],
            est[b, O_MU : O_MU + 4],
            est[b, O_MU_STD : O_MU_STD + 4],
            est[b, O_FZ : O_FZ + 4],
            front[b],
            base[b],
            positions,
            peak_torque,
            peak_power,
            radius,
            settings,
            speeds,
            gains,
            law,
            memory[b],
        )
        if bad:
            return bad
        for w in range(4):
            ctrl[0, C_TORQUE + w] = memory[b, M_TORQUES + w]
        ctrl[0, C_DELTA_R] = memory[b, M_REAR]
    return 0


@numba.njit(inline="always", **JIT)
def _sense(b, state, aux, sensors, truth, readings, sensed) -> int:
    """Vehicle b's true values (its truth row, N_OUT layout) and noisy reading; returns
    noisy_readings' status."""
    bias, normal, noise, cursor = sensors
    for c in range(2):
        sensed[0, c] = aux[b, TRUE_AUX_COLUMNS[c]]
    for c in range(11):
        sensed[0, 2 + c] = state[b, TRUE_STATE_COLUMNS[c]]
    truth[b, :] = 0.0
    truth[b, O_U], truth[b, O_V], truth[b, O_R] = state[b, S_U], state[b, S_V], state[b, S_R]
    truth[b, O_BETA] = sideslip(state[b, S_U], state[b, S_V])  # (as envs.simulation.true_estimate)
    truth[b, O_AX], truth[b, O_AY] = aux[b, A_AX], aux[b, A_AY]
    for w in range(4):
        truth[b, O_MU + w], truth[b, O_FZ + w] = aux[b, A_MU + w], aux[b, A_FZ + w]
    row = scratch((1,), np.int64)
    row[0] = b
    return noisy_readings(sensed, row, bias, normal, noise, cursor, readings[b : b + 1])


#: columns of a step's record (:func:`_record`): time, steering-wheel angle, plant state,
#: diagnostics, applied controls, sensor readings, truth and estimate (N_OUT layout each)
R_T, R_STEERING_WHEEL, R_STATE = 0, 1, 2
R_AUX = R_STATE + NX
R_CONTROLS = R_AUX + NAUX
R_READINGS = R_CONTROLS + NU
R_TRUTH = R_READINGS + 13
R_ESTIMATE = R_TRUTH + N_OUT
R_WIDTH = R_ESTIMATE + N_OUT


@numba.njit(inline="always", **JIT)
def _record(out, t, steering_wheel, state, aux, controls, readings, truth, estimate) -> None:
    """One step's record into ``out`` (R_WIDTH,)."""
    out[R_T], out[R_STEERING_WHEEL] = t, steering_wheel
    out[R_STATE:R_AUX] = state
    out[R_AUX:R_CONTROLS] = aux
    out[R_CONTROLS:R_READINGS] = controls
    out[R_READINGS:R_TRUTH] = readings
    out[R_TRUTH:R_ESTIMATE] = truth
    out[R_ESTIMATE:] = estimate


@numba.njit(**JIT)
def _advance_vehicle(
    b,
    n,
    progress,
    status,
    value,
    k,
    dt,
    state,
    aux,
    plant,
    sensors,
    drivers,
    estimator,
    controller,
    sample,
    reached,
    controls,
    records,
) -> None:
    """Vehicle b's steps from ``progress[b]`` up to ``n`` (see the module docstring); sets
    ``status[b]`` and ``value[b]``. ``records`` (n, B, R_WIDTH): each step's sample, plant state,
    diagnostics and applied controls, before the plant moves (columns R_*)."""
    pk, tp, base_mu, rects, mu_given, use_map, relaxation_speed, reach = plant
    (
        steer_codes,
        steer_tables,
        steer_follower,
        speed_codes,
        speed_tables,
        speed_follower,
        steering_ratio,
        max_front_steer,
        drive_torque,
    ) = drivers
    (
        mode,
        kind,
        epk,
        edt,
        huber_c,
        zero_point_tau,
        stuck,
        slide,
        yaw_balance,
        process_var,
        sensor_var,
        mu_var,
        fields,
        rows,
        est_status,
    ) = estimator
    (
        X,
        P,
        MU,
        P_MU,
        BETA,
        BETA_MU,
        OMEGA_PREV,
        OMEGA_DOT,
        INERTIAL_PREV,
        INERTIAL_REPEATS,
        ZERO_POINT,
        LAST_NLL,
        SLIP_RELAXED,
    ) = fields
    t, readings, valid, truth, est, swa, front, base = sample
    cursor = sensors[3]
    ctrl, step_status, sensed = scratch((1, NU)), scratch((1,), np.int64), scratch((1, 13))
    while progress[b] < n:
        s = progress[b]
        if status[b] != NEEDS_RESPONSES:  # (resumed after a path follower's new row: only the drivers are left)
            if cursor[b] >= NOISE_BLOCK:
                status[b] = NEEDS_NOISE
                return
            bad = _control(b, base, front, est, controller, ctrl)
            if bad:
                status[b], value[b] = ALLOCATION_FAILED, bad
                return
            _record(records[s, b], t[b], swa[b], state[b], aux[b], ctrl[0], readings[b], truth[b], est[b])
            if math.hypot(state[b, S_U], state[b, S_V]) + abs(state[b, S_R]) * reach > relaxation_speed:
                status[b] = TOO_FAST_FOR_RELAXATION
                return
            x = state[b : b + 1].copy()
            step_status[0] = 0
            advance_block(
                x,
                ctrl,
                pk,
                tp,
                base_mu[b : b + 1],
                rects[b : b + 1],
                mu_given[b : b + 1],
                use_map,
                dt,
                1,
                aux[b : b + 1],
                step_status,
            )
            controls[b, :] = ctrl[0]
            if step_status[0]:
                reached[b, :] = x[0]
                status[b], value[b] = PLANT_FAILED, step_status[0]
                return
            state[b, :] = x[0]
            k[b] += 1
            t[b] = k[b] * dt
            sensed_status = _sense(b, state, aux, sensors, truth, readings, sensed)
            if sensed_status >= 0:
                status[b], value[b] = BAD_TRUTH, sensed_status
                return
            if mode == STATE_ESTIMATOR:
                step_row(
                    b,
                    rows,
                    kind,
                    epk,
                    edt,
                    huber_c,
                    zero_point_tau,
                    stuck,
                    slide,
                    yaw_balance,
                    process_var,
                    sensor_var,
                    mu_var,
                    X,
                    P,
                    MU,
                    P_MU,
                    BETA,
                    BETA_MU,
                    OMEGA_PREV,
                    OMEGA_DOT,
                    INERTIAL_PREV,
                    INERTIAL_REPEATS,
                    ZERO_POINT,
                    LAST_NLL,
                    SLIP_RELAXED,
                    readings,
                    valid,
                    est,
                    est_status,
                )
                if est_status[b] != OK:
                    status[b], value[b] = ESTIMATOR_FAILED, est_status[b]
                    return
            else:
                est[b, :] = truth[b]
        code, found = drive(steer_codes[b], steer_tables, steer_follower, b, t, state, swa)
        if code == DRIVEN:
            code, found = drive(speed_codes[b], speed_tables, speed_follower, b, t, state, drive_torque)
        if code != DRIVEN:
            status[b], value[b] = (NEEDS_RESPONSES, found) if code == NEEDS_PREVIEW else (BAD_FOLLOWER_STATE, found)
            return
        for w in range(4):
            base[b, w] = drive_torque[b]
        front[b] = min(max(swa[b] / steering_ratio, -max_front_steer), max_front_steer)
        progress[b] += 1
        status[b] = DONE


@numba.njit(nogil=True, **JIT)
def _advance_cars(
    cars,
    n,
    progress,
    status,
    value,
    k,
    dt,
    state,
    aux,
    plant,
    sensors,
    drivers,
    estimator,
    controller,
    sample,
    reached,
    controls,
    records,
) -> None:
    """:func:`_advance_vehicle` for each vehicle of ``cars`` (M,) int64, without the GIL."""
    for j in range(cars.shape[0]):
        _advance_vehicle(
            cars[j],
            n,
            progress,
            status,
            value,
            k,
            dt,
            state,
            aux,
            plant,
            sensors,
            drivers,
            estimator,
            controller,
            sample,
            reached,
            controls,
            records,
        )


@functools.cache
def _pool(threads: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(threads, thread_name_prefix="fourwis-loop")


os.register_at_fork(after_in_child=_pool.cache_clear)  # (a forked child has none of the parent's threads)


def _run(cars: np.ndarray, *args) -> None:
    """:func:`_advance_cars` over ``cars``, split among numba's threads (``numba.get_num_threads()``:
    Python threads, as the kernel's tuples of arrays cannot enter a numba ``prange``)."""
    threads = min(numba.get_num_threads(), len(cars))
    if threads < 2:
        _advance_cars(cars, *args)
        return
    list(_pool(threads).map(lambda part: _advance_cars(part, *args), np.array_split(cars, threads)))


class Arrays(NamedTuple):
    """A closed loop's sample as the kernel reads and writes it (B vehicles): times t (B,) [s],
    sensor readings (B, 13) and their validity, the truth and the estimate as rows (B, N_OUT) of
    estimation.joint's output layout, steering-wheel angles (B,), front steer (B,) and base
    torques (B, 4)."""

    t: np.ndarray
    readings: np.ndarray
    valid: np.ndarray
    truth: np.ndarray
    estimate: np.ndarray
    steering_wheel: np.ndarray
    front_steer: np.ndarray
    base_torques: np.ndarray


_ESTIMATE_COLUMNS = (
    ("u", O_U, 1),
    ("v", O_V, 1),
    ("beta", O_BETA, 1),
    ("r", O_R, 1),
    ("ax", O_AX, 1),
    ("ay", O_AY, 1),
    ("mu", O_MU, 4),
    ("fz", O_FZ, 4),
    ("beta_std", O_BETA_STD, 1),
    ("mu_std", O_MU_STD, 4),
)


def estimate_rows(estimate: Estimate) -> np.ndarray:
    """An :class:`Estimate` of B vehicles as rows (B, N_OUT) of estimation.joint's output layout."""
    rows = np.empty((len(estimate.u), N_OUT))
    for name, column, width in _ESTIMATE_COLUMNS:
        value = getattr(estimate, name)
        if width == 1:
            rows[:, column] = value
        else:
            rows[:, column : column + width] = value
    return rows


def rows_estimate(rows: np.ndarray) -> Estimate:
    """The :class:`Estimate` (views) of rows (..., N_OUT)."""
    return Estimate(
        **{
            name: rows[..., column] if width == 1 else rows[..., column : column + width]
            for name, column, width in _ESTIMATE_COLUMNS
        }
    )


#: largest batch the compiled path runs. It runs each car's steps one after another, so the
#: plant loses the SIMD lanes it runs blocks of cars in, and the cars are shared between Python
#: threads instead of numba's; at 32 cars the two loops are even, beyond it the Python loop over
#: the batched kernels is faster.
#: Measured side by side (benchmarks/bench_env.fourwis_vector, joint / oracle, env-steps/s, slow
#: host of 2026-12-01): 4 cars 1,426 / 1,974 Python, 2,789 / 3,906 compiled; 32: 4,916 / 10,287
#: against 4,788 / 11,878; 64: 7,320 / 15,589 against 5,400 / 13,352.
MAX_BATCH = 32


def supports(loop) -> bool:
    """Whether the closed loop ``loop`` has a compiled form (see the module docstring) and at
    most MAX_BATCH vehicles."""
    from fourwis.estimation import Oracle, StateEstimator

    controller = type(loop.controller)  # (a subclass that changes the call but inherits kernel_form: Python)
    return (
        loop.batch_size <= MAX_BATCH
        and type(loop.estimator) in (Oracle, StateEstimator)
        and isinstance(loop.road, RoadTables)
        and not loop.sensors.faults
        and (
            loop.controller is None
            or controller is StabilityController
            or ("kernel_form" in vars(controller) and "__call__" in vars(controller))
        )
        and loop.steering_drivers.compiled is not None
        and loop.speed_drivers.compiled is not None
    )


def reports_truth(estimator) -> bool:
    """Whether the compiled path hands the truth over as ``estimator``'s estimate (the oracle)."""
    from fourwis.estimation import Oracle

    return type(estimator) is Oracle


def _estimator_form(estimator, batch: int) -> tuple:
    from fourwis.estimation import StateEstimator

    if isinstance(estimator, StateEstimator):
        members = estimator.noise_arrays[0].shape[0]
        if members not in (1, batch):
            raise ValueError(f"per-member noise for {members} members, the batch has {batch}")
        return (
            STATE_ESTIMATOR,
            estimator.kind_code,
            estimator.params.packed,
            float(estimator.dt),
            float(estimator.huber_c),
            float(estimator.zero_point_time_constant),
            float(estimator.stuck_samples),
            float(estimator.slide_rate),
            float(estimator.yaw_balance_std),
            *estimator.noise_arrays,
            tuple(getattr(estimator, name) for name in STATE_FIELDS),
            np.arange(batch),
            np.zeros(batch, np.int64),
        )
    return _NO_ESTIMATOR


#: the estimator arguments of the oracle (which the kernel does not read)
_NO_ESTIMATOR = (
    ORACLE,
    0,
    np.zeros(1),
    0.0,
    0.0,
    0.0,
    0.0,
    0.0,
    0.0,
    np.zeros((1, 1)),
    np.zeros((1, 1)),
    np.zeros(1),
    (
        np.zeros((1, 1)),
        np.zeros((1, 1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros(1),
        np.zeros((1, 1)),
    ),
    np.zeros(1, np.int64),
    np.zeros(1, np.int64),
)


#: the DYC arguments of the other controller modes (which the kernel does not read)
_NO_STABILITY = (np.zeros(1), np.zeros(1), np.zeros((1, 3)), (0.0,) * 11, np.zeros((1, M_WIDTH)))


def _controller_form(controller, params, batch: int) -> tuple:
    if controller is None:
        return (NO_CONTROLLER, np.zeros((batch, 1)), 0.0, 0.0, *allocator_limits(params), *_NO_STABILITY)
    if isinstance(controller, StabilityController):  # (its own vehicle parameters, as from Python)
        return (STABILITY, np.zeros((batch, 1)), 0.0, 0.0, *controller.kernel_arrays(batch))
    return controller.kernel_form() + _NO_STABILITY


def advance(loop, n: int, moving: np.ndarray | None, arrays: Arrays) -> np.ndarray:
    """``n`` steps of the vehicles of ``loop`` selected by ``moving`` (B,) bool (all if None),
    from the loop's current sample ``arrays`` (updated in place, as are ``loop``'s state, aux,
    clock, sensors and estimator); returns the steps' records (n, B, R_WIDTH) (:func:`_record`;
    a held vehicle's rows stay NaN). A failing vehicle raises the error the Python loop raises
    for it (ValueError, FloatingPointError; the lowest failing index, where the Python loop
    raises the first failure in time); the loop's vehicles then stand at different steps, each
    with its plant, clock, sensors and estimator where it stopped: reset them."""
    params, dt, batch = loop.params, loop.dt, loop.batch_size
    progress = np.zeros(batch, dtype=np.int64)
    if moving is not None:
        progress[~moving] = n
    status, value = np.zeros(batch, dtype=np.int64), np.zeros(batch, dtype=np.int64)
    state, aux, k = loop.state.copy(), loop.aux.copy(), loop.k.copy()
    reached, controls = np.zeros_like(state), np.zeros((batch, NU))
    records = np.full((n, batch, R_WIDTH), np.nan)
    road = loop.road
    plant = (
        params.kernel_array,
        params.kernel_tyre_array,
        road.base_mu,
        road.rects,
        road.mu_given,
        road.use_map,
        RK4_REAL_LIMIT * params.min_relaxation_length / dt,
        params.contact_point_reach,
    )
    sensors = loop.sensors
    sensor_arrays = sensors.kernel_arrays()
    estimator = _estimator_form(loop.estimator, batch)
    controller = _controller_form(loop.controller, params, batch)
    sample = (
        arrays.t,
        arrays.readings,
        arrays.valid,
        arrays.truth,
        arrays.estimate,
        arrays.steering_wheel,
        arrays.front_steer,
        arrays.base_torques,
    )
    steering, speed = loop.steering_drivers.compiled, loop.speed_drivers.compiled
    drive_torque = np.zeros(batch)
    while True:
        cars = np.flatnonzero(progress < n)
        if not len(cars):
            break
        drivers = (
            steering.codes,
            steering.tables,
            follower_form(steering.follower),
            speed.codes,
            speed.tables,
            follower_form(speed.follower),
            float(params.steering_ratio),
            float(params.max_front_steer),
            drive_torque,
        )
        _run(
            cars,
            n,
            progress,
            status,
            value,
            k,
            dt,
            state,
            aux,
            plant,
            sensor_arrays,
            drivers,
            estimator,
            controller,
            sample,
            reached,
            controls,
            records,
        )
        for b in cars[status[cars] != DONE]:
            code = status[b]
            if code == NEEDS_NOISE:
                sensors.refill(b)
            elif code == NEEDS_RESPONSES:
                follower = _lacking(steering, speed, b, int(value[b]))
                if follower is not None:  # (None: added for another vehicle just now)
                    follower.add_responses(int(value[b]))
            else:  # (every car's plant and clock where its sensors and estimator are)
                loop.state, loop.aux, loop.k = state, aux, k
                raise _failure(loop, b, code, int(value[b]), state, reached, controls, arrays)
    loop.state, loop.aux, loop.k = state, aux, k
    return records


def _lacking(steering, speed, b: int, tenths: int):
    """Vehicle b's path follower (its steering driver's or its speed driver's) that has no preview
    responses at ``tenths`` x 0.1 m/s; None if both have them."""
    for drivers in (steering, speed):
        if drivers.codes[b] == FOLLOWER:
            rows = drivers.follower.response_row
            if tenths >= len(rows) or rows[tenths] < 0:
                return drivers.follower
    return None


def _failure(loop, b: int, code: int, value: int, state, reached, controls, arrays: Arrays) -> Exception:
    """The error of vehicle b's failed step (kernel status ``code``, part status ``value``)."""
    if code == BAD_TRUTH:
        return ValueError(f"non-finite true value on sensor channel {CHANNELS[value]!r}")
    if code == ESTIMATOR_FAILED:
        return loop.estimator.step_error(b, value, arrays.readings[b])
    if code == ALLOCATION_FAILED and isinstance(loop.controller, StabilityController):
        return allocation_error(value, allocation_inputs(loop.controller.kernel_arrays(loop.batch_size)[-1][b]))
    if code == ALLOCATION_FAILED:
        _, action, max_yaw_moment, max_rear_steer = loop.controller.kernel_form()[:4]
        est = arrays.estimate[b : b + 1]
        rear = action[b : b + 1, 1] * max_rear_steer if action.shape[1] == 2 else np.zeros(1)
        inputs = (
            arrays.base_torques[b : b + 1],
            action[b : b + 1, 0] * max_yaw_moment,
            est[:, O_FZ : O_FZ + 4],
            est[:, O_MU : O_MU + 4],
            np.zeros((1, 4)),
            est[:, O_U],
            arrays.front_steer[b : b + 1],
            rear,
        )
        return allocation_error(value, inputs)
    if code == TOO_FAST_FOR_RELAXATION:
        check_relaxation_step(state[b : b + 1], loop.params, loop.dt)
    if code == PLANT_FAILED:
        return plant_error(b, value, state[b], controls[b], reached[b])
    if code == BAD_FOLLOWER_STATE:
        return bad_follower_state(b, state[b])
    return RuntimeError(f"vehicle {b}: compiled closed-loop status {code} ({value})")


def step_records(rows: np.ndarray, oracle: bool):
    """The records (n, B, R_WIDTH) of :func:`advance` as one stacked
    :class:`envs.simulation.StepRecord` (views); ``oracle``: the estimate is the truth."""
    from fourwis.envs.simulation import StepRecord

    t = rows[..., R_T]
    truth = rows_estimate(rows[..., R_TRUTH:R_ESTIMATE])
    reading = SensorReading(rows[..., R_READINGS:R_TRUTH], np.ones(rows.shape[:2] + (13,), dtype=bool), t)
    return StepRecord(
        t,
        rows[..., R_STATE:R_AUX],
        rows[..., R_AUX:R_CONTROLS],
        rows[..., R_CONTROLS:R_READINGS],
        rows[..., R_STEERING_WHEEL],
        reading,
        truth,
        truth if oracle else rows_estimate(rows[..., R_ESTIMATE:]),
    )

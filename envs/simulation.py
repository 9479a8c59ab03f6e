"""Closed-loop simulation of one scenario: driver, plant, sensors, estimator, controller.

Each 2 ms step (the paper's sample time): the sensors measure the plant, the estimator turns
the readings into an :class:`estimation.types.Estimate`, the driver gives steering and base
torques (from the true pose and speed), the stability controller (if any) corrects the
torques and rear steer using the estimate only, and the plant advances one RK4 step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple, Protocol

import numpy as np
from tqdm import tqdm

from envs.road import RoadTables, contact_points
from envs.scenarios import Scenario, make_scenario
from envs.sensors import Fault, SensorModel, SensorParams
from envs.vehicle import (A_AX, A_AY, A_FZ, A_MU, C_DELTA_F, C_DELTA_R, C_TORQUE, NU, S_DELTA_F,
                          S_DELTA_R, S_OMEGA, S_R, S_TORQUE, S_U, S_V, derivatives, step)
from control import Command
from estimation.types import Estimate

DT = 0.002  #: physics, sensor and estimator step [s] (the paper samples at 2 ms)


class Controller(Protocol):
    """A stability controller: sees the estimate and the driver's commands, never the truth."""

    def reset(self, scenario: Scenario) -> None: ...

    def __call__(self, t: float, estimate: Estimate, front_steer: np.ndarray, base_torques: np.ndarray) -> Command: ...


class Estimator(Protocol):
    """A batched estimator: sensor readings (B, 13) in, estimate out (``needs_truth``: oracle only).

    ``reset`` (re)initialises the members selected by ``mask`` (B,) bool (all if None) from a
    reading and the initial speed [m/s] (B,) (a car starts from a known speed, like a
    vehicle's speed estimate that has been running since standstill).
    """

    needs_truth: bool

    def reset(self, reading, initial_speed: np.ndarray, mask: np.ndarray | None = None) -> None: ...

    def step(self, reading, truth: Estimate | None = None) -> Estimate: ...


def sensor_truth(state: np.ndarray, aux: np.ndarray) -> np.ndarray:
    """The 13 measured quantities (B, 13) in :data:`envs.sensors.CHANNELS` order from plant state/aux."""
    return np.concatenate([aux[:, [A_AX, A_AY]], state[:, [S_R]], state[:, S_OMEGA:S_OMEGA + 4],
                           state[:, [S_DELTA_F, S_DELTA_R]], state[:, S_TORQUE:S_TORQUE + 4]], axis=1)


def true_estimate(state: np.ndarray, aux: np.ndarray) -> Estimate:
    """The truth in estimator form: what a perfect estimator would report."""
    u, v = state[:, S_U], state[:, S_V]
    zeros = np.zeros_like(u)
    return Estimate(u=u.copy(), v=v.copy(), beta=np.arctan2(v, np.abs(u)), r=state[:, S_R].copy(),
                    ax=aux[:, A_AX].copy(), ay=aux[:, A_AY].copy(), mu=aux[:, A_MU:A_MU + 4].copy(),
                    fz=aux[:, A_FZ:A_FZ + 4].copy(), beta_std=zeros, mu_std=np.zeros_like(aux[:, A_MU:A_MU + 4]))


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


def _stack(items: list[Estimate]) -> Estimate:
    return Estimate(*(np.stack([getattr(e, f)[0] for e in items]) for f in Estimate._fields))


class StepRecord(NamedTuple):
    """One 2 ms sample of a closed loop, taken before the plant advances (batch of 1)."""

    t: float
    state: np.ndarray
    aux: np.ndarray
    controls: np.ndarray
    steering_wheel: float
    reading: object
    truth: Estimate
    estimate: Estimate


class ClosedLoop:
    """Driver + sensors + estimator + controller + plant for one vehicle, advanced 2 ms at a time.

    Used by :func:`simulate` (records every sample) and the Gymnasium env (an agent's command
    enters through ``controller``). ``rng`` seeds the sensor noise and faults.
    """

    def __init__(self, scenario: Scenario, controller: Controller | None, estimator: Estimator | str | None,
                 rng: np.random.Generator, sensor_params: SensorParams | None = None, faults: Sequence[Fault] = (),
                 dt: float = DT):
        params = scenario.vehicle_params
        if isinstance(estimator, str) or estimator is None:
            from estimation import make_estimator

            estimator = make_estimator(estimator or "oracle", params, dt)
        self.scenario, self.controller, self.estimator, self.dt = scenario, controller, estimator, dt
        self.params = params
        self.sensors = SensorModel(sensor_params or SensorParams(), tuple(faults), 1, rng)
        self.state = scenario.initial_state()
        self.speed_driver = scenario.speed_driver()
        self.road = RoadTables.from_roads(scenario.road, 1) if scenario.road.table() is not None else scenario.road
        if controller is not None:
            controller.reset(scenario)
        gx, gy = contact_points(self.state, params)  # diagnostics of the initial state
        _, self.aux = derivatives(self.state, np.zeros((1, NU)), scenario.road.mu_at(gx, gy), params)
        self.k = 0

    @property
    def t(self) -> float:
        return self.k * self.dt

    def advance(self, integrate: bool = True) -> StepRecord:
        """Measure, estimate, drive and control at the current time; then (if ``integrate``)
        advance the plant one step. Returns the sample taken before the plant moved."""
        t, params = self.t, self.params
        reading = self.sensors.measure(sensor_truth(self.state, self.aux), t)
        truth = true_estimate(self.state, self.aux)
        if self.k == 0:
            self.estimator.reset(reading, np.array([self.scenario.speed]))
        estimate = self.estimator.step(reading, truth if self.estimator.needs_truth else None)
        steer_wheel = self.scenario.steering(t, self.state[0])
        controls = np.zeros((1, NU))
        controls[0, C_TORQUE:C_TORQUE + 4] = self.speed_driver(t, self.state[0])
        controls[0, C_DELTA_F] = steer_wheel / params.steering_ratio
        if self.controller is not None:
            command = self.controller(t, estimate, controls[:, C_DELTA_F].copy(),
                                      controls[:, C_TORQUE:C_TORQUE + 4].copy())
            controls[0, C_TORQUE:C_TORQUE + 4] = command.torques[0]
            controls[0, C_DELTA_R] = command.rear_steer[0]
        record = StepRecord(t, self.state[0].copy(), self.aux[0].copy(), controls[0].copy(), steer_wheel, reading,
                            truth, estimate)
        if integrate:
            self.state, self.aux = step(self.state, controls, params, self.road, self.dt)
            self.k += 1
        return record


def simulate(scenario: Scenario | str, controller: Controller | None = None, estimator: Estimator | str | None = None,
             seed: int = 0, sensor_params: SensorParams | None = None, faults: Sequence[Fault] = (),
             dt: float = DT, progress: bool = False) -> Trajectory:
    """Run ``scenario`` once; returns the :class:`Trajectory`.

    ``estimator``: an estimator object, a name for :func:`estimation.make_estimator`, or None
    (the oracle: the controller sees the truth). ``seed`` seeds the sensor noise and faults.
    """
    if isinstance(scenario, str):
        scenario = make_scenario(scenario)
    loop = ClosedLoop(scenario, controller, estimator, np.random.default_rng(seed), sensor_params, faults, dt)
    n = int(math.ceil(scenario.duration / dt - 1e-9))
    records = [loop.advance(integrate=k < n)
               for k in tqdm(range(n + 1), disable=not progress, desc=scenario.name, unit="step", mininterval=0.5)]
    return Trajectory(np.arange(n + 1) * dt, np.stack([r.state for r in records]), np.stack([r.aux for r in records]),
                      np.stack([r.controls for r in records]), np.array([r.steering_wheel for r in records]),
                      np.stack([r.reading.values[0] for r in records]), np.stack([r.reading.valid[0] for r in records]),
                      _stack([r.truth for r in records]), _stack([r.estimate for r in records]), scenario)

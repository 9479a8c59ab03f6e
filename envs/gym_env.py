"""Gymnasium environment: keep the 4WID-4WS car stable from the *estimated* state.

Each env step (``control_dt``, 20 ms) holds the agent's command for ten 2 ms substeps of the
closed loop (driver, noisy sensors, estimator, allocation, truth plant): the same
:class:`envs.simulation.ClosedLoop` the rest of fourwis runs, with a batch of one.

Observation (float32, ``observation="estimated"`` default; ``"true"`` fills the same slots
from the truth with zero uncertainty):

==== ============================================ ============
idx  quantity                                     scale
==== ============================================ ============
0    longitudinal speed u                         / 30 m/s
1    sideslip beta                                / 0.2 rad
2    yaw rate r                                   / 1 rad/s
3    longitudinal acceleration ax                 / 10 m/s^2
4    lateral acceleration ay                      / 10 m/s^2
5-8  road friction mu per wheel (FL, FR, RL, RR)  / 1
9    sideslip standard deviation                  / 0.05 rad
10   mean mu standard deviation                   / 0.3
11   reference yaw rate r_ref                     / 1 rad/s
12   front road-wheel steer of the driver         / 0.3 rad
13   yaw-rate error r - r_ref                     / 1 rad/s
==== ============================================ ============

``observation="sensors"``: the 13 raw channels (ax, ay, r, 4 wheel speeds, 2 steer angles,
4 torques) scaled by (10, 10, 1, 100 x4, 0.3 x2, 600 x4), then r_ref / 1.

Actions (float32 in [-1, 1]): ``action="yaw_moment"`` (default): [corrective yaw moment x
3000 N m, rear steer x max rear steer], allocated to the wheels by control/ within motor and
friction limits (from the estimate); ``"wheel_torques"``: four corrective torques x the motor
peak torque added to the driver's speed-holding torques. Out-of-range actions are clipped
and flagged in ``info["action_clipped"]``; NaN/inf actions raise ValueError.

Reward per step: -(e_r / 0.1)^2 - (beta / 0.05)^2 - 0.1 |a|^2 - (d / 1.0)^2 (d: lateral
deviation from the scenario's path, if it has one) times control_dt; -100 on termination.
Terminated: |beta| > 20 deg (spin-out) or more than 5 m from the path. Truncated: the
scenario's end (``max_episode_steps`` is set from the default duration at registration).
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from control import Command
from control.allocation import allocate_torques
from control.reference import reference_yaw_rate
from envs.metrics import SPIN_OUT_SIDESLIP, path_deviation
from envs.scenarios import SCENARIOS, make_scenario
from envs.sensors import Fault
from envs.simulation import ClosedLoop, StepRecord
from envs.vehicle import S_X, S_Y
from estimation import ESTIMATORS

MAX_YAW_MOMENT = 3000.0  #: yaw-moment action scale [N m]
MAX_PATH_DEVIATION = 5.0  #: termination distance from the path [m]
OBSERVATIONS = ("estimated", "true", "sensors")
ACTIONS = ("yaw_moment", "wheel_torques")
SENSOR_SCALE = np.array([10, 10, 1, 100, 100, 100, 100, 0.3, 0.3, 600, 600, 600, 600], dtype=float)


class _AgentController:
    """Turns the held agent action into wheel torques and rear steer each substep."""

    def __init__(self, params, action_mode: str):
        self.params, self.action_mode = params, action_mode
        self.action = np.zeros(2 if action_mode == "yaw_moment" else 4)

    def reset(self, scenario) -> None:
        self.action[:] = 0.0

    def __call__(self, t, estimate, front_steer, base_torques) -> Command:
        p = self.params
        if self.action_mode == "yaw_moment":
            moment = np.array([self.action[0] * MAX_YAW_MOMENT])
            torques, _ = allocate_torques(base_torques, moment, estimate.fz, estimate.mu, p)
            return Command(torques, np.array([self.action[1] * p.max_rear_steer]))
        limit = p.motor_peak_torque
        return Command(np.clip(base_torques + self.action[None, :] * limit, -limit, limit), np.zeros(1))


class YawStabilityEnv(gym.Env):
    """See the module docstring for observation, action, reward and termination."""

    metadata = {"render_modes": [], "render_fps": 50}

    def __init__(self, scenario: str = "random", speed_kph: float | None = None, mu=None, estimator: str = "joint",
                 observation: str = "estimated", action: str = "yaw_moment", control_dt: float = 0.02,
                 sensor_faults: tuple[Fault, ...] = (), render_mode: str | None = None):
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; known: {sorted(SCENARIOS)}")
        if estimator not in ESTIMATORS:
            raise ValueError(f"unknown estimator {estimator!r}; known: {list(ESTIMATORS)}")
        if observation not in OBSERVATIONS:
            raise ValueError(f"unknown observation {observation!r}; known: {list(OBSERVATIONS)}")
        if action not in ACTIONS:
            raise ValueError(f"unknown action {action!r}; known: {list(ACTIONS)}")
        substeps = control_dt / 0.002
        if not (control_dt > 0 and abs(substeps - round(substeps)) < 1e-9):
            raise ValueError(f"control_dt must be a positive multiple of 0.002 s, got {control_dt!r}")
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not available yet")
        self.overrides = {k: v for k, v in (("speed_kph", speed_kph), ("mu", mu)) if v is not None}
        make_scenario(scenario, **self.overrides)  # validate the overrides now
        self.scenario_name, self.estimator_name = scenario, estimator
        self.observation_mode, self.action_mode = observation, action
        self.substeps, self.control_dt = int(round(substeps)), control_dt
        self.sensor_faults = tuple(sensor_faults)
        self.render_mode = render_mode
        n_obs = 14
        self.observation_space = spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (2 if action == "yaw_moment" else 4,), np.float32)
        self._loop: ClosedLoop | None = None

    def _build(self, seed_rng: np.random.Generator) -> None:
        kwargs = dict(self.overrides)
        if self.scenario_name == "random":
            kwargs["seed"] = int(seed_rng.integers(2**31))
        scenario = make_scenario(self.scenario_name, **kwargs)
        self._controller = _AgentController(scenario.vehicle_params, self.action_mode)
        self._loop = ClosedLoop(scenario, self._controller, self.estimator_name,
                                np.random.default_rng(seed_rng.integers(2**63)), faults=self.sensor_faults)
        self._end = int(math.ceil(scenario.duration / 0.002))

    def _observe(self, rec: StepRecord) -> tuple[np.ndarray, float]:
        p = self._loop.params
        source = rec.truth if self.observation_mode == "true" else rec.estimate
        delta_f = rec.controls[4]
        r_ref = float(reference_yaw_rate(np.array([source.u[0]]), np.array([delta_f]), source.mu, p)[0])
        if self.observation_mode == "sensors":
            obs = np.concatenate([rec.reading.values[0] / SENSOR_SCALE, [r_ref]])
        else:
            e = source
            obs = np.array([e.u[0] / 30, e.beta[0] / 0.2, e.r[0], e.ax[0] / 10, e.ay[0] / 10, *e.mu[0],
                            e.beta_std[0] / 0.05, e.mu_std[0].mean() / 0.3, r_ref, delta_f / 0.3, e.r[0] - r_ref])
        return obs.astype(np.float32), r_ref

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._build(self.np_random)
        self._record = self._loop.advance(integrate=False)
        obs, _ = self._observe(self._record)
        return obs, {"truth": self._record.truth, "estimate": self._record.estimate}

    def step(self, action):
        if self._loop is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, dtype=float)
        if action.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action contains NaN or inf: {action}")
        clipped = np.clip(action, -1.0, 1.0)
        self._controller.action[:] = clipped
        for _ in range(self.substeps):
            self._loop.advance()
        self._record = self._loop.advance(integrate=False)
        rec = self._record
        obs, _ = self._observe(rec)
        truth = rec.truth
        p = self._loop.params
        r_ref_true = float(reference_yaw_rate(truth.u, np.array([rec.controls[4]]), truth.mu, p)[0])
        beta = float(truth.beta[0])
        deviation = self._deviation(rec)
        reward = -self.control_dt * (((truth.r[0] - r_ref_true) / 0.1) ** 2 + (beta / 0.05) ** 2
                                     + 0.1 * float(np.sum(clipped**2)) + (deviation / 1.0) ** 2)
        terminated = bool(abs(beta) > SPIN_OUT_SIDESLIP or deviation > MAX_PATH_DEVIATION)
        if terminated:
            reward -= 100.0
        truncated = self._loop.k >= self._end
        if not np.all(np.isfinite(obs)):
            raise FloatingPointError("non-finite observation: the estimator diverged")
        info = {"truth": truth, "estimate": rec.estimate, "action_clipped": bool(np.any(clipped != action)),
                "peak_beta": abs(beta), "yaw_rate_error": float(truth.r[0] - r_ref_true), "path_deviation": deviation,
                "spin_out": abs(beta) > SPIN_OUT_SIDESLIP}
        return obs, float(reward), terminated, truncated, info

    def _deviation(self, rec: StepRecord) -> float:
        path = self._loop.scenario.reference_path
        if path is None:
            return 0.0
        return path_deviation(rec.state[S_X:S_X + 1], rec.state[S_Y:S_Y + 1], path)[1]

"""Gymnasium environments: keep the 4WID-4WS car stable from the *estimated* state.

Each env step (``control_dt``, 20 ms) holds the agent's command for ten 2 ms substeps of the
closed loop (driver, noisy sensors, estimator, allocation, truth plant): the same
:class:`envs.simulation.ClosedLoop` the rest of fourwis runs. One batched core
(:class:`YawStabilityCore`) serves both :class:`YawStabilityEnv` (batch of one) and the native
:class:`YawStabilityVectorEnv` (batch of N, autoreset by masks, in the same step or the next).

The observation table, actions, reward, termination and ``info`` are documented in
:class:`YawStabilityEnv`; :class:`YawStabilityVectorEnv` batches them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from fourwis.control.allocation import allocate_for_estimate, allocator_limits
from fourwis.control.esc import BrakeESC, outside_stable
from fourwis.control.reference import PhasePlaneRegion, reference_yaw_rate
from fourwis.core.checks import is_integer, is_number
from fourwis.core.types import Command, Estimate
from fourwis.envs.fmvss126 import characterise
from fourwis.envs.layout import A_AY, S_DELTA_F, S_DELTA_R, S_R, S_U, S_V, S_X, S_Y
from fourwis.envs.loop import HeldAction, Sample, wheel_torque_action
from fourwis.envs.metrics import (
    SPIN_OUT_SIDESLIP,
    CoursePaths,
    rolling_sideslip,
    sine_with_dwell_metrics,
    spun_sideslip,
)
from fourwis.envs.render import close_window, show_frame
from fourwis.envs.scenarios import SCENARIOS, Scenario, make_scenario
from fourwis.envs.sensors import CHANNEL_OF_SENSOR, S_BRAKE_SENSOR, Fault
from fourwis.envs.simulation import DT, ClosedLoop
from fourwis.estimation import check_estimator_name

MAX_YAW_MOMENT = 3000.0  #: yaw-moment action scale [N m]
MAX_PATH_DEVIATION = 5.0  #: termination distance from the path [m]
TERMINATION_PENALTY = 100.0
OBSERVATIONS = ("estimated", "true", "sensors")
ACTIONS = ("yaw_moment", "wheel_torques")
RENDER_MODES = ("rgb_array", "human")


class Slot(NamedTuple):
    """One observation slot: ``quantity`` / ``scale`` [``unit``]."""

    quantity: str
    scale: float
    unit: str


#: the wheels in the order of every per-wheel slot (the layouts' FL, FR, RL, RR)
WHEEL_NAMES = ("front-left", "front-right", "rear-left", "rear-right")
#: the observation from an estimate (``observation="estimated"``) or the truth (``"true"``)
STATE_SLOTS = (
    Slot("longitudinal speed u", 30.0, "m/s"),
    Slot("sideslip beta", 0.2, "rad"),
    Slot("yaw rate r", 1.0, "rad/s"),
    Slot("longitudinal acceleration ax", 10.0, "m/s²"),
    Slot("lateral acceleration ay", 10.0, "m/s²"),
    *(Slot(f"road friction mu, {wheel} wheel", 1.0, "-") for wheel in WHEEL_NAMES),
    Slot("sideslip standard deviation", 0.05, "rad"),
    Slot("mean road-friction standard deviation", 0.3, "-"),
    Slot("reference yaw rate r_ref (2-DOF steady state, friction-bounded)", 1.0, "rad/s"),
    Slot("the driver's front road-wheel angle", 0.3, "rad"),
    Slot("yaw-rate error r - r_ref", 1.0, "rad/s"),
)
#: the observation from the raw sensors (``observation="sensors"``): the simulated car's sensors
#: (envs.sensors.SENSORS, not the 16 channels of a log) as its reading's channels carry them, the
#: brake pressures netted into the wheel torques (:data:`SENSOR_CHANNELS`), then r_ref
SENSOR_SLOTS = (
    Slot("longitudinal acceleration ax", 10.0, "m/s²"),
    Slot("lateral acceleration ay", 10.0, "m/s²"),
    Slot("yaw rate r", 1.0, "rad/s"),
    *(Slot(f"wheel speed, {wheel}", 100.0, "rad/s") for wheel in WHEEL_NAMES),
    Slot("front road-wheel angle", 0.3, "rad"),
    Slot("rear road-wheel angle", 0.3, "rad"),
    *(Slot(f"net wheel torque (motor less brake), {wheel}", 600.0, "N m") for wheel in WHEEL_NAMES),
    Slot("reference yaw rate r_ref from the readings and friction 0.8", 1.0, "rad/s"),
)
N_OBS = len(STATE_SLOTS)
#: the reading's channel of each sensor slot of SENSOR_SLOTS (the brake pressures' channels are the
#: torque channels, read once)
SENSOR_CHANNELS = CHANNEL_OF_SENSOR[:S_BRAKE_SENSOR]
STATE_SCALE = np.array([slot.scale for slot in STATE_SLOTS])
SENSOR_SCALE = np.array([slot.scale for slot in SENSOR_SLOTS[:-1]])
NOMINAL_MU = 0.8  #: friction assumed for r_ref in the sensors observation
MAX_CONTROL_DT = 1.0  #: longest control step [s] (render_fps, 1 / control_dt, stays >= 1)


def _unknown_arguments(unknown: dict) -> None:
    if unknown:
        raise ValueError(f"unknown keyword argument(s) {sorted(unknown)}; see the YawStabilityEnv docstring")


@dataclass(frozen=True)
class EnvConfig:
    """Validated keyword arguments of the environments (see :class:`YawStabilityEnv`)."""

    scenario: str = "random"
    speed_kph: float | None = None
    mu: object = None
    estimator: str = "joint"
    observation: str = "estimated"
    action: str = "yaw_moment"
    control_dt: float = 0.02
    sensor_faults: tuple[Fault, ...] = field(default=())
    max_episode_steps: int | None = None
    scenario_kwargs: dict | None = None
    rear_steer: bool = True
    privileged: bool = False
    slip_control: bool = True
    esc: bool = False

    def __post_init__(self) -> None:
        for name, known in (
            ("scenario", sorted(SCENARIOS)),
            ("observation", list(OBSERVATIONS)),
            ("action", list(ACTIONS)),
        ):
            value = getattr(self, name)
            if not (isinstance(value, str) and value in known):
                raise ValueError(f"unknown {name} {value!r}; known: {known}")
        if not isinstance(self.estimator, str):
            raise ValueError(f"estimator must be a name, got {self.estimator!r}")
        check_estimator_name(self.estimator)
        dt = self.control_dt
        substeps = round(float(dt) / DT) if is_number(dt) and math.isfinite(dt) else 0
        # (relative to float32's precision: np.float32(0.02) is 0.0199999996)
        if not (1 <= substeps <= round(MAX_CONTROL_DT / DT) and abs(float(dt) - substeps * DT) <= 1e-6 * float(dt)):
            raise ValueError(f"control_dt must be a multiple of {DT} s up to {MAX_CONTROL_DT} s, got {dt!r}")
        object.__setattr__(self, "control_dt", substeps * DT)  # (a numpy or integer step as the float it stands for)
        try:  # a Fault's fields as a dict too: what a run's config.json (and --env-kwargs JSON) holds
            faults = tuple(Fault(**f) if isinstance(f, dict) else f for f in (self.sensor_faults or ()))
        except TypeError:
            faults = None
        if faults is None or not all(isinstance(f, Fault) for f in faults):
            raise ValueError(
                f"sensor_faults must be a sequence of envs.sensors.Fault (or of dicts of its fields), "
                f"got {self.sensor_faults!r}"
            )
        object.__setattr__(self, "sensor_faults", faults)
        if self.max_episode_steps is not None and not (
            is_integer(self.max_episode_steps) and self.max_episode_steps > 0
        ):
            raise ValueError(f"max_episode_steps must be a positive integer, got {self.max_episode_steps!r}")
        if self.scenario_kwargs is not None and not (
            isinstance(self.scenario_kwargs, dict) and all(isinstance(k, str) for k in self.scenario_kwargs)
        ):
            raise ValueError(f"scenario_kwargs must be a dict of scenario arguments, got {self.scenario_kwargs!r}")
        for key, value in (("speed_kph", self.speed_kph), ("mu", self.mu)):
            if value is not None and key in (self.scenario_kwargs or {}):
                raise ValueError(f"{key} is given both as an argument and in scenario_kwargs; give it once")
        if self.scenario == "random" and "seed" in (self.scenario_kwargs or {}):
            raise ValueError(
                "the random scenario's seed is drawn from reset(seed=...) each episode; scenario_kwargs cannot fix it"
            )
        for name in ("rear_steer", "privileged", "slip_control", "esc"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        make_scenario(self.scenario, **self.overrides)  # validate the overrides now

    @property
    def overrides(self) -> dict:
        named = {k: v for k, v in (("speed_kph", self.speed_kph), ("mu", self.mu)) if v is not None}
        return {**(self.scenario_kwargs or {}), **named}

    @property
    def substeps(self) -> int:
        return int(round(self.control_dt / DT))

    @property
    def render_fps(self) -> int | float:
        """Frames per second of a rendered episode: one per control step (an integer where
        1 / control_dt is one)."""
        fps = 1 / self.control_dt
        return int(round(fps)) if abs(fps - round(fps)) < 1e-9 else fps

    @property
    def observation_size(self) -> int:
        """N_OBS agent slots, followed by the truth's N_OBS when ``privileged``."""
        return 2 * N_OBS if self.privileged else N_OBS

    @property
    def action_size(self) -> int:
        return (2 if self.rear_steer else 1) if self.action == "yaw_moment" else 4

    def draw(self, rng: np.random.Generator) -> tuple[Scenario, np.random.Generator]:
        """An episode's scenario and sensor generator, both drawn from the episode's ``rng``."""
        kwargs = dict(self.overrides)
        if self.scenario == "random":
            kwargs["seed"] = int(rng.integers(2**31))
        return make_scenario(self.scenario, **kwargs), np.random.default_rng(rng.integers(2**63))


def state_observation(e: Estimate, delta_f: np.ndarray, params) -> np.ndarray:
    """The observation (B, N_OBS) of STATE_SLOTS from an estimate (or the truth) and the
    driver's front road-wheel angle ``delta_f`` (B,) [rad]."""
    r_ref = reference_yaw_rate(e.u, delta_f, e.mu, params)
    values = np.column_stack(
        [e.u, e.beta, e.r, e.ax, e.ay, e.mu, e.beta_std, e.mu_std.mean(axis=1), r_ref, delta_f, e.r - r_ref]
    )
    return values / STATE_SCALE


class AgentController:
    """Turns the held agent actions (B, n) into wheel torques and rear steer each substep (the
    compiled loop runs :class:`fourwis.envs.loop.HeldAction`, this class's :meth:`kernel`; a call
    computes the same in numpy), with the car's ESC beneath them if ``config.esc``."""

    def __init__(self, params, config: EnvConfig, batch_size: int):
        self.params, self.action_mode = params, config.action
        self.action = np.zeros((batch_size, config.action_size))
        self.esc, self.esc_on = BrakeESC(params), bool(config.esc)

    def reset(self) -> None:
        self.action[:] = 0.0
        self.esc.reset()

    def __call__(self, t, estimate, front_steer, base_torques) -> Command:
        p = self.params
        rear = np.zeros(len(base_torques))
        if self.action_mode == "yaw_moment":
            if self.action.shape[1] == 2:
                rear = self.action[:, 1] * p.max_rear_steer
            first = outside_stable(self.esc.settings, estimate, front_steer)
            torques = allocate_for_estimate(
                base_torques, self.action[:, 0] * MAX_YAW_MOMENT, estimate, p, front_steer=front_steer,
                rear_steer=rear, stability_first=first,
            ).torques  # fmt: skip
        else:
            torques = wheel_torque_action(base_torques, self.action, p.motor_peak_torque, p.brake_peak_torque)
        if self.esc_on:
            torques = self.esc(t, estimate, front_steer, torques).torques
        return Command(torques, rear)

    def kernel(self) -> HeldAction:
        """This controller as the compiled loop runs it (the held actions themselves)."""
        p = self.params
        yaw_moment = self.action_mode == "yaw_moment"
        return HeldAction(
            self.action, yaw_moment, MAX_YAW_MOMENT, float(p.max_rear_steer), allocator_limits(p),
            p.brake_peak_torque, self.esc.kernel(len(self.action)), self.esc_on,
        )  # fmt: skip


class _EpisodeStats:
    """Running per-vehicle episode statistics (B,), plus the 2 ms series an SWD verdict needs."""

    def __init__(self, batch_size: int):
        self.length = np.zeros(batch_size, dtype=np.int64)
        self.ret = np.zeros(batch_size)
        self.yaw_sq = np.zeros(batch_size)
        self.peak_beta = np.zeros(batch_size)
        self.peak_phase_plane = np.zeros(batch_size)
        self.max_deviation = np.zeros(batch_size)
        self.spun = np.zeros(batch_size, dtype=bool)
        self.series: list[list] = [[] for _ in range(batch_size)]

    def clear(self, members: np.ndarray) -> None:
        for name in ("length", "ret", "yaw_sq", "peak_beta", "peak_phase_plane", "max_deviation", "spun"):
            getattr(self, name)[members] = 0
        for b in members:
            self.series[b] = []


class YawStabilityCore:
    """The batched environment logic for B vehicles (one :class:`ClosedLoop`).

    ``rngs``: one episode generator per vehicle (the env's ``np_random``); each episode draws
    its scenario and sensor noise from it, so vehicle b of a batch reproduces a single env
    seeded like it, bit for bit.
    """

    def __init__(self, config: EnvConfig, rngs: list[np.random.Generator]):
        self.config = config
        self.batch_size = len(rngs)
        scenarios, sensor_rngs = zip(*(config.draw(rng) for rng in rngs))
        params = scenarios[0].vehicle_params
        self.controller = AgentController(params, config, self.batch_size)
        self.loop = ClosedLoop(
            list(scenarios),
            self.controller,
            config.estimator,
            list(sensor_rngs),
            faults=config.sensor_faults,
            slip_control=config.slip_control,
        )
        self.params = params
        self.stats = _EpisodeStats(self.batch_size)
        self._ends = self._end_steps(scenarios)
        self._paths = CoursePaths([s.reference_path for s in scenarios])
        #: the vehicles whose strip-chart history is recorded (B,) bool (set by envs that render)
        self.traced = np.zeros(self.batch_size, dtype=bool)
        self._renderer = None
        self._traces: list[list[tuple[float, float, float, float]]] = [[] for _ in range(self.batch_size)]

    @staticmethod
    def _end_steps(scenarios) -> np.ndarray:
        return np.array([int(math.ceil(s.duration / DT - 1e-9)) for s in scenarios])

    def reset_members(self, mask: np.ndarray, rngs: list[np.random.Generator]) -> None:
        """New episodes for the vehicles selected by ``mask`` (B,) bool, drawn from ``rngs``."""
        members = np.flatnonzero(mask)
        scenarios, sensor_rngs = zip(*(self.config.draw(rng) for rng in rngs))
        self.loop.reset_members(mask, list(scenarios), list(sensor_rngs))
        self.controller.esc.reset(mask)
        self._ends[members] = self._end_steps(scenarios)
        self._paths.replace(members, [s.reference_path for s in scenarios])
        self.stats.clear(members)
        for b in members:
            self._traces[b] = []

    def observe(self, sample: Sample | None = None) -> np.ndarray:
        """Observations (B, observation_size) float32 at the current time (from ``sample``, the
        loop's current sample, if the caller has taken it already)."""
        s = self.loop.sample() if sample is None else sample
        delta_f = s.front_steer
        if self.config.observation == "sensors":
            values = s.reading.values[:, SENSOR_CHANNELS]
            r_ref = reference_yaw_rate(
                values[:, 3:7].mean(axis=1) * self.params.wheel_radius,
                values[:, 7],
                np.full((self.batch_size, 4), NOMINAL_MU),
                self.params,
            )
            obs = np.concatenate([values / SENSOR_SCALE, r_ref[:, None]], axis=1)
        else:
            obs = state_observation(s.truth if self.config.observation == "true" else s.estimate, delta_f, self.params)
        if self.config.privileged:
            obs = np.concatenate([obs, state_observation(s.truth, delta_f, self.params)], axis=1)
        if not np.all(np.isfinite(obs)):
            b = int(np.flatnonzero(~np.all(np.isfinite(obs), axis=1))[0])
            raise FloatingPointError(f"non-finite observation for vehicle {b}: the estimator diverged")
        return obs.astype(np.float32)

    def step(
        self, actions: np.ndarray, moving: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        """Advance every vehicle, or those selected by ``moving`` (B,) bool, one control step
        under ``actions`` (B, n) (already validated). A vehicle held still earns reward 0 and
        neither terminates nor truncates; its episode statistics stand."""
        clipped = np.clip(actions, -1.0, 1.0)
        self.controller.action[:] = clipped
        moved = np.ones(self.batch_size, dtype=bool) if moving is None else moving
        swd = [b for b, s in enumerate(self.loop.scenarios) if s.name == "sine_with_dwell" and moved[b]]
        steps = self.loop.advance_steps(self.config.substeps, moving, records=bool(swd))
        for b in swd:
            self.stats.series[b].extend(
                zip(
                    steps.t[:, b],
                    steps.steering_wheel[:, b],
                    steps.state[:, b, S_R],
                    steps.aux[:, b, A_AY],
                    steps.truth.beta[:, b],
                )
            )
        s = self.loop.sample()
        obs = self.observe(s)
        truth = s.truth
        r_ref = reference_yaw_rate(truth.u, s.front_steer, truth.mu, self.params)
        yaw_error = truth.r - r_ref
        beta = truth.beta
        phase_plane = PhasePlaneRegion.default().state_index(truth)
        deviation = self._deviation()
        reward = -self.config.control_dt * (
            (yaw_error / 0.1) ** 2 + (beta / 0.05) ** 2 + 0.1 * np.sum(clipped**2, axis=1) + deviation**2
        )
        spin = np.abs(beta) > SPIN_OUT_SIDESLIP
        if np.count_nonzero(spin):  # (rare: the steering geometry only where it can matter)
            state = self.loop.state
            spin = spun_sideslip(
                beta,
                rolling_sideslip(
                    state[:, S_U],
                    state[:, S_DELTA_F],
                    state[:, S_DELTA_R],
                    self.params.cg_to_front,
                    self.params.cg_to_rear,
                ),
                speed=np.hypot(state[:, S_U], state[:, S_V]),
            )
        terminated = (spin | (deviation > MAX_PATH_DEVIATION)) & moved
        reward = np.where(moved, reward - TERMINATION_PENALTY * terminated, 0.0)
        st = self.stats  # (the held vehicles' statistics add 0: non-negative peaks times False)
        st.length += moved
        st.ret += reward
        st.yaw_sq += yaw_error**2 * moved
        st.peak_beta = np.maximum(st.peak_beta, np.abs(beta) * moved)
        st.peak_phase_plane = np.maximum(st.peak_phase_plane, phase_plane * moved)
        st.max_deviation = np.maximum(st.max_deviation, deviation * moved)
        st.spun |= spin & moved
        truncated = (self.loop.k >= self._ends) & moved
        if self.config.max_episode_steps is not None:
            truncated |= (st.length >= self.config.max_episode_steps) & moved
        if self.traced.any():  # t, r, r_ref, beta for the strip charts of render()
            for b in np.flatnonzero(moved & self.traced):
                self._traces[b].append((s.t[b], truth.r[b], r_ref[b], beta[b]))
        info = {
            "truth": truth,
            "estimate": s.estimate,
            "action_clipped": np.any(clipped != actions, axis=1),
            "beta": beta,
            "yaw_rate_error": yaw_error,
            "path_deviation": deviation,
            "spin_out": spin,
            "phase_plane_index": phase_plane,
            "episode_metrics": [
                self.episode_metrics(b) if terminated[b] or truncated[b] else None for b in range(self.batch_size)
            ],
        }
        return obs, reward, terminated, truncated, info

    def _deviation(self) -> np.ndarray:
        """Distance [m] (B,) from the course's reference path while the car is alongside it (0
        before its start and past its end, where the run-out continues straight: measured to
        the path's end point there, a car leaving a course cleanly passed 5 m and was
        terminated), as the comparison's path metrics count it."""
        return self._paths.deviation(self.loop.state[:, S_X], self.loop.state[:, S_Y])

    def episode_metrics(self, b: int) -> dict:
        """Vehicle b's episode so far (see the YawStabilityEnv docstring)."""
        st = self.stats
        spun = bool(st.spun[b])
        out = {
            "length": int(st.length[b]),
            "return": float(st.ret[b]),
            "yaw_rate_tracking_rms": float(np.sqrt(st.yaw_sq[b] / max(st.length[b], 1))),
            "peak_beta": float(st.peak_beta[b]),
            "peak_phase_plane_index": float(st.peak_phase_plane[b]),
            "max_path_deviation": float(st.max_deviation[b]),
            "spin_out": bool(spun),
        }
        if st.series[b]:
            t, swa, r, ay, beta = np.array(st.series[b]).T
            try:
                # (A of this car: the responsiveness criterion applies from 5A; characterised
                # once per process, a few seconds)
                res = sine_with_dwell_metrics(t, swa, r, ay, sideslip=beta, A=characterise(self.params))
                out.update(
                    fmvss126_ratio_1000=res.yaw_rate_ratio_1000,
                    fmvss126_ratio_1750=res.yaw_rate_ratio_1750,
                    fmvss126_displacement=res.lateral_displacement,
                    fmvss126_passed=res.passed and not spun,
                )
            except ValueError:  # cut short before the manoeuvre could be evaluated
                out.update(fmvss126_passed=False)
        return out

    def render(self, b: int = 0, moment: _Moment | None = None) -> np.ndarray:
        """A frame of vehicle ``b`` (see :mod:`envs.render`) now, or at a ``moment`` taken earlier."""
        if self._renderer is None:
            from fourwis.envs.render import Renderer

            self._renderer = Renderer()
        moment = moment or self.moment()
        trace = moment.traces[b][: moment.trace_lengths[b]]
        return self._renderer.frame(moment, b, np.array(trace).reshape(-1, 4))

    def moment(self) -> _Moment:
        """What a frame draws, as it is now: copies, and each trace list with its length (a
        trace only grows until a reset replaces the list)."""
        loop = self.loop
        return _Moment(
            loop.state.copy(),
            loop.aux.copy(),
            loop.t,
            list(loop.scenarios),
            loop.params,
            list(self._traces),
            [len(trace) for trace in self._traces],
        )


class _Moment(NamedTuple):
    """The closed loop's state, diagnostics, clocks, scenarios and parameters at one instant,
    and each vehicle's trace length then: what :class:`envs.render.Renderer` draws from."""

    state: np.ndarray
    aux: np.ndarray
    t: np.ndarray
    scenarios: list
    params: object
    traces: list
    trace_lengths: list[int]


class _CarFrames(Sequence):
    """The native vector env's rgb_array frames, one per car, of the moment ``render()`` was
    called, each drawn when first read (~90 ms a frame: gymnasium's RecordVideo with
    ``record_first_only`` draws car 0 alone)."""

    def __init__(self, core: YawStabilityCore):
        self._core, self._moment, self._frames = core, core.moment(), {}

    def __len__(self) -> int:
        return self._core.batch_size

    def __getitem__(self, b):
        if isinstance(b, slice):
            return [self[i] for i in range(*b.indices(len(self)))]
        b = range(len(self))[b]  # (IndexError past the end; negative indices count from the end)
        if b not in self._frames:
            self._frames[b] = self._core.render(b, self._moment)
        return self._frames[b]


def _first(estimate: Estimate) -> Estimate:
    """The first vehicle's fields of a batched estimate."""
    return Estimate(*(field[0] for field in estimate))


def _check_actions(actions, shape: tuple[int, ...]) -> np.ndarray:
    actions = np.asarray(actions, dtype=float)
    if actions.shape != shape:
        raise ValueError(f"action must have shape {shape}, got {actions.shape}")
    if not np.all(np.isfinite(actions)):
        raise ValueError(f"action contains NaN or inf: {actions}")
    return actions


def _spaces(config: EnvConfig) -> tuple[spaces.Box, spaces.Box]:
    return (
        spaces.Box(-np.inf, np.inf, (config.observation_size,), np.float32),
        spaces.Box(-1.0, 1.0, (config.action_size,), np.float32),
    )


def _check_render_mode(render_mode: str | None) -> None:
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"unknown render_mode {render_mode!r}; known: {list(RENDER_MODES)}")


class YawStabilityEnv(gym.Env):
    """One car (the batched core with B = 1): keep it stable from the estimated state.

    **Observation** (float32, ``N_OBS`` slots): :data:`STATE_SLOTS` from the estimate
    (``observation="estimated"``, the default) or from the truth with zero uncertainty
    (``"true"``); ``"sensors"``: :data:`SENSOR_SLOTS`, the car's raw sensors (the brake
    pressures netted into the wheel torques) and r_ref. The fixed-friction estimators report
    their nominal 0.8 in the friction slots and zero friction uncertainty. ``privileged=True``
    appends the truth's ``N_OBS`` slots (asymmetric actor-critic: ``training.asymmetric``).

    **Action** (float32 in [-1, 1]): ``action="yaw_moment"``: [corrective yaw moment x
    MAX_YAW_MOMENT N m, rear road-wheel angle x the rear servo's range] (``rear_steer=False``:
    the moment alone), allocated to the wheels within the motors' and tyres' limits from the
    estimate; ``"wheel_torques"``: four corrective net wheel torques added to the driver's, a
    positive action times the motor's peak torque, a negative one times the motor's and the
    friction brake's peaks (braking; the wheels' actuators split it between motor and friction
    brake). Out-of-range actions are clipped (``info["action_clipped"]``); NaN raises. Every wheel
    torque passes the car's wheel-slip control, ABS and traction control
    (:mod:`fourwis.control.wheel_slip`), unless ``slip_control=False``; ``esc=True`` puts the
    brake-based ESC (:mod:`fourwis.control.esc`, the controller ``esc``) beneath the agent's
    command, as in a production car.

    **Reward** per step: -(e_r / 0.1)^2 - (beta / 0.05)^2 - 0.1 |a|^2 - (d / 1 m)^2, times
    ``control_dt`` (e_r the true yaw rate less the reference [rad/s], beta the true sideslip
    [rad], d the distance from the scenario's path [m] while the car is alongside it);
    -TERMINATION_PENALTY on termination.

    **Episode end**: terminated on a spin-out (:func:`envs.metrics.spun_sideslip`) or more than
    MAX_PATH_DEVIATION from the path; truncated at the scenario's end (``gym.make`` adds a
    TimeLimit of ``MAX_EPISODE_STEPS``). The last step's ``info["episode_metrics"]`` holds the
    episode's length, return, tracking and sideslip peaks (and FMVSS 126's verdict on
    ``sine_with_dwell``).

    ``info``: ``truth`` and ``estimate`` (:class:`fourwis.core.types.Estimate`), ``action_clipped``,
    ``beta``, ``yaw_rate_error``, ``path_deviation``, ``spin_out``, ``phase_plane_index``.
    Unknown keywords and bad values raise ValueError naming them. The docs' environment page has
    the tables.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 50}

    def __init__(
        self,
        scenario: str = "random",
        speed_kph: float | None = None,
        mu=None,
        estimator: str = "joint",
        observation: str = "estimated",
        action: str = "yaw_moment",
        control_dt: float = 0.02,
        sensor_faults: tuple[Fault, ...] = (),
        render_mode: str | None = None,
        scenario_kwargs: dict | None = None,
        rear_steer: bool = True,
        privileged: bool = False,
        slip_control: bool = True,
        esc: bool = False,
        **unknown,
    ):
        _unknown_arguments(unknown)
        self.config = EnvConfig(
            scenario,
            speed_kph,
            mu,
            estimator,
            observation,
            action,
            control_dt,
            sensor_faults,
            scenario_kwargs=scenario_kwargs,
            rear_steer=rear_steer,
            privileged=privileged,
            slip_control=slip_control,
            esc=esc,
        )
        _check_render_mode(render_mode)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": self.config.render_fps}
        self.observation_space, self.action_space = _spaces(self.config)
        self._core: YawStabilityCore | None = None
        self._window = None
        self._ended = False

    @property
    def core(self) -> YawStabilityCore:
        if self._core is None:
            raise RuntimeError("call reset() before step() or render()")
        return self._core

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict or None, got {options!r}")
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; this env takes none")
        super().reset(seed=seed)
        if self._core is None:
            self._core = YawStabilityCore(self.config, [self.np_random])
            self._core.traced[:] = self.render_mode is not None
        else:
            self._core.reset_members(np.ones(1, dtype=bool), [self.np_random])
        self._ended = False
        obs = self._core.observe()[0]
        s = self._core.loop.sample()
        if self.render_mode == "human":
            self.render()
        return obs, {"truth": _first(s.truth), "estimate": _first(s.estimate)}

    def step(self, action):
        action = _check_actions(action, self.action_space.shape)
        if self._ended:
            gym.logger.warn(
                "step() after the episode ended (terminated or truncated); call reset() first: "
                "the car goes on, but the episode's statistics no longer mean one episode"
            )
        obs, reward, terminated, truncated, info = self.core.step(action[None, :])
        info = {k: (_first(v) if k in ("truth", "estimate") else v[0]) for k, v in info.items()}
        if info["episode_metrics"] is None:
            del info["episode_metrics"]
        self._ended = bool(terminated[0] or truncated[0])
        if self.render_mode == "human":
            self.render()
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), info

    def episode_metrics(self) -> dict:
        """The current episode's metrics so far (what ``info["episode_metrics"]`` holds when it
        ends): for an episode that a TimeLimit wrapper cut."""
        return self.core.episode_metrics(0)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        frame = self.core.render()
        if self.render_mode == "rgb_array":
            return frame
        self._window = show_frame(frame, self._window)
        return None

    def close(self):
        self._window = close_window(self._window)


def _shown(info: dict, keys: list[str], shown: np.ndarray) -> dict:
    """The per-step ``keys`` of ``info`` for the cars ``shown`` (B,) bool, zero for the others,
    each with its gymnasium ``_key`` mask."""
    out = {k: np.where(shown, info[k], np.zeros_like(info[k])) for k in keys}
    out.update({f"_{k}": shown.copy() for k in keys})
    return out


def _per_car(n: int, rows: np.ndarray, item) -> np.ndarray:
    """An object array of ``n`` entries: ``item(b)`` for the cars ``rows``, None for the others."""
    out = np.full(n, None, dtype=object)
    for b in rows:
        out[b] = item(b)
    return out


class YawStabilityVectorEnv(VectorEnv):
    """``num_envs`` cars in one batched core: the native vector env of ``FourWIS/YawStability-v0``.

    Step for step the env matches a ``SyncVectorEnv`` of single envs seeded ``seed + i`` with
    the same ``autoreset_mode`` (gymnasium's ``AutoresetMode`` or its value):

    - ``NEXT_STEP`` (default, gymnasium's, which its stateful vector wrappers such as
      ``NormalizeObservation`` need): a finished car returns its last observation and
      ``info["episode_metrics"]`` (an object array of per-car dicts, masked by
      ``_episode_metrics``); the next step resets it instead of moving it (its action is
      ignored; reward 0, no termination, per-step keys masked out).
    - ``SAME_STEP`` (SB3's convention; :class:`training.rl.SB3VecEnv` needs it): a finished
      car is reset at once. Its last
      observation is in ``info["final_obs"]`` (object array) and its last step's info in
      ``info["final_info"]`` (the per-step keys as (num_envs,) arrays, plus
      ``episode_metrics``, an object array); the top-level per-step keys then hold the new
      episode's (zero, masked out, as SyncVectorEnv's reset info has none).
    - ``DISABLED``: stepping a finished car is an error until ``reset`` with a
      ``reset_mask`` restarts it.

    ``info`` follows gymnasium's vector convention, each key with a ``_key`` mask. ``truth``
    and ``estimate`` are batched Estimates (one per step, not an object array of per-car
    ones), in ``final_info`` those of the last step. ``reset(options={"reset_mask": mask})``
    resets only the selected cars; ``max_episode_steps`` truncates here, with episode metrics.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": list(RENDER_MODES), "render_fps": 50}
    #: the human-mode window; a class default too, so that an env whose constructor raised, which
    #: gymnasium's VectorEnv.__del__ closes, closes quietly
    _window = None

    def __init__(
        self,
        num_envs: int = 1,
        scenario: str = "random",
        speed_kph: float | None = None,
        mu=None,
        estimator: str = "joint",
        observation: str = "estimated",
        action: str = "yaw_moment",
        control_dt: float = 0.02,
        sensor_faults: tuple[Fault, ...] = (),
        render_mode: str | None = None,
        max_episode_steps: int | None = None,
        scenario_kwargs: dict | None = None,
        rear_steer: bool = True,
        privileged: bool = False,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        slip_control: bool = True,
        esc: bool = False,
        **unknown,
    ):
        _unknown_arguments(unknown)
        if not (is_integer(num_envs) and num_envs >= 1):
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        try:
            self.autoreset_mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(
                f"unknown autoreset_mode {autoreset_mode!r}; known: {[m.value for m in AutoresetMode]}"
            ) from None
        self.config = EnvConfig(
            scenario,
            speed_kph,
            mu,
            estimator,
            observation,
            action,
            control_dt,
            sensor_faults,
            max_episode_steps,
            scenario_kwargs,
            rear_steer,
            privileged,
            slip_control,
            esc,
        )
        _check_render_mode(render_mode)
        self.num_envs, self.render_mode = int(num_envs), render_mode
        self.metadata = {**self.metadata, "render_fps": self.config.render_fps, "autoreset_mode": self.autoreset_mode}
        self.single_observation_space, self.single_action_space = _spaces(self.config)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs, self._car_seeds = map(list, zip(*(seeding.np_random() for _ in range(self.num_envs))))
        self._core: YawStabilityCore | None = None
        self._finished = np.zeros(self.num_envs, dtype=bool)  # ended, not yet reset (NEXT_STEP, DISABLED)

    def _seeds(self, seed) -> list:
        if seed is None or (is_integer(seed) and seed >= 0):
            return [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        try:
            seeds = list(seed)
        except TypeError:
            seeds = None
        if (
            seeds is None
            or len(seeds) != self.num_envs
            or not all(s is None or (is_integer(s) and s >= 0) for s in seeds)
        ):
            raise ValueError(f"seed must be None, an integer or {self.num_envs} integers >= 0 (or None), got {seed!r}")
        return [None if s is None else int(s) for s in seeds]  # numpy integers too (gymnasium wants int)

    @property
    def np_random_seed(self) -> tuple[int, ...]:
        """Each car's generator seed (what a SyncVectorEnv's ``np_random_seed`` gives)."""
        return tuple(self._car_seeds)

    def _reset_mask(self, options: dict | None) -> np.ndarray:
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict or None, got {options!r}")
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; known: ['reset_mask']")
        if mask is None:
            return np.ones(self.num_envs, dtype=bool)
        if not (
            isinstance(mask, np.ndarray) and mask.dtype == np.bool_ and mask.shape == (self.num_envs,) and mask.any()
        ):
            raise ValueError(
                f"options['reset_mask'] must be a bool array of shape ({self.num_envs},) with a True, got {mask!r}"
            )
        if self._core is None and not mask.all():
            raise ValueError("the first reset must reset every car (no reset_mask)")
        return mask

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        seeds, mask = self._seeds(seed), self._reset_mask(options)
        members = np.flatnonzero(mask)
        for i in members:
            if seeds[i] is not None:  # (unseeded, a car keeps the generator it has, as SyncVectorEnv's do)
                self._rngs[i], self._car_seeds[i] = seeding.np_random(seeds[i])
        if self._core is None:
            self._core = YawStabilityCore(self.config, self._rngs)
            self._core.traced[:] = self.render_mode == "rgb_array"  # (human mode shows car 0)
            self._core.traced[0] = self.render_mode is not None
        else:
            self._core.reset_members(mask, [self._rngs[i] for i in members])
        self._finished[members] = False
        s = self._core.loop.sample()
        if self.render_mode == "human":
            self.render()
        return self._core.observe(), {
            "truth": s.truth,
            "_truth": mask.copy(),
            "estimate": s.estimate,
            "_estimate": mask.copy(),
        }

    def close_extras(self, **kwargs) -> None:
        """Close the human-mode window (gymnasium's VectorEnv.close calls this once)."""
        self._window = close_window(self._window)

    def step(self, actions):
        if self._core is None:
            raise RuntimeError("call reset() before step()")
        actions = _check_actions(actions, self.action_space.shape)
        same_step = self.autoreset_mode == AutoresetMode.SAME_STEP
        obs, reward, terminated, truncated, info = (self._step_same_reset if same_step else self._step_later_reset)(
            actions
        )
        info.update(_truth=np.ones(self.num_envs, dtype=bool), _estimate=np.ones(self.num_envs, dtype=bool))
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, info

    def _step_same_reset(self, actions: np.ndarray):
        """:meth:`step` in ``SAME_STEP`` autoreset mode (see the class docstring)."""
        obs, reward, terminated, truncated, info = self._core.step(actions)
        metrics = info.pop("episode_metrics")
        done = terminated | truncated
        per_step = [k for k in info if k not in ("truth", "estimate")]
        if done.any():
            rows = np.flatnonzero(done)
            final_info = {
                "truth": info["truth"],
                "estimate": info["estimate"],
                "episode_metrics": _per_car(self.num_envs, rows, metrics.__getitem__),
                "_truth": done.copy(),
                "_estimate": done.copy(),
                "_episode_metrics": done.copy(),
                **_shown(info, per_step, done),
            }
            final_obs = _per_car(self.num_envs, rows, lambda b: obs[b].copy())
            self._core.reset_members(done, [self._rngs[b] for b in rows])
            obs = self._core.observe()
            s = self._core.loop.sample()
            info.update(
                truth=s.truth,
                estimate=s.estimate,
                final_obs=final_obs,
                _final_obs=done.copy(),
                final_info=final_info,
                _final_info=done.copy(),
            )
        info.update(_shown(info, per_step, ~done))
        return obs, reward, terminated, truncated, info

    def _step_later_reset(self, actions: np.ndarray):
        """:meth:`step` in ``NEXT_STEP`` and ``DISABLED`` autoreset modes (see the class docstring)."""
        restarting = self._finished.copy()
        if restarting.any():
            if self.autoreset_mode == AutoresetMode.DISABLED:
                raise RuntimeError(
                    f"cars {np.flatnonzero(restarting).tolist()} ended their episodes: with "
                    "autoreset_mode DISABLED, reset them first (reset(options={'reset_mask': mask}))"
                )
            self._core.reset_members(restarting, [self._rngs[b] for b in np.flatnonzero(restarting)])
        obs, reward, terminated, truncated, info = self._core.step(actions, ~restarting if restarting.any() else None)
        metrics = info.pop("episode_metrics")
        done = terminated | truncated
        info.update(_shown(info, [k for k in info if k not in ("truth", "estimate")], ~restarting))
        if done.any():
            info.update(
                episode_metrics=_per_car(self.num_envs, np.flatnonzero(done), metrics.__getitem__),
                _episode_metrics=done.copy(),
            )
        self._finished = done
        return obs, reward, terminated, truncated, info

    def render(self):
        """rgb_array: a sequence of every car's frame, each drawn when read; human: car 0 in a window."""
        if self.render_mode is None or self._core is None:
            return None
        if self.render_mode == "rgb_array":
            return _CarFrames(self._core)
        self._window = show_frame(self._core.render(), self._window)
        return None

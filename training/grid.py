"""The evaluation grid of issue 41: estimators on roads, speeds, manoeuvres, sensor seeds and
model errors they were not developed on, split into a development and a held-out half.

Axes (:data:`FRICTIONS`, :data:`SPEEDS_KPH`, :data:`MANOEUVRES`, sensor seeds, :data:`MODEL_ERRORS`)
alternate between the halves: friction 0.2, 0.4, ... 1.0 and speeds 30, 60, 90, 120 km/h are
development values, 0.3, 0.5, 0.7, 0.9 and 45, 75, 105 km/h held out; steady turns at 0.3, 0.5,
0.7, 0.9 of the grip develop, 0.4, 0.6, 0.8 are held out; of the other manoeuvres' variants the
first develops and the second is held out (and so on); even sensor seeds develop, odd ones are
held out; the estimator's model with mass +10 %, yaw inertia -15 % or cornering stiffness +20 %
develops, with -10 %, +15 % or -20 % it is held out (the nominal model belongs to both). A
split, patch or jump road belongs to the half of its lower friction (its pair alternates alike).
A cell is held out if any of its values is (:attr:`Cell.half`); a held-out cell runs an odd
seed, a development cell an even one.

The full factorial is too big; the grid (:func:`grid_cells`) is friction x manoeuvre in full on
uniform roads at 60 km/h, the split / patch / jump roads with the manoeuvres that drive
straight on (a 30 s turn circles back over a road's boundary), speeds and model errors each on
a subset (:data:`SUBSET_FRICTIONS` x :data:`SUBSET_MANOEUVRES`), and closed-loop cells
(DYC-LQR and DYC-SMC with the joint estimator and with the oracle) on :data:`CLOSED_LOOP_MANOEUVRES`
x :data:`SUBSET_FRICTIONS` x :data:`CLOSED_LOOP_SPEEDS_KPH`. ``quick`` keeps a few cells of each
kind (the tests' end-to-end run).

Each run's metrics are those of :func:`training.estimate.run_metrics` (whatever it reports;
new columns flow through to the runs CSV and the tables) and, for a closed-loop cell, of
:func:`training.compare.run_metrics`, plus the grid's own (:func:`grid_metrics`) over the
scored window after the transient (:attr:`Manoeuvre.scored_from`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from fourwis.core.constants import GRAVITY
from fourwis.envs.road import FrictionMap, patch, split, uniform
from fourwis.envs.scenarios import Scenario, make_scenario, neutral_steer_angle
from fourwis.envs.simulation import Trajectory, simulate
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation import check_estimator_name, make_estimator
from fourwis.estimation.model import AxleTyre
from fourwis.training import compare
from fourwis.training.compare import ORACLE_TOLERANCE, build_controller, naming_the_run, oracle_ratio
from fourwis.training.estimate import METRIC_UNITS, consistency, filter_consistency, run_metrics
from fourwis.training.io import atomic_write, atomic_write_text, check_writable, pyplot, staged_output
from fourwis.training.pool import Backend, as_backend, parallel_map
from fourwis.training.provenance import Provenance, provenance
from fourwis.training.tables import require_distinct, write_runs_csv

DEG = 180.0 / math.pi
HALVES = ("dev", "held-out")
HALF_CHOICES = (*HALVES, "both")

FRICTIONS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
DEV_FRICTIONS = (0.2, 0.4, 0.6, 0.8, 1.0)
SPEEDS_KPH = (30.0, 45.0, 60.0, 75.0, 90.0, 105.0, 120.0)
DEV_SPEEDS_KPH = (30.0, 60.0, 90.0, 120.0)
BASE_SPEED_KPH = 60.0  #: the speed of the friction x manoeuvre cells [km/h]
TURN_FRACTIONS = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
DEV_TURN_FRACTIONS = (0.3, 0.5, 0.7, 0.9)
#: the pair of a split, patch or jump road: (low, low + ROAD_PAIR_GAP), both of low's half
ROAD_PAIR_GAP = 0.4
PAIR_LOWS = tuple(m for m in FRICTIONS if m + ROAD_PAIR_GAP <= FRICTIONS[-1] + 1e-9)
PATCH_X = (40.0, 90.0)  #: where a patch road's low-friction patch lies, X from..to [m]; a jump's starts at 40 m
TURN_DURATION = 30.0  #: a steady turn is held this long [s] (the issue's paper_step held 30 s)
TURN_SCORED_FROM = 10.0  #: a steady turn's transient ends here [s] (the issue's "RMSE after 10 s")
MANOEUVRE_START = 1.0  #: steps, sines and turns start here [s]
SHORT_DURATION = 10.0  #: steps, sines and random runs last this long [s]
TRANSIENT = 1.0  #: the other manoeuvres' scored window starts here [s]: the filters' start-up
SINE_FRACTION = 0.6  #: a sine's amplitude: the steady steer for this fraction of the grip
SETTLE_BAND = 0.05  #: the issue's "settles within 0.05 of the truth" [-]
HALF_GRIP = 0.5  #: turns at or above this fraction of the grip must read the friction (issue 41, item 2)
AT_LIMIT = 0.95  #: a run whose peak |a_y| reaches this fraction of mu g is at the limit (no sideslip target)
BETA_TARGET = math.radians(0.2)  #: sideslip RMSE target after the transient, below the limit [rad]
Z_BAND = (0.5, 2.0)  #: the target band of RMS(error / sigma)
STEER_TOLERANCE = 0.01  #: the steady turn's lateral acceleration is calibrated within 1 % on the plant
STEER_ITERATIONS = 12
CALIBRATION_DURATION = 8.0  #: a calibration run [s]; its steady a_y is the mean over its last 2 s
CLOSED_LOOP_CONTROLLERS = ("dyc-lqr", "dyc-smc")
CLOSED_LOOP_ESTIMATORS = ("joint", "oracle")
HEADLINE_SEEDS = 2  #: sensor seeds of each headline run (as fourwis compare)
#: open loop (the oracle's errors are 0); joint-paper, the paper's estimator, shows the improvement
DEFAULT_ESTIMATORS = ("joint", "joint-paper", "alo-fkf", "ckf", "baseline-kf")
#: estimators run on the friction x manoeuvre cells of :data:`CLOSED_LOOP_FRICTIONS` only: the
#: linear baseline steps in Python (~190 us per 2 ms step against ~25 for the compiled filters),
#: and the whole grid with it would take twice as long (docs/decisions/0037-evaluation-grid.md)
FRICTION_ONLY = ("baseline-kf",)


@dataclass(frozen=True)
class Road:
    """A grid road: ``kind`` uniform (friction ``low``), split (``high`` under the left wheels,
    ``low`` under the right), patch (``high`` with ``low`` for X in :data:`PATCH_X`) or jump
    (``high`` onto ``low`` from X = PATCH_X[0] on)."""

    kind: str
    low: float
    high: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("uniform", "split", "patch", "jump"):
            raise ValueError(f"road kind must be uniform, split, patch or jump, got {self.kind!r}")
        if (self.high is None) != (self.kind == "uniform"):
            raise ValueError(f"a {self.kind} road needs {'no' if self.kind == 'uniform' else 'a'} high friction")

    @property
    def label(self) -> str:
        if self.kind == "uniform":
            return f"mu {self.low:g}"
        sep = {"split": "|", "patch": ">", "jump": ">"}[self.kind]
        return f"{self.kind} {self.high:g}{sep}{self.low:g}"

    @property
    def dev(self) -> bool:
        return _member(self.low, DEV_FRICTIONS)

    @property
    def start_mu(self) -> float:
        """The mean friction under the wheels at the start: a manoeuvre's grip refers to it."""
        return (
            self.low if self.kind == "uniform" else 0.5 * (self.low + self.high) if self.kind == "split" else self.high
        )

    def friction_map(self) -> FrictionMap:
        if self.kind == "uniform":
            return uniform(self.low)
        if self.kind == "split":
            return split(self.high, self.low)
        return patch(self.high, self.low, PATCH_X[0], PATCH_X[1] if self.kind == "patch" else math.inf)


@dataclass(frozen=True)
class Manoeuvre:
    """A grid manoeuvre: ``family`` turn (steady turn at ``variant`` of the grip, 30 s), step
    (steering step to the steady steer of ``variant`` of the grip), sine (``variant`` Hz at the
    steady steer of :data:`SINE_FRACTION`), lane (ISO 3888-``variant`` course, path follower)
    or random (``envs.scenarios.random`` seed ``variant`` on the grid's road and speed)."""

    family: str
    variant: float

    @property
    def label(self) -> str:
        unit = {"turn": "g", "step": "g", "sine": " Hz", "lane": "", "random": ""}[self.family]
        name = {"lane": "iso3888-", "random": "random "}.get(self.family, f"{self.family} ")
        return f"{name}{self.variant:g}{unit}"

    @property
    def dev(self) -> bool:
        if self.family == "turn":
            return _member(self.variant, DEV_TURN_FRACTIONS)
        variants = [m.variant for m in MANOEUVRES if m.family == self.family]
        return variants.index(self.variant) % 2 == 0

    @property
    def grip_fraction(self) -> float:
        """The designed fraction of the grip (NaN for lane changes and random runs, which set their own)."""
        return {"turn": self.variant, "step": self.variant, "sine": SINE_FRACTION}.get(self.family, math.nan)

    @property
    def scored_from(self) -> float:
        """Start of the scored window [s]: the transient before it is not scored."""
        return TURN_SCORED_FROM if self.family == "turn" else TRANSIENT


MANOEUVRES = (
    *(Manoeuvre("turn", f) for f in TURN_FRACTIONS),
    Manoeuvre("step", 0.6),
    Manoeuvre("step", 0.8),
    Manoeuvre("sine", 0.5),
    Manoeuvre("sine", 0.8),
    Manoeuvre("lane", 1),
    Manoeuvre("lane", 2),
    *(Manoeuvre("random", k) for k in range(4)),
)
STRAIGHT_MANOEUVRES = tuple(m for m in MANOEUVRES if m.family != "turn")
SUBSET_FRICTIONS = (0.5, 0.8)  #: the speed and model-error studies' roads (one of each half)
CLOSED_LOOP_FRICTIONS = (0.4, 0.5, 0.8, 0.9)  #: the closed-loop cells' roads (and the slow baseline's)
SUBSET_MANOEUVRES = (Manoeuvre("turn", 0.5), Manoeuvre("turn", 0.6), Manoeuvre("sine", 0.5), Manoeuvre("sine", 0.8))
CLOSED_LOOP_MANOEUVRES = STRAIGHT_MANOEUVRES[:6]  #: steps, sines and lane changes
CLOSED_LOOP_SPEEDS_KPH = (60.0, 75.0)


@dataclass(frozen=True)
class ModelError:
    """The estimator's model off the plant by these factors (mass, yaw inertia, lateral
    cornering stiffness); the plant is unchanged."""

    name: str
    mass: float = 1.0
    yaw_inertia: float = 1.0
    cornering: float = 1.0

    @property
    def dev(self) -> bool | None:
        """True / False for a development / held-out error, None for the nominal model (both halves)."""
        factors = (self.mass, self.yaw_inertia, self.cornering)
        if factors == (1.0, 1.0, 1.0):
            return None
        return factors in ((1.1, 1.0, 1.0), (1.0, 0.85, 1.0), (1.0, 1.0, 1.2))

    def estimator(self, name: str, params: VehicleParams):
        """The estimator ``name`` for the plant ``params`` with this model error (a name when nominal)."""
        if self.dev is None:
            return name
        model = params.replace(mass=params.mass * self.mass, yaw_inertia=params.yaw_inertia * self.yaw_inertia)
        # (the estimator's own tyre, its shape and relaxation length as make_estimator gives it the
        # shipped one, with the cornering stiffness off)
        shipped = AxleTyre.shipped(shape="magic" if name == "joint" else "dugoff")
        tyre = replace(
            shipped,
            m2=shipped.m2 * self.cornering,
            n2=shipped.n2 * self.cornering,
            relaxation_length=float(params.static_relaxation_lengths[1]),
        )
        return make_estimator(name, model, tyres=(tyre, tyre))


NOMINAL = ModelError("nominal")
MODEL_ERRORS = (
    ModelError("mass +10%", mass=1.1),
    ModelError("mass -10%", mass=0.9),
    ModelError("yaw inertia -15%", yaw_inertia=0.85),
    ModelError("yaw inertia +15%", yaw_inertia=1.15),
    ModelError("cornering +20%", cornering=1.2),
    ModelError("cornering -20%", cornering=0.8),
)


def _member(value: float, values: Sequence[float]) -> bool:
    return any(math.isclose(value, v, abs_tol=1e-9) for v in values)


@dataclass(frozen=True)
class Cell:
    """One run of the grid: a road, a manoeuvre, a speed [km/h], a sensor seed, the estimator's
    model error, an estimator and a controller (None: open loop). ``swa`` [rad]: the steady
    steering-wheel angle of the manoeuvre's grip fraction and ``steady_ay`` [m/s^2] the plant's
    steady lateral acceleration with it (:func:`steady_turn_steer`; NaN where the manoeuvre
    steers itself)."""

    road: Road
    manoeuvre: Manoeuvre
    speed_kph: float
    seed: int
    model_error: ModelError
    estimator: str
    controller: str | None = None
    swa: float = math.nan
    steady_ay: float = math.nan

    @property
    def conditions_dev(self) -> bool:
        """Road, manoeuvre, speed and model error all development values."""
        return (
            self.road.dev
            and self.manoeuvre.dev
            and _member(self.speed_kph, DEV_SPEEDS_KPH)
            and self.model_error.dev is not False
        )

    @property
    def half(self) -> str:
        return "dev" if self.conditions_dev and self.seed % 2 == 0 else "held-out"

    @property
    def scenario(self) -> str:
        """The cell's conditions in words (what an error message names)."""
        return f"{self.road.label}, {self.manoeuvre.label}, {self.speed_kph:g} km/h, {self.model_error.name} model"

    @property
    def study(self) -> str:
        """Which part of the grid the cell belongs to: friction x manoeuvre, speed, model error or closed loop."""
        if self.controller is not None:
            return "closed loop"
        if self.model_error is not NOMINAL and self.model_error.dev is not None:
            return "model error"
        return "speed" if self.speed_kph != BASE_SPEED_KPH else "friction x manoeuvre"

    def build(self, params: VehicleParams = VehicleParams()) -> Scenario:
        """The cell's Scenario on the plant ``params``."""
        m, road = self.manoeuvre, self.road.friction_map()
        common = dict(speed_kph=self.speed_kph, mu=road, params=params)
        if m.family in ("turn", "step"):
            duration = TURN_DURATION if m.family == "turn" else SHORT_DURATION
            return make_scenario("paper_step", angle=self.swa, step_time=MANOEUVRE_START, duration=duration, **common)
        if m.family == "sine":
            amplitude = math.degrees(self.swa)  # (paper_sine's sine starts at MANOEUVRE_START too)
            return make_scenario(
                "paper_sine", duration=SHORT_DURATION, amplitude_deg=amplitude, frequency=m.variant, **common
            )
        if m.family == "lane":
            return make_scenario("paper_dlc" if m.variant == 1 else "iso3888_2", **common)
        return make_scenario("random", seed=int(m.variant), duration=SHORT_DURATION, **common)


# -- the steady turn's steering ------------------------------------------------------------------


def steady_lateral_acceleration(swa: float, mu: float, speed_kph: float, params: VehicleParams) -> float:
    """The plant's steady lateral acceleration u r [m/s^2] with the steering wheel held at ``swa``
    [rad] from 1 s at ``speed_kph`` on a uniform road of ``mu``: the mean over the last 2 s of an
    8 s run (no estimator, no controller)."""
    scenario = make_scenario(
        "paper_step",
        speed_kph=speed_kph,
        mu=mu,
        angle=swa,
        step_time=MANOEUVRE_START,
        duration=CALIBRATION_DURATION,
        params=params,
    )
    truth = simulate(scenario, seed=0).truth
    last = slice(-int(2.0 / 0.002), None)
    return float(np.mean(truth.u[last] * truth.r[last]))


def steady_turn_steer(
    fraction: float, mu: float, speed_kph: float, params: VehicleParams = VehicleParams()
) -> tuple[float, float]:
    """(steering-wheel angle [rad], steady lateral acceleration [m/s^2]) at which the plant
    ``params`` turns steadily at ``fraction`` x ``mu`` g at ``speed_kph``: from the neutral-steer
    angle, rescaled by target / measured lateral acceleration (:func:`steady_lateral_acceleration`)
    until within :data:`STEER_TOLERANCE` (the lateral acceleration is concave in the steer, so the
    iteration climbs to it from below). Where the plant's steady limit lies below the target (0.9
    of mu 1.0 at 60 km/h: the limit is 0.88 g) or the steering lock comes first, the angle at which
    the lateral acceleration stops rising, and that acceleration."""
    if not (0.0 < fraction < 1.0):
        raise ValueError(f"fraction of the grip must lie in (0, 1), got {fraction!r}")
    target = fraction * mu * GRAVITY
    swa = neutral_steer_angle(target, speed_kph / 3.6, params) * params.steering_ratio
    lock = params.max_front_steer * params.steering_ratio
    best = (0.0, 0.0)
    for _ in range(STEER_ITERATIONS):
        ay = steady_lateral_acceleration(swa, mu, speed_kph, params)
        if abs(ay - target) <= STEER_TOLERANCE * target:
            return swa, ay
        if ay <= best[1] * (1.0 + 1e-3) or swa >= lock:  # past the plant's steady limit, or at the lock
            return max(best, (swa, ay), key=lambda b: b[1])
        best = (swa, ay)
        swa = min(swa * target / ay, lock)
    return best


def _calibrate(key: tuple[float, float, float]) -> tuple[tuple[float, float, float], tuple[float, float]]:
    return key, steady_turn_steer(*key)


# -- the grid ------------------------------------------------------------------------------------


def grid_cells(
    half: str = "both",
    estimators: Sequence[str] = DEFAULT_ESTIMATORS,
    quick: bool = False,
    closed_loop: bool = True,
    seeds: int = 1,
) -> list[Cell]:
    """The grid's cells (``swa`` not yet set) of ``half`` (dev, held-out or both), each open-loop
    condition with every estimator in ``estimators`` (the oracle skips the model errors: it has
    no model), ``seeds`` sensor seeds per condition (even ones for development conditions, odd
    ones for held-out), and, with ``closed_loop``, the closed-loop cells
    (:data:`CLOSED_LOOP_CONTROLLERS` x :data:`CLOSED_LOOP_ESTIMATORS`). ``quick``: a few cells
    of each study, without the slow baseline (:data:`FRICTION_ONLY`)."""
    if half not in HALF_CHOICES:
        raise ValueError(f"half must be one of {list(HALF_CHOICES)}, got {half!r}")
    if not estimators:
        raise ValueError("estimators must not be empty")
    for name in estimators:
        check_estimator_name(name)
    require_distinct("estimators", estimators)
    if not (isinstance(seeds, int) and not isinstance(seeds, bool) and seeds >= 1):
        raise ValueError(f"seeds must be an integer >= 1, got {seeds!r}")
    uniform_roads = [Road("uniform", m) for m in FRICTIONS]
    pair_roads = [
        Road(kind, low, round(low + ROAD_PAIR_GAP, 6)) for kind in ("split", "patch", "jump") for low in PAIR_LOWS
    ]
    subset_roads = [Road("uniform", m) for m in SUBSET_FRICTIONS]
    speeds = [s for s in SPEEDS_KPH if s != BASE_SPEED_KPH]
    manoeuvres, straight, subset, errors = MANOEUVRES, STRAIGHT_MANOEUVRES, SUBSET_MANOEUVRES, MODEL_ERRORS
    closed, closed_speeds = CLOSED_LOOP_MANOEUVRES, CLOSED_LOOP_SPEEDS_KPH
    closed_roads = [Road("uniform", m) for m in CLOSED_LOOP_FRICTIONS]
    if quick:
        closed_roads = [Road("uniform", 0.4), Road("uniform", 0.5)]  # (one cell of each half)
        uniform_roads, pair_roads = [Road("uniform", 0.4), Road("uniform", 0.5)], [Road("split", 0.2, 0.6)]
        subset_roads, speeds = subset_roads[1:], [90.0]
        manoeuvres, straight = (Manoeuvre("turn", 0.5), Manoeuvre("step", 0.8)), (Manoeuvre("sine", 0.5),)
        subset, errors, closed, closed_speeds = (
            subset[2:3],
            (MODEL_ERRORS[0], MODEL_ERRORS[1]),
            closed[:1],
            closed_speeds[:1],
        )
    conditions = (
        [(r, m, BASE_SPEED_KPH, NOMINAL) for r in uniform_roads for m in manoeuvres]
        + [(r, m, BASE_SPEED_KPH, NOMINAL) for r in pair_roads for m in straight]
        + [(r, m, s, NOMINAL) for s in speeds for r in subset_roads for m in subset]
        + [(r, m, BASE_SPEED_KPH, e) for e in errors for r in subset_roads for m in subset]
    )
    cells = []
    for road, m, speed, error in conditions:
        for estimator in estimators:
            if estimator == "oracle" and error is not NOMINAL:
                continue
            other_study = road.kind != "uniform" or speed != BASE_SPEED_KPH or error is not NOMINAL
            if estimator in FRICTION_ONLY and (quick or other_study or not _member(road.low, CLOSED_LOOP_FRICTIONS)):
                continue  # (the slow Python baseline: not in a quick run)
            cells += _seeded(Cell(road, m, speed, 0, error, estimator), seeds)
    if closed_loop:
        for road in closed_roads:
            for m in closed:
                for speed in closed_speeds:
                    for controller in CLOSED_LOOP_CONTROLLERS:
                        for estimator in CLOSED_LOOP_ESTIMATORS:
                            cells += _seeded(Cell(road, m, speed, 0, NOMINAL, estimator, controller), seeds)
    return [c for c in cells if half == "both" or c.half == half]


def _seeded(cell: Cell, seeds: int) -> list[Cell]:
    """``cell`` with its ``seeds`` sensor seeds: 0, 2, ... for development conditions, 1, 3, ... else."""
    first = 0 if cell.conditions_dev else 1
    return [replace(cell, seed=first + 2 * k) for k in range(seeds)]


def with_steering(cells: Sequence[Cell], jobs: int | None, progress: bool, backend: Backend) -> list[Cell]:
    """``cells`` with the steady steer of their manoeuvre's grip fraction on their start friction
    (:func:`steady_turn_steer` once per distinct fraction, friction and speed)."""
    keys = sorted(
        {
            (c.manoeuvre.grip_fraction, c.road.start_mu, c.speed_kph)
            for c in cells
            if math.isfinite(c.manoeuvre.grip_fraction)
        }
    )
    steer = dict(parallel_map(_calibrate, keys, jobs, "steady-steer calibration", progress, backend))
    return [
        replace(c, swa=steer[key][0], steady_ay=steer[key][1])
        if math.isfinite((key := (c.manoeuvre.grip_fraction, c.road.start_mu, c.speed_kph))[0])
        else c
        for c in cells
    ]


# -- per-run metrics -----------------------------------------------------------------------------

GRID_UNITS = {
    "rmse_beta_settled": "rad",
    "mu_abs_error_last_half": "-",
    "mu_settled": "0/1",
    "mu_drift_last_half": "-",
    "mu_read_low": "-",
    "beta_z_rms": "-",
    "mu_z_rms": "-",
    "grip_use": "-",
}


def grid_metrics(traj: Trajectory, manoeuvre: Manoeuvre) -> dict[str, float]:
    """The grid's metrics of one run, over the scored window from ``manoeuvre.scored_from``:
    rmse_beta_settled [rad]; over the last half of the run, with the friction error the mean
    over the wheels of |mu_hat - mu|: mu_abs_error_last_half (its mean), mu_settled (1 if it
    stays within :data:`SETTLE_BAND` throughout), mu_drift_last_half (the least-squares slope of
    the wheels' mean mu_hat times the half's length: how far it drifts over it), mu_read_low
    (mean of mu - mu_hat: > 0 reads a road more slippery than it is); beta_z_rms and mu_z_rms:
    RMS of error / sigma (beta_std, mu_std per wheel; :func:`fourwis.training.estimate.consistency`)
    in the scored window (NaN where the estimator reports no sigma); grip_use: peak |a_y| / (mu g)
    of the truth in the scored window (mu: the wheels' mean)."""
    T, E, t = traj.truth, traj.estimate, traj.t
    window = t >= manoeuvre.scored_from
    last = np.arange(t.size) >= t.size // 2
    error = E.beta[window] - T.beta[window]
    mu_error = np.mean(np.abs(E.mu - T.mu), axis=1)
    mu_hat = np.mean(E.mu[last], axis=1)
    slope = np.polyfit(t[last], mu_hat, 1)[0] if np.all(np.isfinite(mu_hat)) else math.nan
    beta_std, mu_std = E.beta_std[window], E.mu_std[window]
    return {
        "rmse_beta_settled": float(np.sqrt(np.mean(error**2))),
        "mu_abs_error_last_half": float(np.mean(mu_error[last])),
        "mu_settled": float(np.all(mu_error[last] < SETTLE_BAND)),
        "mu_drift_last_half": float(slope * (t[last][-1] - t[last][0])),
        "mu_read_low": float(np.mean(np.mean(T.mu[last], axis=1) - mu_hat)),
        "beta_z_rms": consistency(error, beta_std)[0],
        "mu_z_rms": consistency(E.mu[window] - T.mu[window], mu_std)[0],
        "grip_use": float(np.max(np.abs(T.ay[window]) / (np.mean(T.mu[window], axis=1) * GRAVITY))),
    }


@naming_the_run
def _run_cell(cell: Cell) -> tuple[Cell, dict[str, float]]:
    scenario = cell.build()
    params = scenario.vehicle_params
    estimator = cell.model_error.estimator(cell.estimator, params)
    controller = None if cell.controller is None else build_controller(cell.controller, params)
    traj = simulate(scenario, controller=controller, estimator=estimator, seed=cell.seed)
    # (NEES and NIS: a fresh estimator replays the run's sensors)
    metrics = run_metrics(traj) | filter_consistency(traj, cell.model_error.estimator(cell.estimator, params))
    if controller is not None:  # (the comparison's own; its estimator errors are run_metrics')
        metrics |= {k: v for k, v in compare.run_metrics(traj).items() if k not in metrics}
    return cell, metrics | grid_metrics(traj, cell.manoeuvre)


def run_grid(
    cells: Sequence[Cell], jobs: int | None = None, progress: bool = True, backend: Backend | str | None = None
) -> list[tuple[Cell, dict[str, float]]]:
    """Every cell (their steer calibrated first, :func:`with_steering`) on ``backend``; (cell, metrics) in order."""
    backend = as_backend(backend)
    cells = with_steering(cells, jobs, progress, backend)
    return list(parallel_map(_run_cell, cells, jobs, "grid runs", progress, backend))


# -- the target checks ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Check:
    """One target of issue 41 on one run: its name, whether it applies, the value and its bound."""

    target: str
    value: float
    bound: str
    passed: bool


def checks(cell: Cell, m: dict[str, float]) -> list[Check]:
    """The issue-41 targets that apply to a run: open loop, sideslip RMSE after the transient <=
    0.2 deg below the limit (grip_use < :data:`AT_LIMIT`); on uniform-road steady turns that use
    at least half the grip the friction settles within 0.05 and drifts less than 0.05 over the
    last half, below half the grip it does not read low (mu_read_low < 0.05); open loop and with
    the DYC in the loop, RMS(error / sigma) of sideslip and friction within :data:`Z_BAND`
    (where the estimator reports sigmas and, for friction, estimates it)."""
    out = []
    estimates_mu = bool(m.get("mu_estimated", 1.0))
    if cell.controller is None and m["grip_use"] < AT_LIMIT:
        beta = m["rmse_beta_settled"]
        out.append(Check("sideslip RMSE", beta * DEG, "<= 0.2 deg", beta <= BETA_TARGET))
    if cell.controller is None and estimates_mu and cell.manoeuvre.family == "turn" and cell.road.kind == "uniform":
        if cell.manoeuvre.variant >= HALF_GRIP - 1e-9:
            error = m["mu_abs_error_last_half"]
            out.append(Check("mu settles", error, f"< {SETTLE_BAND} throughout", bool(m["mu_settled"])))
            drift = m["mu_drift_last_half"]
            out.append(Check("mu no drift", drift, f"|drift| < {SETTLE_BAND}", abs(drift) < SETTLE_BAND))
        else:
            low = m["mu_read_low"]
            out.append(Check("mu holds", low, f"read low < {SETTLE_BAND}", low < SETTLE_BAND))
    loop = "" if cell.controller is None else ", DYC in the loop"
    for name, key in (("sideslip", "beta_z_rms"), ("friction", "mu_z_rms")):
        value = m[key]
        if math.isfinite(value) and (name == "sideslip" or estimates_mu):
            inside = Z_BAND[0] <= value <= Z_BAND[1]
            out.append(Check(f"{name} RMS(e/sigma){loop}", value, f"in [{Z_BAND[0]}, {Z_BAND[1]}]", inside))
    return out


def loop_ratios(results: Sequence[tuple[Cell, dict]]) -> list[tuple[Cell, str, float, float]]:
    """The closed-loop cells' (joint cell, controller, peak-sideslip ratio, yaw-rate-RMS ratio) of
    the joint estimator against the oracle with the same law, conditions and seed."""
    oracle = {
        (c.road, c.manoeuvre, c.speed_kph, c.seed, c.controller): m
        for c, m in results
        if c.controller is not None and c.estimator == "oracle"
    }
    out = []
    for c, m in results:
        key = (c.road, c.manoeuvre, c.speed_kph, c.seed, c.controller)
        if c.controller is not None and c.estimator != "oracle" and key in oracle:
            o = oracle[key]
            out.append(
                (
                    c,
                    c.controller,
                    oracle_ratio(m["peak_beta"], o["peak_beta"]),
                    oracle_ratio(m["yaw_tracking_rms"], o["yaw_tracking_rms"]),
                )
            )
    return out


def headline_ratios(
    seeds: int, jobs: int | None, progress: bool, backend: Backend, quick: bool
) -> list[tuple[str, str, float, float]]:
    """(scenario, controller, peak-sideslip ratio, yaw-rate-RMS ratio) of the joint estimator
    against the oracle on the comparison's headline scenarios (:func:`training.compare.run_matrix`,
    means over ``seeds``); ``quick``: the first headline scenario only."""
    scenarios = compare.HEADLINE[:1] if quick else compare.HEADLINE
    results, _ = compare.run_matrix(
        scenarios, CLOSED_LOOP_ESTIMATORS, CLOSED_LOOP_CONTROLLERS, seeds, jobs, progress, backend=backend
    )
    table = compare.aggregate(results)
    return [
        (
            s,
            c,
            oracle_ratio(table[(s, "joint", c)]["peak_beta"], table[(s, "oracle", c)]["peak_beta"]),
            oracle_ratio(table[(s, "joint", c)]["yaw_tracking_rms"], table[(s, "oracle", c)]["yaw_tracking_rms"]),
        )
        for s in scenarios
        for c in CLOSED_LOOP_CONTROLLERS
    ]


# -- the report ----------------------------------------------------------------------------------


def _units(names: Sequence[str]) -> dict[str, str]:
    """Each metric's unit (estimate's, compare's and the grid's; "?" for one none of them states)."""
    known = {**compare.METRIC_UNITS, **METRIC_UNITS, **GRID_UNITS}
    return {n: known.get(n, "?") for n in names}


def metric_names(results: Sequence[tuple[Cell, dict]]) -> list[str]:
    """Every metric any run reports, in first-seen order (new metrics of run_metrics flow through)."""
    return list(dict.fromkeys(k for _, m in results for k in m))


CELL_COLUMNS = [
    "half",
    "study",
    "road",
    "manoeuvre",
    "speed [km/h]",
    "model",
    "estimator",
    "controller",
    "seed",
    "swa [rad]",
    "steady_grip [-]",
]


def _cell_row(cell: Cell, _metrics: dict) -> list:
    return [
        cell.half,
        cell.study,
        cell.road.label,
        cell.manoeuvre.label,
        f"{cell.speed_kph:g}",
        cell.model_error.name,
        cell.estimator,
        cell.controller or "none",
        cell.seed,
        "" if not math.isfinite(cell.swa) else f"{cell.swa:.6g}",
        "" if not math.isfinite(cell.steady_ay) else f"{cell.steady_ay / (cell.road.start_mu * GRAVITY):.4g}",
    ]


def write_csv(results: Sequence[tuple[Cell, dict]], path: Path) -> Path:
    """runs.csv: a run per row, its cell (:data:`CELL_COLUMNS`) then every metric (``name [unit]``, SI)."""
    names = metric_names(results)
    return write_runs_csv(results, CELL_COLUMNS, _cell_row, names, _units(names), path)


def _fmt(value: float, digits: int = 3) -> str:
    return "—" if not math.isfinite(value) else f"{value:.{digits}g}"


def _ratio(value: float) -> str:
    return "—" if not math.isfinite(value) else f"{value:.2f}"


def _open_loop(results, half: str | None = None):
    return [(c, m) for c, m in results if c.controller is None and (half is None or c.half == half)]


def _heat_cells(results) -> tuple[list[Road], list[Manoeuvre]]:
    cells = [c for c, _ in _open_loop(results) if c.study == "friction x manoeuvre"]
    roads = sorted({c.road for c in cells}, key=lambda r: (["uniform", "split", "patch", "jump"].index(r.kind), r.low))
    manoeuvres = [m for m in MANOEUVRES if any(c.manoeuvre == m for c in cells)]
    return roads, manoeuvres


def plot_heat_maps(results, estimators: Sequence[str], metric: str, scale: float, title: str, path: Path) -> Path:
    """PNG: ``metric`` (times ``scale``) over road x manoeuvre at the base speed, nominal model,
    mean over seeds: a panel per estimator (rows) and half (columns); blank where the cell is
    in the other half."""
    plt = pyplot()
    roads, manoeuvres = _heat_cells(results)
    halves = [h for h in HALVES if any(c.half == h for c, _ in results)]
    fig, axes = plt.subplots(
        len(estimators),
        len(halves),
        figsize=(5.5 * len(halves), 0.28 * len(roads) * len(estimators) + 1.5),
        squeeze=False,
    )
    values = {}
    for c, m in _open_loop(results):
        if c.study == "friction x manoeuvre":
            values.setdefault((c.half, c.estimator, c.road, c.manoeuvre), []).append(m[metric] * scale)
    finite = [v for vs in values.values() for v in vs if math.isfinite(v)]
    vmax = float(np.percentile(finite, 95)) if finite else 1.0
    for i, e in enumerate(estimators):
        for j, h in enumerate(halves):
            ax = axes[i, j]
            grid = np.full((len(roads), len(manoeuvres)), np.nan)
            for a, r in enumerate(roads):
                for b, mn in enumerate(manoeuvres):
                    if (h, e, r, mn) in values:
                        grid[a, b] = float(np.mean(values[(h, e, r, mn)]))
            image = ax.imshow(grid, aspect="auto", cmap="viridis", vmin=0.0, vmax=vmax)
            for a in range(len(roads)):
                for b in range(len(manoeuvres)):
                    if math.isfinite(grid[a, b]):
                        ax.text(b, a, f"{grid[a, b]:.2f}", ha="center", va="center", fontsize=4.5, color="w")
            ax.set_xticks(range(len(manoeuvres)), [mn.label for mn in manoeuvres], rotation=90, fontsize=6)
            ax.set_yticks(range(len(roads)), [r.label for r in roads], fontsize=6)
            ax.set_title(f"{e}, {h}", fontsize=8)
            fig.colorbar(image, ax=ax, fraction=0.04)
    fig.suptitle(f"{title} at {BASE_SPEED_KPH:g} km/h, nominal model (blank: the other half)")
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.4 / fig.get_figheight()))  # (room for the title)
    atomic_write(path, lambda p: fig.savefig(p, format="png", dpi=110))
    plt.close(fig)
    return path


#: the metrics of the per-half tables' first rows (the others follow in the order the runs report them)
LEAD_METRICS = (
    ("rmse_beta_settled", DEG, "deg"),
    ("mu_abs_error_last_half", 1.0, "-"),
    ("mu_settled", 1.0, "share"),
    ("mu_drift_last_half", 1.0, "-"),
    ("beta_z_rms", 1.0, "-"),
    ("mu_z_rms", 1.0, "-"),
)


def _table_lines(results, half: str, estimators: Sequence[str]) -> list[str]:
    """Per estimator: mean / worst (largest |value|) of every metric over the half's open-loop runs."""
    runs = _open_loop(results, half)
    present = [e for e in estimators if any(c.estimator == e for c, _ in runs)]
    if not runs:
        return [f"No open-loop runs in the {half} half.", ""]
    names = [n for n, _, _ in LEAD_METRICS] + [
        n for n in metric_names(runs) if n not in {x for x, _, _ in LEAD_METRICS}
    ]
    scale = {n: (s, u) for n, s, u in LEAD_METRICS}
    units = _units(names)
    lines = [
        f"Open-loop runs of the {half} half: mean / worst (largest magnitude) over its cells.",
        "",
        "| metric | " + " | ".join(f"{e} ({sum(c.estimator == e for c, _ in runs)} runs)" for e in present) + " |",
        "|---|" + "---:|" * len(present),
    ]
    for n in names:
        k, unit = scale.get(n, (1.0, units[n]))
        row = []
        for e in present:
            vals = np.array([m.get(n, math.nan) * k for c, m in runs if c.estimator == e], dtype=float)
            vals = vals[np.isfinite(vals)]
            worst = float(vals[np.argmax(np.abs(vals))]) if vals.size else math.nan
            row.append("—" if not vals.size else f"{_fmt(float(np.mean(vals)))} / {_fmt(worst)}")
        lines.append(f"| {n} [{unit}] | " + " | ".join(row) + " |")
    return lines + [""]


MISSES_LISTED = 8  #: the worst misses listed per target, estimator and half (all of them: checks.csv)


def _margin(check: Check) -> float:
    """How far a missed check is from its bound (for ordering the misses; larger: worse)."""
    if "RMS(e/sigma)" in check.target:
        return max(Z_BAND[0] / check.value if check.value > 0 else math.inf, check.value / Z_BAND[1])
    if check.target == "sideslip RMSE":
        return check.value / (BETA_TARGET * DEG)
    return abs(check.value)


def all_checks(results) -> list[tuple[Cell, Check]]:
    return [(c, k) for c, m in results for k in checks(c, m)]


def write_checks_csv(results, path: Path) -> Path:
    """checks.csv: every target check of every run (cell, target, value, bound, passed)."""
    import csv
    import io

    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow([*CELL_COLUMNS, "target", "value", "bound", "passed"])
    for cell, k in all_checks(results):
        writer.writerow([*_cell_row(cell, {}), k.target, f"{k.value:.6g}", k.bound, int(k.passed)])
    return atomic_write_text(path, buffer.getvalue())


def _target_lines(results, half: str, estimators: Sequence[str]) -> list[str]:
    found = [(c, k) for c, k in all_checks(results) if c.half == half]
    if not found:
        return []
    targets = list(dict.fromkeys(k.target for _, k in found))
    present = [e for e in estimators if any(c.estimator == e for c, _ in found)]
    lines = [
        f"Passed / applicable runs of the {half} half per target (the targets of issue 41; "
        "\\* marks every run passing):",
        "",
        "| target | bound | " + " | ".join(present) + " |",
        "|---|---|" + "---:|" * len(present),
    ]
    for t in targets:
        bound = next(k.bound for _, k in found if k.target == t)
        row = []
        for e in present:
            ks = [k for c, k in found if k.target == t and c.estimator == e]
            passed = sum(k.passed for k in ks)
            row.append("—" if not ks else f"{passed}/{len(ks)}" + (" \\*" if passed == len(ks) else ""))
        lines.append(f"| {t} | {bound} | " + " | ".join(row) + " |")
    lines += ["", f"The worst misses ({MISSES_LISTED} at most per target and estimator; all in checks.csv):", ""]
    lines += ["| target | estimator | cell | value | bound |", "|---|---|---|---:|---|"]
    for t in targets:
        for e in present:
            misses = sorted(
                ((c, k) for c, k in found if k.target == t and c.estimator == e and not k.passed),
                key=lambda ck: -_margin(ck[1]),
            )
            for c, k in misses[:MISSES_LISTED]:
                lines.append(f"| {t} | {e} | {c.scenario}, seed {c.seed} | {k.value:.3g} | {k.bound} |")
    return lines + [""]


def _loop_lines(results) -> list[str]:
    ratios = loop_ratios(results)
    if not ratios:
        return []
    lines = [
        "## Closed loop: joint against the oracle",
        "",
        f"Each closed-loop cell's joint-estimator run as a ratio to the oracle's with the same law, "
        f"conditions and seed: peak sideslip / yaw-rate RMS error; within target at <= {ORACLE_TOLERANCE:.2f} "
        "(— where the oracle's value is at the noise floor).",
        "",
        "| half | controller | cells within 10% on both | worst peak-sideslip ratio | worst yaw-RMS ratio |",
        "|---|---|---:|---:|---:|",
    ]
    for h in HALVES:
        for ctl in CLOSED_LOOP_CONTROLLERS:
            rs = [r for r in ratios if r[0].half == h and r[1] == ctl]
            if not rs:
                continue
            ok = sum(all(not math.isfinite(x) or x <= ORACLE_TOLERANCE for x in r[2:]) for r in rs)
            worst = [max((x for r in rs for x in [r[i]] if math.isfinite(x)), default=math.nan) for i in (2, 3)]
            lines.append(f"| {h} | {ctl} | {ok}/{len(rs)} | {_ratio(worst[0])} | {_ratio(worst[1])} |")
    lines += [
        "",
        "Cells outside 10%:",
        "",
        "| half | controller | cell | peak sideslip | yaw-rate RMS |",
        "|---|---|---|---:|---:|",
    ]
    for c, ctl, pb, yr in ratios:
        if any(math.isfinite(x) and x > ORACLE_TOLERANCE for x in (pb, yr)):
            lines.append(f"| {c.half} | {ctl} | {c.scenario}, seed {c.seed} | {_ratio(pb)} | {_ratio(yr)} |")
    return lines + [""]


def _headline_lines(headline) -> list[str]:
    if not headline:
        return []
    lines = [
        "## Closed loop on the headline scenarios",
        "",
        "`fourwis compare`'s headline scenarios (neither half), joint against the oracle with the same "
        "law, means over seeds: peak sideslip / yaw-rate RMS error; bold above "
        f"{ORACLE_TOLERANCE:.2f}.",
        "",
        "| scenario | " + " | ".join(CLOSED_LOOP_CONTROLLERS) + " |",
        "|---|" + "---:|" * len(CLOSED_LOOP_CONTROLLERS),
    ]
    cells = {(s, c): (pb, yr) for s, c, pb, yr in headline}

    def bold(x: float) -> str:
        return f"**{_ratio(x)}**" if math.isfinite(x) and x > ORACLE_TOLERANCE else _ratio(x)

    for s in dict.fromkeys(s for s, *_ in headline):
        lines.append(
            f"| {s} | "
            + " | ".join(f"{bold(cells[(s, c)][0])} / {bold(cells[(s, c)][1])}" for c in CLOSED_LOOP_CONTROLLERS)
            + " |"
        )
    return lines + [""]


def markdown_report(results, estimators: Sequence[str], half: str, headline, header: Provenance | None = None) -> str:
    """grid.md: who wrote it, what the grid holds, the heat maps, a table and the target checks
    per half side by side, the closed-loop ratios."""
    counts = {h: sum(c.half == h for c, _ in results) for h in HALVES}
    lines = [
        "# fourwis evaluation grid (issue 41)",
        "",
        *(header or provenance()).markdown(),
        "",
        f"Runs: {len(results)} ({counts['dev']} development, {counts['held-out']} held-out; --half {half}). "
        "Frictions alternate between the halves (dev 0.2, 0.4, ..., 1.0; held-out 0.3, ..., 0.9; a split, "
        "patch or jump road by its lower friction), speeds likewise (dev 30, 60, 90, 120 km/h; held-out "
        "45, 75, 105), steady turns (dev 0.3, 0.5, 0.7, 0.9 of the grip; held-out 0.4, 0.6, 0.8), the other "
        "manoeuvres' variants (first dev, second held-out, ...), sensor seeds (even dev, odd held-out) "
        "and the estimator's model error (dev mass +10 %, yaw inertia -15 %, cornering stiffness +20 %; "
        "held-out the opposite signs; the nominal model in both); a cell is held-out if any of its values is. "
        f"Steady turns last {TURN_DURATION:g} s and are scored from {TURN_SCORED_FROM:g} s, the other "
        f"manoeuvres from {TRANSIENT:g} s; friction metrics over the last half of each run. Their steer is "
        "calibrated on the plant to the target lateral acceleration (fraction x mu g, within "
        f"{STEER_TOLERANCE:.0%}). The linear baseline (Python, slow) runs on the uniform friction x "
        "manoeuvre cells only. Every run: runs.csv; every target check: checks.csv.",
        "",
        "## Friction x manoeuvre",
        "",
        "![sideslip RMSE after the transient](heat_sideslip.png)",
        "",
        "![friction error over the last half](heat_friction.png)",
        "",
    ]
    for h in HALVES:
        lines += [f"## The {h} half", "", *_table_lines(results, h, estimators), *_target_lines(results, h, estimators)]
    lines += _loop_lines(results)
    lines += _headline_lines(headline)
    return "\n".join(lines)


def grid_report(
    out: str | Path,
    half: str = "both",
    estimators: Sequence[str] = DEFAULT_ESTIMATORS,
    quick: bool = False,
    seeds: int = 1,
    jobs: int | None = None,
    command: str | None = None,
    backend: Backend | str | None = None,
    progress: bool = True,
) -> Path:
    """Run the grid (:func:`grid_cells`, :func:`run_grid`) and the headline closed loop
    (:func:`headline_ratios`); write grid.md, runs.csv, checks.csv, heat_sideslip.png and
    heat_friction.png into ``out`` as one set (:func:`training.io.staged_output`). Returns the
    path of grid.md."""
    out = check_writable(out)
    pyplot()  # (the heat maps need matplotlib: say so before the runs)
    backend = as_backend(backend)
    cells = grid_cells(half, estimators, quick, seeds=seeds)
    results = run_grid(cells, jobs, progress, backend)
    headline = headline_ratios(1 if quick else HEADLINE_SEEDS, jobs, progress, backend, quick)
    header = provenance(command)
    with staged_output(out) as stage:
        write_csv(results, stage / "runs.csv")
        write_checks_csv(results, stage / "checks.csv")
        plot_heat_maps(
            results,
            estimators,
            "rmse_beta_settled",
            DEG,
            "Sideslip RMSE after the transient [deg]",
            stage / "heat_sideslip.png",
        )
        plot_heat_maps(
            results,
            estimators,
            "mu_abs_error_last_half",
            1.0,
            "Friction error |mu_hat - mu|, last half [-]",
            stage / "heat_friction.png",
        )
        atomic_write_text(stage / "grid.md", markdown_report(results, estimators, half, headline, header))
    return out / "grid.md"

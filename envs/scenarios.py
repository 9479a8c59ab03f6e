"""Named manoeuvres: the paper's five conditions, the regulation tests, RL training scenarios.

``SCENARIOS`` maps each name to its default :class:`Scenario`; ``make_scenario(name, **overrides)``
builds one with overrides (``speed_kph``, ``mu``, ``duration``, ``steering``,
``rear_steer_feedforward`` for all; scenario-specific ones listed in each builder's docstring).

Readings of the paper (section 3.3.3, 4.3), where it leaves details open:

* ``paper_dlc``: the double lane change is driven on the ISO 3888-1 course by a
  path-following driver (the paper's CarSim driver model).
* ``paper_step``: "a turning angle with an amplitude of 1 radian is introduced to the
  steering wheel at the 5-s interval": a 1 rad steering-wheel step at t = 5 s, rising in 0.1 s.
* ``paper_sine``: the paper gives neither amplitude nor frequency; we use 90 deg of
  steering wheel at 0.5 Hz, which reaches ~0.5 g on mu 0.8 (enough to make mu observable).
* ``paper_split_dlc``: "double-shift road surface opposite each other" with mu 0.5 and 0.3 is
  read as the double lane change on a left/right split road: the car starts with its left
  wheels on 0.5 and its right wheels on 0.3, and the lane change to the left carries all four
  wheels onto the 0.5 side and back, so per-wheel friction changes during the manoeuvre.
* ``paper_serpentine``: a slalom through cones 18 m apart (common slalom spacing), driven by
  the path follower on a sinusoidal line of 1 m amplitude.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from fourwis.core.checks import is_integer, is_number
from fourwis.core.constants import GRAVITY
from fourwis.envs import courses
from fourwis.envs.driver import Constant, PathFollower, Ramp, Sine, SineWithDwell, SpeedHold, Step, SumOfSines
from fourwis.envs.road import FrictionMap, PatchMap, as_friction_map, check_mu, patch, split, uniform
from fourwis.envs.vehicle import VehicleParams, initial_state

Steering = Callable[[float, np.ndarray], float]


MAX_SPEED_KPH = 300.0  #: fastest scenario speed [km/h] (far beyond the motors' top speed)
MAX_DURATION = 600.0  #: longest scenario [s] (a simulation keeps every 2 ms sample: 300,000 of them)


@dataclass(frozen=True)
class Scenario:
    """A manoeuvre: initial speed, road, driver inputs, duration.

    ``steering(t, plant_state) -> steering-wheel angle [rad]``; longitudinally the driver holds
    ``speed_kph`` until ``coast_after`` [s], then coasts, and from ``brake_after`` [s] brakes with
    ``brake_torque`` [N m] per wheel. ``course`` (cones) and
    ``reference_path`` (N, 2) are set where the manoeuvre follows a path.
    """

    name: str
    speed_kph: float
    road: FrictionMap
    duration: float
    steering: Steering
    coast_after: float = math.inf
    brake_after: float = math.inf
    brake_torque: float = 0.0
    rear_steer_feedforward: bool = False
    start_x: float = 0.0
    course: courses.Course | None = None
    reference_path: np.ndarray | None = None
    params: VehicleParams = field(default_factory=VehicleParams)

    def __post_init__(self) -> None:
        if not callable(self.steering):
            raise ValueError(
                f"steering must be a callable steering(t, plant_state) -> angle [rad], got {self.steering!r}"
            )
        if not isinstance(self.rear_steer_feedforward, (bool, np.bool_)):
            raise ValueError(f"rear_steer_feedforward must be True or False, got {self.rear_steer_feedforward!r}")
        if not isinstance(self.params, VehicleParams):
            raise ValueError(f"params must be a VehicleParams, got {self.params!r}")
        if not (is_number(self.speed_kph) and 0.0 < self.speed_kph <= MAX_SPEED_KPH):
            raise ValueError(f"speed_kph must lie in (0, {MAX_SPEED_KPH:g}], got {self.speed_kph!r}")
        if not (is_number(self.duration) and 0.0 < self.duration <= MAX_DURATION):
            raise ValueError(
                f"scenario {self.name!r}: duration must lie in (0, {MAX_DURATION:g}] s, got "
                f"{self.duration!r} (a builder's own duration grows as the speed, "
                f"{self.speed_kph!r} km/h, falls: give a shorter one)"
            )

    @property
    def speed(self) -> float:
        """Initial and target speed [m/s]."""
        return self.speed_kph / 3.6

    @property
    def vehicle_params(self) -> VehicleParams:
        """The plant parameters with this scenario's 4WS feed-forward switch (on if the
        scenario's or the given parameters' switch is)."""
        return self.params.replace(
            rear_steer_feedforward=self.rear_steer_feedforward or self.params.rear_steer_feedforward
        )

    def initial_state(self, batch_size: int = 1) -> np.ndarray:
        """Plant state (batch_size, NX) at the start: straight at ``speed`` from ``start_x``."""
        return initial_state(self.vehicle_params, self.speed, batch_size, x=self.start_x)

    def speed_driver(self) -> SpeedHold:
        return SpeedHold(
            self.speed,
            self.vehicle_params,
            coast_after=self.coast_after,
            brake_after=self.brake_after,
            brake_torque=self.brake_torque,
        )


def _positive(name: str, value) -> float:
    if not (is_number(value) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def _finite(name: str, value, minimum: float = -math.inf) -> float:
    if not (is_number(value) and math.isfinite(value) and value >= minimum):
        raise ValueError(
            f"{name} must be a finite number" + (f" >= {minimum:g}" if minimum > -math.inf else "") + f", got {value!r}"
        )
    return float(value)


def _interval(name: str, value) -> tuple[float, float]:
    """(low, high) of two finite numbers 0 < low <= high, or ValueError naming ``name``."""
    try:
        low, high = value
    except (TypeError, ValueError):
        low = high = None
    if not all(is_number(v) and math.isfinite(v) and v > 0 for v in (low, high)) or low > high:
        raise ValueError(f"{name} must be two finite numbers 0 < low <= high, got {value!r}")
    return float(low), float(high)


def _direction(direction) -> int:
    if not (is_number(direction) and direction in (1, -1)):
        raise ValueError(f"direction must be +1 (left) or -1 (right), got {direction!r}")
    return int(direction)


def _road(mu) -> FrictionMap:
    """The road of a scenario's ``mu``: a friction coefficient, a (left, right) pair for a split
    road (a list too, as JSON gives it), a FrictionMap or a callable mu(x, y)."""
    if isinstance(mu, np.ndarray) and mu.shape == (2,):
        mu = tuple(mu.tolist())
    if isinstance(mu, (tuple, list)) and len(mu) == 2 and all(is_number(m) for m in mu):
        return split(mu_left=mu[0], mu_right=mu[1], y_split=0.0)
    try:
        return as_friction_map(mu)
    except ValueError as err:
        raise ValueError(
            f"bad mu {mu!r}: {err}; or a (left, right) pair of friction coefficients for a split road"
        ) from None


def neutral_steer_angle(lateral_acceleration: float, speed: float, params: VehicleParams) -> float:
    """Front road-wheel angle [rad] for a steady ``lateral_acceleration`` [m/s^2] at ``speed``
    [m/s] of the neutral-steer (kinematic) single-track model: ay L / u^2 (this car is neutral)."""
    return lateral_acceleration * params.wheelbase / speed**2


def _body(params: VehicleParams) -> tuple[float, float, float]:
    """Width and body extents ahead of / behind the CG [m], for the courses' driver line."""
    return params.width, params.front_extent, params.rear_extent


def _path_scenario(name, course, speed_kph, mu, duration, lead_in, steering, params, **kw) -> Scenario:
    path = course.centreline
    if duration is None:
        duration = (path[-1, 0] - path[0, 0] + lead_in + 20.0) / (speed_kph / 3.6)
    start = path[0, 0] - lead_in
    full_path = np.vstack([[start, path[0, 1]], path])
    driver = steering if steering is not None else PathFollower(full_path, params)
    return Scenario(
        name,
        speed_kph,
        _road(mu),
        _positive("duration", duration),
        driver,
        start_x=start,
        course=course,
        reference_path=full_path,
        params=params,
        **kw,
    )


def paper_dlc(
    speed_kph=35.0, mu=0.5, duration=None, steering=None, rear_steer_feedforward=False, params=VehicleParams()
) -> Scenario:
    """Paper 3.3.3 (1): double lane change (ISO 3888-1 course), mu 0.5, 35 km/h."""
    _positive("speed_kph", speed_kph)
    return _path_scenario(
        "paper_dlc",
        courses.iso3888_1(*_body(params)),
        speed_kph,
        mu,
        duration,
        20.0,
        steering,
        params,
        rear_steer_feedforward=rear_steer_feedforward,
    )


def paper_split_dlc(
    speed_kph=25.0, mu=(0.5, 0.3), duration=None, steering=None, rear_steer_feedforward=False, params=VehicleParams()
) -> Scenario:
    """Paper 4.3.1: double lane change on a left/right split road, ``mu = (left, right)`` = (0.5, 0.3), 25 km/h."""
    _positive("speed_kph", speed_kph)
    return _path_scenario(
        "paper_split_dlc",
        courses.iso3888_1(*_body(params)),
        speed_kph,
        mu,
        duration,
        20.0,
        steering,
        params,
        rear_steer_feedforward=rear_steer_feedforward,
    )


def _starts_in_time(name: str, parameter: str, start, duration) -> float:
    """A manoeuvre's start time [s] given as ``parameter``, checked to come before ``duration`` [s]
    (a later one would leave the run without its manoeuvre)."""
    start, duration = _finite(parameter, start, 0.0), _positive("duration", duration)
    if start >= duration:
        raise ValueError(
            f"{name}: {parameter} = {start!r} s is not before the end of the run (duration = "
            f"{duration!r} s): the run would end before its manoeuvre starts; lower {parameter} or "
            "raise duration"
        )
    return start


def paper_step(
    speed_kph=40.0,
    mu=0.3,
    duration=10.0,
    steering=None,
    step_time=None,
    angle=1.0,
    rear_steer_feedforward=False,
    params=VehicleParams(),
) -> Scenario:
    """Paper 3.3.3 (2): steering-wheel step of ``angle`` [rad] (1 rad) at ``step_time`` [s] (5 s;
    given, it must come before ``duration``), mu 0.3, 40 km/h."""
    if steering is None:
        step_time = 5.0 if step_time is None else _starts_in_time("paper_step", "step_time", step_time, duration)
        steering = Step(_finite("angle", angle), step_time)
    return Scenario(
        "paper_step",
        _positive("speed_kph", speed_kph),
        _road(mu),
        _positive("duration", duration),
        steering,
        rear_steer_feedforward=rear_steer_feedforward,
        params=params,
    )


def paper_sine(
    speed_kph=40.0,
    mu=0.8,
    duration=10.0,
    steering=None,
    amplitude_deg=90.0,
    frequency=0.5,
    rear_steer_feedforward=False,
    params=VehicleParams(),
) -> Scenario:
    """Paper 3.3.3 (3): sinusoidal steering-wheel input (``amplitude_deg`` at ``frequency`` Hz), mu 0.8, 40 km/h."""
    steering = (
        steering
        if steering is not None
        else Sine(math.radians(_positive("amplitude_deg", amplitude_deg)), _positive("frequency", frequency), start=1.0)
    )
    return Scenario(
        "paper_sine",
        _positive("speed_kph", speed_kph),
        _road(mu),
        _positive("duration", duration),
        steering,
        rear_steer_feedforward=rear_steer_feedforward,
        params=params,
    )


def paper_serpentine(
    speed_kph=40.0,
    mu=0.5,
    duration=None,
    steering=None,
    spacing=18.0,
    amplitude=1.0,
    n_cones=8,
    rear_steer_feedforward=False,
    params=VehicleParams(),
) -> Scenario:
    """Paper 4.3.2: slalom through ``n_cones`` cones ``spacing`` [m] apart, path amplitude ``amplitude`` [m]."""
    course = courses.slalom(_positive("spacing", spacing), _positive("amplitude", amplitude), n_cones)
    return _path_scenario(
        "paper_serpentine",
        course,
        _positive("speed_kph", speed_kph),
        mu,
        duration,
        20.0,
        steering,
        params,
        rear_steer_feedforward=rear_steer_feedforward,
    )


def sine_with_dwell(
    speed_kph=80.0,
    mu=1.0,
    duration=5.0,
    steering=None,
    amplitude_deg=180.0,
    direction=1,
    start=None,
    rear_steer_feedforward=False,
    params=VehicleParams(),
) -> Scenario:
    """FMVSS 126 sine with dwell at ``amplitude_deg`` of steering wheel, first towards ``direction``
    (+1 left, -1 right); speed held until the steering starts at ``start`` [s] (1 s; given, it
    must come before ``duration``), then coasting. The amplitude series (1.5A ... max(6.5A,
    270 deg), capped at 300 deg) and A come from :mod:`envs.fmvss126`."""
    amplitude = math.radians(_positive("amplitude_deg", amplitude_deg)) * _direction(direction)
    if start is None:
        start = 1.0
    elif steering is None:
        start = _starts_in_time("sine_with_dwell", "start", start, duration)
    else:  # (another steering: start only ends the speed holding)
        start = _finite("start", start, 0.0)
    steering = steering if steering is not None else SineWithDwell(amplitude, start)
    return Scenario(
        "sine_with_dwell",
        _positive("speed_kph", speed_kph),
        _road(mu),
        _positive("duration", duration),
        steering,
        coast_after=start,
        rear_steer_feedforward=rear_steer_feedforward,
        params=params,
    )


def slowly_increasing_steer(
    speed_kph=80.0,
    mu=1.0,
    duration=None,
    steering=None,
    rate_deg=13.5,
    direction=1,
    rear_steer_feedforward=False,
    params=VehicleParams(),
) -> Scenario:
    """FMVSS 126 characterisation: steering-wheel ramp at ``rate_deg`` deg/s at constant speed.

    Runs until the ramp would reach 0.55 g in the linear bicycle model (past the 0.5 g the
    procedure asks for) unless ``duration`` is given."""
    rate = math.radians(_positive("rate_deg", rate_deg)) * _direction(direction)
    speed = _positive("speed_kph", speed_kph) / 3.6
    if duration is None:
        swa_end = neutral_steer_angle(0.55 * GRAVITY, speed, params) * params.steering_ratio
        duration = 1.0 + 1.5 * swa_end / abs(rate)
    steering = steering if steering is not None else Ramp(rate, start=1.0)
    return Scenario(
        "slowly_increasing_steer",
        speed_kph,
        _road(mu),
        _positive("duration", duration),
        steering,
        rear_steer_feedforward=rear_steer_feedforward,
        params=params,
    )


def iso3888_2(
    speed_kph=60.0, mu=1.0, duration=None, steering=None, rear_steer_feedforward=False, params=VehicleParams()
) -> Scenario:
    """ISO 3888-2 obstacle-avoidance lane change: enter at ``speed_kph``, coast from the course entry
    (the first gate's start; the driver's line begins 10 m before it, after a 30 m lead-in)."""
    _positive("speed_kph", speed_kph)
    course = courses.iso3888_2(*_body(params))
    scenario = _path_scenario(
        "iso3888_2",
        course,
        speed_kph,
        mu,
        duration,
        30.0,
        steering,
        params,
        rear_steer_feedforward=rear_steer_feedforward,
    )
    return replace(scenario, coast_after=(course.gates[0].x_start - scenario.start_x) / scenario.speed)


def straight_braking(
    speed_kph=100.0, mu=1.0, duration=None, steering=None, brake_at=0.5, rear_steer_feedforward=False,
    params=VehicleParams(),
) -> Scenario:  # fmt: skip
    """Full braking in a straight line from ``speed_kph`` on ``mu``: the driver holds the speed
    until ``brake_at`` [s], then asks every wheel for the brakes' peak torque (a full pedal, more
    than the road can take: the wheels lock unless ABS works). Runs until 1.5 times the ideal
    stopping time v / (mu g) after the brake application plus 1 s unless ``duration`` is given."""
    speed = _positive("speed_kph", speed_kph) / 3.6
    road = _road(mu)
    brake_at = _finite("brake_at", brake_at, 0.0)
    if duration is None:
        lowest = min([road.table()[0], *road.table()[1][:, 4]]) if road.table() is not None else 0.1
        duration = brake_at + 1.5 * speed / (lowest * GRAVITY) + 1.0
    return Scenario(
        "straight_braking",
        speed_kph,
        road,
        _positive("duration", duration),
        steering if steering is not None else Constant(0.0),
        brake_after=brake_at,
        brake_torque=params.brake_peak_torque,
        rear_steer_feedforward=rear_steer_feedforward,
        params=params,
    )


def mu_jump(
    speed_kph=60.0,
    mu=0.9,
    duration=6.0,
    steering=None,
    mu_patch=0.3,
    lateral_g=0.4,
    patch_x=25.0,
    rear_steer_feedforward=False,
    params=VehicleParams(),
) -> Scenario:
    """Steady cornering at ``lateral_g`` (neutral-steer steering-wheel angle) on ``mu``, onto a
    ``mu_patch`` surface covering every X >= ``patch_x`` [m] (about 1.5 s into the turn). ``mu``
    may be a patch map (e.g. a split road): its patches stay, the jump is laid over them."""
    speed, duration = _positive("speed_kph", speed_kph) / 3.6, _positive("duration", duration)
    reach = speed * duration  # the largest X [m] the car reaches: on a straight, its distance
    if steering is None:
        delta = neutral_steer_angle(_positive("lateral_g", lateral_g) * GRAVITY, speed, params)
        steering = Constant(delta * params.steering_ratio)
        # the circle the steering is designed for (neutral steer, front axle only) from X = 0
        # heading +X [m]: a scenario whose designed path misses its patch is refused, even if a
        # sliding or rear-steered car would happen to reach it
        radius = params.wheelbase / delta
        reach = radius * math.sin(reach / radius) if reach < 0.5 * math.pi * radius else radius
    if not _finite("patch_x", patch_x) > params.cg_to_front:
        raise ValueError(
            f"mu_jump: patch_x must lie ahead of the front axle at the start (X > "
            f"{params.cg_to_front:g} m), got {patch_x!r}: the car would start on the patch"
        )
    if reach <= patch_x:
        raise ValueError(
            f"mu_jump: at {speed_kph!r} km/h for {duration!r} s the car reaches X = {reach:.1f} m at "
            f"most, short of the patch at X = {patch_x!r} m; raise speed_kph or duration (or lower "
            "lateral_g)"
        )
    base = _road(mu)
    if not isinstance(base, PatchMap):
        raise ValueError(f"mu_jump needs a uniform or patch map as mu, got {mu!r}")
    jump = patch(base.base, check_mu("mu_patch", mu_patch), patch_x, math.inf).patches
    road = PatchMap(base.base, base.patches + jump)
    return Scenario(
        "mu_jump",
        speed_kph,
        road,
        _positive("duration", duration),
        steering,
        rear_steer_feedforward=rear_steer_feedforward,
        params=params,
    )


def random(
    speed_kph=None,
    mu=None,
    duration=10.0,
    steering=None,
    seed=0,
    rear_steer_feedforward=False,
    params=VehicleParams(),
    speed_range_kph=(30.0, 110.0),
    lateral_demand=(0.3, 1.2),
    course_share=0.0,
) -> Scenario:
    """Domain-randomised training scenario drawn from ``seed``: speed uniform in
    ``speed_range_kph`` (30-110 km/h); road uniform, split, or with a patch (mu 0.2-1.0);
    steering a sum of three random sines (0.2-1.2 Hz) with an amplitude that asks for
    ``lateral_demand`` (0.3-1.2) times mu g in the linear model, or a random step. The ranges
    change the values drawn, not the draws: a seed gives the same road and frequencies, and a
    fixed ``speed_kph`` or ``mu`` leaves the seed's other draws as they were.

    ``course_share`` (default 0): the probability of a course episode instead, a double lane
    change (:func:`envs.courses.lane_change`: ISO 3888-1's sections times 0.8-2.0, lane 3
    1.5-3.5 m to the left or right) steered by the path-following driver, who answers the
    controller's yaw moment as open-loop steering cannot; it lasts until 20 m past the exit."""
    speed_low, speed_high = _interval("speed_range_kph", speed_range_kph)
    if speed_high > MAX_SPEED_KPH:
        raise ValueError(f"speed_range_kph must lie in (0, {MAX_SPEED_KPH:g}], got {speed_range_kph!r}")
    demand_low, demand_high = _interval("lateral_demand", lateral_demand)
    if not (is_number(course_share) and 0.0 <= course_share <= 1.0):
        raise ValueError(f"course_share must be a probability in [0, 1], got {course_share!r}")
    if not (isinstance(seed, (np.random.SeedSequence, np.random.Generator)) or (is_integer(seed) and seed >= 0)):
        raise ValueError(f"seed must be an integer >= 0 (or a numpy SeedSequence or Generator), got {seed!r}")
    rng = np.random.default_rng(seed)
    # speed and road are drawn even where given, so that fixing one keeps a seed's other draws
    drawn_speed = float(rng.uniform(speed_low, speed_high))
    speed_kph = drawn_speed if speed_kph is None else _positive("speed_kph", speed_kph)
    kind = rng.integers(3)
    lo, hi = np.sort(rng.uniform(0.2, 1.0, 2))
    order = rng.permutation([lo, hi]) if kind == 1 else None
    if mu is None:
        mu = (
            uniform(hi)
            if kind == 0
            else split(*order)
            if kind == 1
            else patch(hi, lo, float(rng.uniform(20.0, 150.0)), float(rng.uniform(170.0, 300.0)))
        )
    elif kind == 2:
        rng.uniform(20.0, 150.0, 2)  # (the patch's extent, as if drawn)
    road = _road(mu)
    if steering is None and course_share > 0.0 and rng.random() < course_share:
        width, front, rear = _body(params)
        course = courses.lane_change(
            width,
            scale=float(rng.uniform(0.8, 2.0)),
            offset=float(rng.uniform(1.5, 3.5)),
            direction=int(rng.choice([-1, 1])),
            front_extent=front,
            rear_extent=rear,
        )
        return _path_scenario(
            "random", course, speed_kph, road, None, 20.0, None, params, rear_steer_feedforward=rear_steer_feedforward
        )
    if steering is None:
        speed = speed_kph / 3.6
        mu_ref = road.table()[0] if road.table() is not None else 0.5
        demand = rng.uniform(demand_low, demand_high) * mu_ref * GRAVITY
        # (at walking pace the demand would ask for more than the lock: held there)
        swa = min(neutral_steer_angle(demand, speed, params), params.max_front_steer) * params.steering_ratio
        if rng.random() < 0.75:
            weights = rng.dirichlet(np.ones(3))
            steering = SumOfSines(
                tuple(float(w * swa) for w in weights),
                tuple(float(f) for f in rng.uniform(0.2, 1.2, 3)),
                tuple(float(p) for p in rng.uniform(0, 2 * np.pi, 3)),
            )
        else:
            steering = Step(float(swa * rng.choice([-1.0, 1.0])), float(rng.uniform(1.0, 4.0)))
    return Scenario(
        "random",
        speed_kph,
        road,
        _positive("duration", duration),
        steering,
        rear_steer_feedforward=rear_steer_feedforward,
        params=params,
    )


_BUILDERS: dict[str, Callable[..., Scenario]] = {
    f.__name__: f
    for f in (
        paper_dlc,
        paper_step,
        paper_sine,
        paper_split_dlc,
        paper_serpentine,
        sine_with_dwell,
        slowly_increasing_steer,
        iso3888_2,
        mu_jump,
        straight_braking,
        random,
    )
}
PAPER_SCENARIOS = ("paper_dlc", "paper_step", "paper_sine", "paper_split_dlc", "paper_serpentine")
SCENARIOS: dict[str, Scenario] = {name: build() for name, build in _BUILDERS.items()}


def make_scenario(name: str, **overrides) -> Scenario:
    """Build the scenario ``name`` with ``overrides``; ValueError names an unknown scenario or argument."""
    if not isinstance(name, str) or name not in _BUILDERS:
        raise ValueError(f"unknown scenario {name!r}; known: {sorted(_BUILDERS)}")
    build = _BUILDERS[name]
    allowed = build.__code__.co_varnames[: build.__code__.co_argcount]
    unknown = sorted(set(overrides) - set(allowed))
    if unknown:
        raise ValueError(f"unknown argument(s) {unknown} for scenario {name!r}; allowed: {sorted(allowed)}")
    return build(**overrides)


__all__ = ["SCENARIOS", "PAPER_SCENARIOS", "Scenario", "make_scenario"]

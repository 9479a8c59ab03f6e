"""Vehicle files: another car for the estimators, in TOML (docs/logs.md has the full format).

A vehicle file gives what the estimators' model needs of a car that is not fourwis's own: the
body (:class:`fourwis.envs.vehicle.VehicleParams` fields; the plant-only ones keep fourwis's
values, the estimators do not read them), the tyres of each axle from what a user has, the
road friction the estimators start from, and how the car's recorded channels map onto the
estimators' inputs (steering geometry, drive layout, brakes, its sensors' noise)::

    name = "my car"
    nominal_mu = 1.0              # road friction the estimators start from / hold [-]

    [body]                        # VehicleParams fields, SI
    mass = 982.0
    cg_to_front = 1.33
    wheel_radius = [0.30, 0.32]   # one radius, or [front, rear] [m]

    [steering]
    ackermann = 1.0               # 0: parallel, 1: full Ackermann (for a log's single steer angle)

    [tyres.front]                 # per axle, one of:
    cornering_stiffness = 7.0e4   #   the axle's cornering stiffness at its static load [N/rad]
    # slip_stiffness = 8.3e4      #   (optional) and its slip stiffness [N]
    # cornering_stiffness_table = [[2000, 3.2e4], [4000, 5.6e4]]  # per tyre: [load N, N/rad], ...
    # m1, n1, m2, n2 = ...        #   or the eq. 17 fit itself (estimation.model.AxleTyre)
    # mu_scale = 1.0              # the friction scale k (default 1: the force peaks at mu Fz)
    # relaxation_length = 0.4     # lateral relaxation length [m] (make_estimator tyre_relaxation)
    # magic_c, magic_e = 1.48, 0.03  # the Magic Formula's shape and curvature (AxleTyre; 0: Dugoff's)
    # load_sensitivity = -0.09    # the peak's change per static load [-] (default 0)
    # reference_load = 3400.0     # the load the peak is given at [N] (default 1)

    [drive]
    layout = "rear"               # the driven wheels: "front", "rear" or "all"
    front_share = 0.5             # ("all") the front axle's share of the drive torque
    gear_ratios = [12.1, 7.9]     # overall engine-to-wheel ratio per gear (a log's gear channel)
    driveline_efficiency = 1.0
    brake_balance = 0.6           # the front axle's share of the braking force [-]
    brake_gain = [2.0e-4, 1.2e-4] # brake torque per pressure, per wheel of each axle [N m/Pa]

    [sensors]                     # the log's sensor noise, one sigma per sample (SI)
    ax = 0.03                     # ay, yaw_rate [rad/s], speed [m/s], wheel_speed [m/s] likewise

The Dugoff fit from a cornering stiffness alone: each tyre carries half the axle's stiffness
at its static load, and the stiffness grows in proportion to the load (eq. 17 with n = 0: the
load dependence such data leave open); from a table, the least-squares eq. 17 fit of
training/tyre_fit.py. Without a slip stiffness it is the cornering stiffness times that of
fourwis's own tyre over its cornering stiffness at its static load (1.19: the PAC2002 tyre of
envs.tyre). Without a ``[tyres]`` section the car has fourwis's own tyre fit on both axles. A
tyre's Magic Formula shape (magic_c > 0, with magic_e, load_sensitivity, reference_load:
:class:`fourwis.estimation.model.AxleTyre`) is read where given; without it, ``joint`` gives
the tyre the fit's shape on its stiffness (``ModelParams.from_vehicle(shape="magic")``).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from fourwis.core.checks import is_number
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation.joint import MU_BOUNDS
from fourwis.estimation.model import AxleTyre
from fourwis.training.tyre_fit import fit_quadratic

DRIVE_LAYOUTS = ("front", "rear", "all")
SENSOR_NOISE_CHANNELS = ("ax", "ay", "yaw_rate", "speed", "wheel_speed")  #: [sensors] keys
#: the top-level keys and sections of a vehicle file
TOP_LEVEL = ("name", "description", "source", "nominal_mu", "body", "steering", "tyres", "drive", "sensors")
TYRE_KEYS = (
    "cornering_stiffness",
    "slip_stiffness",
    "cornering_stiffness_table",
    "slip_stiffness_table",
    "m1",
    "n1",
    "m2",
    "n2",
    "mu_scale",
    "relaxation_length",
    "magic_c",
    "magic_e",
    "load_sensitivity",
    "reference_load",
)
DRIVE_KEYS = ("layout", "front_share", "gear_ratios", "driveline_efficiency", "brake_balance", "brake_gain")
STEERING_KEYS = ("ackermann",)
#: slip over cornering stiffness of fourwis's own tyre at its static load (the default slip stiffness)
_SHIPPED = AxleTyre.shipped()
_FZ0 = float(VehicleParams().static_wheel_loads[0])
SLIP_OVER_CORNERING = float(_SHIPPED.stiffness(_FZ0)[0] / _SHIPPED.stiffness(_FZ0)[1])


@dataclass(frozen=True)
class Vehicle:
    """A car for the estimators: its parameters (``params``, duck-typed VehicleParams; the
    model's wheel radius the mean of the axles'), its tyres (front, rear) (None: fourwis's own
    fit), the road friction ``nominal_mu`` the estimators start from, each axle's wheel radius
    [m], the steering's Ackermann fraction [-], the drive layout, the front axle's share of the
    drive torque, the overall gear ratios [-], the driveline efficiency [-], the front axle's
    share of the braking force [-], each axle's brake gain per wheel [N m/Pa], the sensors'
    noise by channel (one sigma per sample, SI) and where it was read from."""

    name: str
    params: VehicleParams
    tyres: tuple[AxleTyre, AxleTyre] | None
    nominal_mu: float = 0.8
    wheel_radius: tuple[float, float] | None = None
    ackermann: float = 1.0
    drive_layout: str = "all"
    front_drive_share: float = 0.5
    gear_ratios: tuple[float, ...] = ()
    driveline_efficiency: float = 1.0
    brake_balance: float | None = None
    brake_gain: tuple[float, float] | None = None
    sensor_noise: dict = field(default_factory=dict)
    source: str = "fourwis"
    description: str = ""

    def __post_init__(self) -> None:
        if self.wheel_radius is None:
            object.__setattr__(self, "wheel_radius", (self.params.wheel_radius,) * 2)
        if self.brake_balance is None:  # the static front load share
            object.__setattr__(self, "brake_balance", self.params.cg_to_rear / self.params.wheelbase)

    @property
    def axle_radius(self) -> np.ndarray:
        """Each wheel's rolling radius (4,) [m], FL, FR, RL, RR."""
        front, rear = self.wheel_radius
        return np.array([front, front, rear, rear])

    def estimator_options(self) -> dict:
        """The keyword arguments make_estimator takes for this car: its tyres (if not fourwis's)
        and nominal mu."""
        options = {"nominal_mu": self.nominal_mu}
        if self.tyres is not None:
            options["tyres"] = self.tyres
        return options


def fourwis_vehicle(params: VehicleParams | None = None) -> Vehicle:
    """fourwis's own simulated car (``params``, default VehicleParams()) with its tyre fit,
    four-wheel drive by in-wheel motors and the estimators' default nominal mu (0.8)."""
    return Vehicle("fourwis", params or VehicleParams(), None)


def _error(path, message: str) -> ValueError:
    return ValueError(f"vehicle file {path}: {message}")


def _number(path, where: str, value, rule: str = "> 0") -> float:
    ok = is_number(value) and math.isfinite(value)
    ok = ok and (value > 0 if rule == "> 0" else value >= 0 if rule == ">= 0" else True)
    ok = ok and (value <= 1 if rule == "in [0, 1]" else True) and (value >= 0 if rule == "in [0, 1]" else True)
    if not ok:
        raise _error(path, f"{where} must be a finite number {rule}, got {value!r}")
    return float(value)


def _check_keys(path, where: str, table: dict, known) -> None:
    if not isinstance(table, dict):
        raise _error(path, f"[{where}] must be a table, got {table!r}")
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise _error(path, f"unknown key(s) {unknown} in [{where}]; known: {sorted(known)}")


def _stiffness(path, where: str, table: dict, kind: str, static_load: float) -> tuple[float, float] | None:
    """(m, n) of eq. 17 for ``kind`` ("cornering" or "slip") from an axle value or a table, or None."""
    axle, points = table.get(f"{kind}_stiffness"), table.get(f"{kind}_stiffness_table")
    if axle is not None and points is not None:
        raise _error(path, f"[{where}] gives both {kind}_stiffness and {kind}_stiffness_table: give one")
    if axle is not None:
        per_tyre = _number(path, f"[{where}] {kind}_stiffness", axle) / 2.0
        return per_tyre / static_load, 0.0
    if points is not None:
        try:
            array = np.asarray(points, dtype=float)
        except (TypeError, ValueError):
            array = np.empty(0)
        if array.ndim != 2 or array.shape[1] != 2 or len(array) < 2 or not np.all(np.isfinite(array) & (array > 0)):
            raise _error(
                path,
                f"[{where}] {kind}_stiffness_table must be two or more [load N, stiffness] pairs > 0, got {points!r}",
            )
        m, n, _ = fit_quadratic(array[:, 0], array[:, 1])
        return m, n
    return None


def _tyre(path, axle: str, table: dict, static_load: float) -> AxleTyre:
    """The axle's :class:`AxleTyre` from its [tyres.<axle>] table (module docstring)."""
    where = f"tyres.{axle}"
    _check_keys(path, where, table, TYRE_KEYS)
    given_fit = [k for k in ("m1", "n1", "m2", "n2") if k in table]
    cornering = _stiffness(path, where, table, "cornering", static_load)
    slip = _stiffness(path, where, table, "slip", static_load)
    if given_fit and (cornering or slip):
        raise _error(path, f"[{where}] gives both a fit ({given_fit}) and stiffness values: give one")
    if given_fit:
        if len(given_fit) != 4:
            raise _error(path, f"[{where}] needs all of m1, n1, m2, n2 for a fit, got {given_fit}")
        m1, n1, m2, n2 = (_number(path, f"[{where}] {k}", table[k], "any") for k in ("m1", "n1", "m2", "n2"))
    elif cornering is not None:
        m2, n2 = cornering
        m1, n1 = slip if slip is not None else (SLIP_OVER_CORNERING * m2, SLIP_OVER_CORNERING * n2)
    else:
        raise _error(path, f"[{where}] needs a cornering_stiffness (or a table, or the fit m1, n1, m2, n2)")
    try:
        return AxleTyre(
            m1,
            n1,
            m2,
            n2,
            _number(path, f"[{where}] mu_scale", table.get("mu_scale", 1.0)),
            _number(path, f"[{where}] relaxation_length", table.get("relaxation_length", 0.0), ">= 0"),
            _number(path, f"[{where}] magic_c", table.get("magic_c", 0.0), ">= 0"),
            _number(path, f"[{where}] magic_e", table.get("magic_e", 0.0), "any"),
            _number(path, f"[{where}] load_sensitivity", table.get("load_sensitivity", 0.0), "any"),
            _number(path, f"[{where}] reference_load", table.get("reference_load", 1.0)),
        )
    except ValueError as err:
        raise _error(path, f"[{where}]: {err}") from None


def read_vehicle(path: str | Path) -> Vehicle:
    """The :class:`Vehicle` of the TOML file ``path`` (module docstring); ValueError naming the
    file and the bad key or value, FileNotFoundError if there is none."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no vehicle file {str(path)!r}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise _error(path, f"not valid TOML: {err}") from None
    _check_keys(path, "top level", data, TOP_LEVEL)
    body = data.get("body", {})
    _check_keys(path, "body", body, [f.name for f in fields(VehicleParams) if f.name != "tyre"])
    radius = body.get("wheel_radius")
    radii = None
    if isinstance(radius, list):
        if len(radius) != 2:
            raise _error(path, f"[body] wheel_radius must be one radius or [front, rear], got {radius!r}")
        radii = tuple(_number(path, "[body] wheel_radius", r) for r in radius)
        body = {**body, "wheel_radius": 0.5 * (radii[0] + radii[1])}
    try:
        params = VehicleParams().replace(**body)
    except (ValueError, TypeError) as err:
        raise _error(path, f"[body]: {err}") from None
    steering = data.get("steering", {})
    _check_keys(path, "steering", steering, STEERING_KEYS)
    ackermann = _number(path, "[steering] ackermann", steering.get("ackermann", 1.0), "in [0, 1]")
    loads = params.static_wheel_loads
    tyres = data.get("tyres")
    if tyres is not None:
        _check_keys(path, "tyres", tyres, ("front", "rear"))
        missing = [axle for axle in ("front", "rear") if axle not in tyres]
        if missing:
            raise _error(path, f"[tyres] needs both axles; [tyres.{missing[0]}] is missing")
        tyres = (_tyre(path, "front", tyres["front"], loads[0]), _tyre(path, "rear", tyres["rear"], loads[2]))
    drive = data.get("drive", {})
    _check_keys(path, "drive", drive, DRIVE_KEYS)
    layout = drive.get("layout", "all")
    if layout not in DRIVE_LAYOUTS:
        raise _error(path, f"[drive] layout must be one of {list(DRIVE_LAYOUTS)}, got {layout!r}")
    gears = drive.get("gear_ratios", [])
    if not isinstance(gears, list):
        raise _error(path, f"[drive] gear_ratios must be a list of ratios, got {gears!r}")
    gains = drive.get("brake_gain")
    if gains is not None:
        if not isinstance(gains, list) or len(gains) != 2:
            raise _error(path, f"[drive] brake_gain must be [front, rear] [N m/Pa], got {gains!r}")
        gains = tuple(_number(path, "[drive] brake_gain", g, ">= 0") for g in gains)
    sensors = data.get("sensors", {})
    _check_keys(path, "sensors", sensors, SENSOR_NOISE_CHANNELS)
    nominal_mu = data.get("nominal_mu", 0.8)
    if not (is_number(nominal_mu) and MU_BOUNDS[0] <= nominal_mu <= MU_BOUNDS[1]):
        raise _error(path, f"nominal_mu must lie in {MU_BOUNDS} (the estimators' friction range), got {nominal_mu!r}")
    name = data.get("name", path.stem)
    if not isinstance(name, str):
        raise _error(path, f"name must be a string, got {name!r}")
    return Vehicle(
        name,
        params,
        tyres,
        float(nominal_mu),
        radii,
        ackermann,
        layout,
        _number(path, "[drive] front_share", drive.get("front_share", 0.5), "in [0, 1]"),
        tuple(_number(path, "[drive] gear_ratios", g) for g in gears),
        _number(path, "[drive] driveline_efficiency", drive.get("driveline_efficiency", 1.0)),
        None
        if "brake_balance" not in drive
        else _number(path, "[drive] brake_balance", drive["brake_balance"], "in [0, 1]"),
        gains,
        {k: _number(path, f"[sensors] {k}", v, ">= 0") for k, v in sensors.items()},
        str(path),
        str(data.get("description", "")),
    )


def vehicle_toml(vehicle: Vehicle) -> str:
    """A vehicle file's text for ``vehicle`` that :func:`read_vehicle` reads back to the same
    estimator model for every kind (what ``fourwis simulate`` writes beside its log): its body,
    its tyres as the eq. 17 fit with every :class:`AxleTyre` field, the drive and its nominal mu.
    A car with fourwis's own tyres (``tyres`` None) gets no ``[tyres]`` section, which reads back
    as the same: each kind then takes the shipped fit in its own shape, with ``joint``'s Magic
    Formula, load sensitivity and relaxation length (docs/decisions/0045), which one explicit
    tyre could not give every kind."""
    params, default = vehicle.params, VehicleParams()
    lines = [f"name = {vehicle.name!r}".replace("'", '"'), f"nominal_mu = {vehicle.nominal_mu!r}", "", "[body]"]
    for f in fields(VehicleParams):
        if f.name in ("tyre",):
            continue
        value = getattr(params, f.name)
        if value != getattr(default, f.name) or f.name in ("mass", "cg_to_front", "cg_to_rear", "wheel_radius"):
            lines.append(f"{f.name} = {str(value).lower() if isinstance(value, bool) else repr(float(value))}")
    lines += ["", "[steering]", f"ackermann = {vehicle.ackermann!r}"]
    if vehicle.tyres is None:
        lines += ["", "# no [tyres]: fourwis's own tyre fit on both axles (estimation/data/dugoff_fit.json)"]
    for axle, tyre in zip(("front", "rear"), vehicle.tyres or ()):
        lines += ["", f"[tyres.{axle}]"] + [f"{f.name} = {getattr(tyre, f.name)!r}" for f in fields(AxleTyre)]
    lines += [
        "",
        "[drive]",
        f'layout = "{vehicle.drive_layout}"',
        f"front_share = {vehicle.front_drive_share!r}",
        f"brake_balance = {vehicle.brake_balance!r}",
        "",
    ]
    return "\n".join(lines)

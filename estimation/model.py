"""The estimator's own vehicle model (paper section 2): 3-DOF body, Dugoff tyres with
load-dependent stiffness (eq. 17), quasi-static normal loads. Simpler than, and different
from, the truth plant (PAC2002 tyres with relaxation, wheel dynamics, lags): no inverse crime.

The physics is compiled (numba): the tyre functions work on scalars, and :func:`body_forces`
/ :func:`transition` evaluate them for all of a filter's cubature points at once, in SIMD
lanes; parameters travel as the value :attr:`ModelParams.kernel` (a NamedTuple of floats).
:func:`normal_loads` and :func:`state_transition` are the Python entry points. Corrections to
the paper (standard textbook forms, Rajamani 2012 ch. 13; Dugoff, Fancher & Segel 1970):

* eq. 4-6: each wheel's force is rotated by its own steer angle and the moment arms are
  +/- t/2 laterally and +a / -b longitudinally with the signs of ISO 8855 (the paper's rear-
  wheel signs slip);
* eq. 8-10: the Dugoff parameter L carries mu*Fz and the factor 2, and the force is
  C tan(alpha)/(1+s) f(L) (the paper's eq. 8 multiplies the force by mu*Fz, its eq. 10 leaves
  both out of L);
* eq. 11-12: the wheel-centre speeds carry -/+ (t/2) r for the left / right wheels, and the
  rear slip angles' lateral speed is v - b r (eq. 12 prints -v + b r);
* eq. 14: the rear normal loads carry a/l (the paper writes b/l), :func:`wheel_load`;
* eq. 15: one slip ratio, (R omega - u_w) / max(|R omega|, |u_w|), positive when driving, for
  drive and brake alike (the paper's drive case flips the sign and divides by the wheel-centre
  speed instead of R omega);
* eq. 4-7 leave out the resistances; with ``ModelParams.from_vehicle(..., resistances=True)``
  the wheel's torque balance subtracts its rolling resistance f_r Fz (J omega_dot = T - R Fx -
  R f_r Fz) and the body's longitudinal balance the aerodynamic drag (1/2) rho Cd A u|u|
  (Kiencke & Nielsen 2005, ch. 7). Without them the model reads a car cruising at 20 m/s as
  accelerating; the shipped estimators keep the paper's model all the same, since the
  resistances make the friction gate miss drops (docs/decisions/0020-tyre-relaxation-and-resistances-off.md);
* the paper's tyre has no transient: its force follows the slip angle at once. With
  ``ModelParams.from_vehicle(..., relaxation=True)`` each wheel's slip angle instead relaxes
  towards the kinematic one over the tyre's lateral relaxation length sigma (first-order lag in
  travelled distance, d tan(alpha)/dt = (|u_w| / sigma)(tan(alpha_kin) - tan(alpha)); Pacejka,
  *Tire and Vehicle Dynamics*, 3rd ed., sec. 7.2). The estimator carries the lag as a known
  offset of tan(alpha) from its previous estimate (:func:`wheel_kinematics`), so the state
  vector stays the paper's. Off in the shipped estimators: the sideslip estimate improves, the
  friction estimate worsens on the sine (docs/decisions/0020-tyre-relaxation-and-resistances-off.md);
* eq. 10: Dugoff's speed reduction of friction is mu (1 - eps u sqrt(s^2 + tan^2 alpha))
  (Dugoff, Fancher & Segel 1970: the sliding speed; the paper's form puts the stiffnesses
  inside the root, which makes eps carry newtons).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields, replace
from functools import cached_property
from importlib import resources
from typing import NamedTuple

import numba
import numpy as np

from fourwis.core import vecmath
from fourwis.core.checks import is_number
from fourwis.core.constants import GRAVITY
from fourwis.core.kernels import JIT, scratch

MIN_SPEED = 1.0  #: denominator floor for slip quantities [m/s]


def _load_fit() -> dict:
    return json.loads(resources.files("fourwis.estimation").joinpath("data/dugoff_fit.json").read_text())


MODEL_STEP = 0.002  #: [s] the model's longest integration step: a longer filter step integrates in substeps
TYRE_SHAPES = ("dugoff", "magic")  #: the lateral force's shapes of :class:`AxleTyre`


@dataclass(frozen=True)
class AxleTyre:
    """One axle's tyres in the estimator's model (both wheels alike; paper eq. 8-10 and 17).
    Stiffness C(Fz) = m Fz - n Fz^2 at wheel load Fz [N]: m1 [1/unit slip], n1 [1/(unit slip N)]
    longitudinal, m2 [1/rad], n2 [1/(rad N)] lateral (so C is in N/unit slip and N/rad);
    mu_scale: the friction scale k, the tyre using k mu on a road of friction mu [-];
    relaxation_length: the lateral relaxation length sigma [m] its slip angle lags by (0: the
    paper's tyre, without transient). The lateral force's shape: Dugoff's (the paper's) while
    magic_c is 0, else the simplified Magic Formula (:func:`magic_lateral`) with shape factor
    magic_c (C) and curvature magic_e (E) [-], its peak k mu Fz (1 + load_sensitivity (Fz /
    reference_load - 1)) (load_sensitivity [-], reference_load [N]): Dugoff is linear up to half
    the grip and rounds off late, the plant's tyre bends from the start, which put the sideslip
    0.1-0.3 deg off at 50-70% of the grip even at the true friction
    (docs/decisions/0045-friction-and-sideslip-consistency.md)."""

    m1: float
    n1: float
    m2: float
    n2: float
    mu_scale: float = 1.0
    relaxation_length: float = 0.0
    magic_c: float = 0.0
    magic_e: float = 0.0
    load_sensitivity: float = 0.0
    reference_load: float = 1.0

    def __post_init__(self) -> None:
        rules = {
            "m1": "> 0",
            "m2": "> 0",
            "mu_scale": "> 0",
            "n1": "",
            "n2": "",
            "relaxation_length": ">= 0",
            "magic_c": ">= 0",
            "magic_e": "",
            "load_sensitivity": "",
            "reference_load": "> 0",
        }
        for name, rule in rules.items():
            value = getattr(self, name)
            ok = is_number(value) and math.isfinite(value)
            ok = ok and (value > 0 if rule == "> 0" else value >= 0 if rule else True)
            if not ok:
                raise ValueError(f"AxleTyre.{name} must be a finite number {rule}".rstrip() + f", got {value!r}")

    @classmethod
    def shipped(cls, fit: dict | None = None, *, shape: str = "dugoff") -> AxleTyre:
        """The eq. 17 fit of fourwis's own simulated tyre (estimation/data/dugoff_fit.json, or
        ``fit``) with the lateral ``shape`` ``"dugoff"`` (its friction scale) or ``"magic"`` (the
        fit's Magic Formula shape, friction scale and load sensitivity, :meth:`with_magic_shape`)."""
        fit = fit or _load_fit()
        if shape not in TYRE_SHAPES:
            raise ValueError(f"tyre shape must be one of {list(TYRE_SHAPES)}, got {shape!r}")
        dugoff_tyre = cls(fit["m1"], fit["n1"], fit["m2"], fit["n2"], fit["mu_scale"])
        return dugoff_tyre if shape == "dugoff" else dugoff_tyre.with_magic_shape(fit, peak=True)

    def with_magic_shape(self, fit: dict | None = None, peak: bool = False) -> AxleTyre:
        """This tyre with the Magic Formula lateral shape (C, E) of the shipped fit (or ``fit``);
        its stiffness (the slope at zero slip) kept, and its friction scale unless ``peak``:
        then the fit's friction scale and load sensitivity too (the shipped tyre's own). A tyre
        that has a shape keeps it. Another car's tyre given by its stiffness alone borrows the
        shape of fourwis's passenger tyre: the closest thing to it the file gives."""
        if self.magic_c > 0.0:
            return self
        magic = (fit or _load_fit())["magic"]
        shape = dict(magic_c=float(magic["magic_c"]), magic_e=float(magic["magic_e"]))
        if peak:
            shape |= dict(
                mu_scale=float(magic["mu_scale"]),
                load_sensitivity=float(magic["load_sensitivity"]),
                reference_load=float(magic["reference_load"]),
            )
        return replace(self, **shape)

    def stiffness(self, fz) -> tuple[np.ndarray, np.ndarray]:
        """(Cx [N/unit slip], Cy [N/rad]) at wheel load(s) ``fz`` [N]."""
        fz = np.asarray(fz, dtype=float)
        return self.m1 * fz - self.n1 * fz**2, self.m2 * fz - self.n2 * fz**2

    @property
    def kernel(self) -> TyreKernel:
        """These coefficients as the compiled model reads them."""
        return TyreKernel(*(float(getattr(self, f.name)) for f in fields(self)))


#: :class:`AxleTyre` as the compiled model takes it: a NamedTuple of the same fields (floats)
TyreKernel = NamedTuple("TyreKernel", [(f.name, float) for f in fields(AxleTyre)])


@dataclass(frozen=True)
class ModelParams:
    """Estimator model parameters (SI): the body (mass [kg], yaw inertia [kg m^2], CG to the
    axles [m], tracks [m], wheel radius [m], CG height [m], wheel spin inertia [kg m^2]), the
    tyres of each axle (:class:`AxleTyre`; their friction scale k is fitted to the plant tyre by
    training/tyre_fit.py: Dugoff saturates more gently than the Magic Formula, so with k = 1 the
    estimated mu reads high), eps: Dugoff's speed reduction of friction [s/m];
    rolling_resistance: f_r [-]; drag_factor: (1/2) rho Cd A [kg/m], drag = drag_factor u|u|;
    force_ellipse: the combined-slip cut of the lateral force from the measured longitudinal
    force (:func:`lateral_force`; False: Dugoff's cut by the wheel-speed slip, the paper's)."""

    mass: float
    yaw_inertia: float
    cg_to_front: float
    cg_to_rear: float
    track_front: float
    track_rear: float
    wheel_radius: float
    cg_height: float
    wheel_inertia: float
    front: AxleTyre
    rear: AxleTyre
    eps: float = 0.0
    rolling_resistance: float = 0.0
    drag_factor: float = 0.0
    force_ellipse: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.force_ellipse, bool):
            raise ValueError(f"ModelParams.force_ellipse must be True or False, got {self.force_ellipse!r}")
        for name in ("front", "rear"):
            if not isinstance(getattr(self, name), AxleTyre):
                raise ValueError(
                    f"ModelParams.{name} must be an estimation.model.AxleTyre, got {getattr(self, name)!r}"
                )

    @classmethod
    def from_vehicle(
        cls,
        vehicle,
        fit: dict | None = None,
        resistances: bool = False,
        relaxation: bool = False,
        tyres: tuple[AxleTyre, AxleTyre] | None = None,
        force_ellipse: bool = False,
        shape: str = "dugoff",
    ) -> ModelParams:
        """From a duck-typed VehicleParams and the tyres (front, rear) ``tyres`` (default: both
        axles the eq. 17 fit of fourwis's own simulated tyre, estimation/data/dugoff_fit.json, or
        ``fit``). ``resistances``: also the car's rolling resistance and drag, which the paper's
        model (and the shipped estimators) leave out: with them u and beta are more accurate, but
        the joint estimator's friction gate misses more friction drops.
        ``relaxation``: the slip angles lag by the tyres' lateral relaxation lengths: those of
        ``tyres`` (each must have one), or, for fourwis's own tyre, its length at the mean static
        wheel load m g / 4 (``vehicle.static_relaxation_lengths``, 0.36 m for the paper's car; the
        plant's grows with load, which this constant leaves out). Both off by default
        (docs/decisions/0020-tyre-relaxation-and-resistances-off.md). ``force_ellipse``: see the
        class docstring (docs/decisions/0034-combined-slip-from-the-measured-force.md).
        ``shape``: the tyres' lateral shape (:data:`TYRE_SHAPES`): ``"magic"`` gives fourwis's
        own tyre the fit's Magic Formula and other tyres of Dugoff's form the fit's shape factors
        (:meth:`AxleTyre.with_magic_shape`); ``"dugoff"`` keeps the tyres as they are."""
        if shape not in TYRE_SHAPES:
            raise ValueError(f"tyre shape must be one of {list(TYRE_SHAPES)}, got {shape!r}")
        if tyres is None:
            shipped = AxleTyre.shipped(fit, shape=shape)
            sigma = float(vehicle.static_relaxation_lengths[1]) if relaxation else 0.0
            front = rear = replace(shipped, relaxation_length=sigma)
        else:
            if fit is not None:
                raise ValueError("give the tyres or a fit of fourwis's tyre, not both")
            if len(tyres) != 2 or not all(isinstance(t, AxleTyre) for t in tyres):
                raise ValueError(f"tyres must be (front, rear) estimation.model.AxleTyre, got {tyres!r}")
            for axle, tyre in zip(("front", "rear"), tyres):
                if relaxation and tyre.relaxation_length <= 0:
                    raise ValueError(f"relaxation needs the {axle} tyres' relaxation length; it is not given")
            front, rear = (t if relaxation else replace(t, relaxation_length=0.0) for t in tyres)
            if shape == "magic":
                front, rear = front.with_magic_shape(fit), rear.with_magic_shape(fit)
        return cls(
            vehicle.mass,
            vehicle.yaw_inertia,
            vehicle.cg_to_front,
            vehicle.cg_to_rear,
            vehicle.track_front,
            vehicle.track_rear,
            vehicle.wheel_radius,
            vehicle.cg_height,
            vehicle.wheel_inertia,
            front,
            rear,
            rolling_resistance=vehicle.rolling_resistance if resistances else 0.0,
            drag_factor=0.5 * vehicle.air_density * vehicle.drag_area if resistances else 0.0,
            force_ellipse=bool(force_ellipse),
        )

    @property
    def wheelbase(self) -> float:
        return self.cg_to_front + self.cg_to_rear

    @property
    def static_wheel_loads(self) -> np.ndarray:
        """Static normal loads (4,) [N], FL, FR, RL, RR."""
        front = self.mass * GRAVITY * self.cg_to_rear / (2.0 * self.wheelbase)
        rear = self.mass * GRAVITY * self.cg_to_front / (2.0 * self.wheelbase)
        return np.array([front, front, rear, rear])

    @property
    def axle_cornering_stiffness(self) -> tuple[float, float]:
        """(C_f, C_r): each axle's linear cornering stiffness at its static load [N/rad] (two tyres)."""
        fz = self.static_wheel_loads
        return 2.0 * float(self.front.stiffness(fz[0])[1]), 2.0 * float(self.rear.stiffness(fz[2])[1])

    @cached_property
    def kernel(self) -> ModelKernel:
        """These parameters as the compiled model reads them (a value: numba keeps it in registers)."""
        return ModelKernel(
            *(
                getattr(self, f.name).kernel
                if f.name in ("front", "rear")
                else getattr(self, f.name)
                if f.name == "force_ellipse"
                else float(getattr(self, f.name))
                for f in fields(self)
            )
        )


#: :class:`ModelParams` as the compiled model takes it: a NamedTuple of the same fields (floats,
#: the axles' :data:`TyreKernel` and the force_ellipse flag)
ModelKernel = NamedTuple(
    "ModelKernel",
    [
        (f.name, TyreKernel if f.name in ("front", "rear") else bool if f.name == "force_ellipse" else float)
        for f in fields(ModelParams)
    ],
)


@numba.njit(inline="always", **JIT)
def axle_tyre(pk, w: int):
    """Wheel w's (FL, FR, RL, RR) axle tyres, a :data:`TyreKernel`, of the model ``pk``."""
    return pk.front if w < 2 else pk.rear


class ModelInputs(NamedTuple):
    """What the process model needs besides the state, for one vehicle's step: friction mu
    (4,) (the state filter's) or the state x (6,) (the friction filter's, whose points are the
    mu), the steer table (4, 4) (:func:`steer_trig`), wheel speeds omega (4,) [rad/s], motor
    torques (4,) [N m], wheel accelerations omega_dot (4,) [rad/s^2], the model and the step
    dt [s]."""

    mu: np.ndarray
    steer: np.ndarray
    omega: np.ndarray
    torque: np.ndarray
    omega_dot: np.ndarray
    model: ModelKernel
    dt: float


class Inputs(NamedTuple):
    """Measured inputs of one step: road-wheel steer angles (4,) [rad], wheel speeds (4,)
    [rad/s], motor torques (4,) [N m], wheel angular accelerations (4,) [rad/s^2]."""

    delta: np.ndarray
    omega: np.ndarray
    torque: np.ndarray
    omega_dot: np.ndarray


@numba.njit(inline="always", **JIT)
def wheel_position(pk, w: int) -> tuple[float, float]:
    """Wheel w's (FL, FR, RL, RR) position from the CG [m]: +a / -b forward, +/- t/2 left.
    ``pk``: :attr:`ModelParams.kernel`."""
    x = pk.cg_to_front if w < 2 else -pk.cg_to_rear
    half = 0.5 * (pk.track_front if w < 2 else pk.track_rear)
    return x, half if w % 2 == 0 else -half


@numba.njit(inline="always", **JIT)
def wheel_load(ax: float, ay: float, pk, w: int) -> float:
    """Quasi-static load [N] of wheel w (FL, FR, RL, RR) from body accelerations ax, ay
    [m/s^2]: static share plus longitudinal (m ax h / L) and lateral (m ay h / t, split by axle
    static share) transfer; floored at 5% of the static load."""
    m, a, b, h = pk.mass, pk.cg_to_front, pk.cg_to_rear, pk.cg_height
    L = a + b
    if w < 2:
        axle = m * GRAVITY * b / L - m * ax * h / L
        transfer = m * ay * h * (b / L) / pk.track_front
        floor = 0.05 * m * GRAVITY * b / (2 * L)
    else:
        axle = m * GRAVITY * a / L + m * ax * h / L
        transfer = m * ay * h * (a / L) / pk.track_rear
        floor = 0.05 * m * GRAVITY * a / (2 * L)
    return max(axle / 2 - transfer if w % 2 == 0 else axle / 2 + transfer, floor)


@numba.njit(inline="always", **JIT)
def load_tuple(ax: float, ay: float, pk: ModelKernel) -> tuple[float, float, float, float]:
    """The four wheels' :func:`wheel_load` [N] (FL, FR, RL, RR)."""
    return wheel_load(ax, ay, pk, 0), wheel_load(ax, ay, pk, 1), wheel_load(ax, ay, pk, 2), wheel_load(ax, ay, pk, 3)


@numba.njit(**JIT)
def wheel_loads(ax: float, ay: float, pk: ModelKernel, fz: np.ndarray) -> None:
    """:func:`load_tuple` written into fz (4,) [N]."""
    fz[0], fz[1], fz[2], fz[3] = load_tuple(ax, ay, pk)


@numba.njit(inline="always", **JIT)
def fill_steer_trig(delta, trig: np.ndarray) -> None:
    """cos, sin and tan of the four road-wheel steer angles delta (4,) [rad] (array or tuple)
    into rows 0-2 of the wheel table trig (4, 4), and a zero slip lag into row 3 (the tyre
    relaxation's offset of tan(alpha), which the joint estimator's step fills in when the model
    has a relaxation length): computed once per step, shared by every cubature point."""
    for w in range(4):
        trig[0, w], trig[1, w], trig[2, w] = math.cos(delta[w]), math.sin(delta[w]), math.tan(delta[w])
        trig[3, w] = 0.0


@numba.njit(**JIT)
def steer_trig(delta: np.ndarray) -> np.ndarray:
    """:func:`fill_steer_trig` of delta (4,) [rad] as a new (4, 4) wheel table (no slip lag)."""
    trig = np.empty((4, 4))
    fill_steer_trig(delta, trig)
    return trig


@numba.njit(inline="always", **JIT)
def wheel_trig(steer: np.ndarray, w: int) -> tuple[float, float, float, float]:
    """cos, sin, tan of wheel w's steer angle and its slip lag from :func:`steer_trig`'s (4, 4)
    wheel table. The tyre functions take this tuple, not the table: an array handed to an
    inlined function inside a loop keeps the compiler from vectorising the loop."""
    return steer[0, w], steer[1, w], steer[2, w], steer[3, w]


@numba.njit(inline="always", **JIT)
def wheel_kinematics(u: float, v: float, r: float, trig: tuple, pk, w: int) -> tuple[float, float]:
    """Wheel w's tan(slip angle) and wheel-centre speed along its heading [m/s] (eq. 11-14,
    standard form: alpha_i = delta_i - atan((v + x_i r) / (u - y_i r)), the longitudinal speed
    floored at MIN_SPEED), with tan(alpha) = (tan delta - q) / (1 + q tan delta),
    q = (v + x_i r) / (u - y_i r): no inverse trigonometry per point, less the tyre's relaxation
    lag of tan(alpha) (0 without relaxation). ``trig``: :func:`wheel_trig`."""
    x_w, y_w = wheel_position(pk, w)
    vx = u - r * y_w
    vy = v + r * x_w
    q = vy / max(abs(vx), MIN_SPEED)
    cos_d, sin_d, tan_d, lag = trig
    return (tan_d - q) / (1.0 + q * tan_d) - lag, vx * cos_d + vy * sin_d


@numba.njit(inline="always", **JIT)
def dugoff(
    fz: float, slip: float, tan_alpha: float, mu: float, cx: float, cy: float, speed: float, eps: float
) -> tuple[float, float, float]:
    """Dugoff combined-slip forces Fx, Fy [N] and Dugoff's lambda (Dugoff, Fancher & Segel 1970;
    Rajamani 2012 sec. 13.9), with ``slip`` positive when driving (the SAE sign of this package)
    and the speed reduction of friction on the sliding speed u sqrt(s^2 + tan^2 a):
    lambda = mu Fz (1 - eps u sqrt(s^2 + tan^2 a)) (1 + s) / (2 sqrt(Cx^2 s^2 + Cy^2 tan^2 a)),
    f = (2 - lambda) lambda if lambda < 1 else 1; Fx = Cx s/(1+s) f, Fy = Cy tan(a)/(1+s) f.
    (Dugoff's paper writes 1 - s for braking slip, positive when braking: the same law.) Below lambda = 1 the force
    depends on mu (the tyre is saturating)."""
    one_plus_s = max(1.0 + slip, 0.05)
    demand = vecmath.sqrt((cx * slip) * (cx * slip) + (cy * tan_alpha) * (cy * tan_alpha))
    lam = (
        mu
        * fz
        * (1.0 - eps * speed * vecmath.sqrt(slip * slip + tan_alpha * tan_alpha))
        * one_plus_s
        / (2.0 * max(demand, 1e-9))
    )
    f = (2.0 - lam) * lam if lam < 1.0 else 1.0
    return cx * slip / one_plus_s * f, cy * tan_alpha / one_plus_s * f, lam


@numba.njit(inline="always", **JIT)
def stiffness(fz: float, tyre) -> tuple[float, float]:
    """Eq. 17's load-dependent stiffnesses Cx(Fz) = m1 Fz - n1 Fz^2 [N/unit slip] and
    Cy(Fz) = m2 Fz - n2 Fz^2 [N/rad] at wheel load ``fz`` [N]; ``tyre``: :attr:`AxleTyre.kernel`
    (a wheel's: :func:`axle_tyre`)."""
    return tyre.m1 * fz - tyre.n1 * fz * fz, tyre.m2 * fz - tyre.n2 * fz * fz


@numba.njit(inline="always", **JIT)
def tyre_operating_point(u, v, r, fz, trig, omega, pk, w) -> tuple[float, float, float, float]:
    """Wheel w's tan(slip angle), longitudinal slip and stiffnesses Cx, Cy (eq. 17) at load fz;
    ``trig``: :func:`wheel_trig`, ``omega``: its speed [rad/s]."""
    tan_alpha, along = wheel_kinematics(u, v, r, trig, pk, w)
    wheel_speed = omega * pk.wheel_radius
    slip = (wheel_speed - along) / max(abs(wheel_speed), abs(along), MIN_SPEED)
    cx, cy = stiffness(fz, axle_tyre(pk, w))
    return tan_alpha, slip, cx, cy


@numba.njit(inline="always", **JIT)
def peak_friction(fz: float, tyre_mu: float, tyre) -> float:
    """A tyre's peak force coefficient [-] at load ``fz`` [N] and friction ``tyre_mu`` (k mu): k mu
    times the load sensitivity 1 + s (Fz / F0 - 1) of its peak (``tyre.load_sensitivity`` s,
    ``tyre.reference_load`` F0 [N]; s = 0, Dugoff's tyre: k mu exactly)."""
    return tyre_mu * (1.0 + tyre.load_sensitivity * (fz / tyre.reference_load - 1.0))


@numba.njit(inline="always", **JIT)
def magic_lateral(fz: float, alpha: float, tyre_mu: float, cy: float, tyre) -> float:
    """The simplified Magic Formula's pure-slip lateral force [N] (Pacejka, *Tire and Vehicle
    Dynamics*, 3rd ed., eq. 4.49 without shifts): D sin(C atan(B x - E (B x - atan(B x)))), x the
    slip angle ``alpha`` [rad], D :func:`peak_friction` times Fz, C ``tyre.magic_c``, E ``tyre.magic_e`` and
    B = Cy / (C D), so that the slope at zero slip is the eq. 17 stiffness ``cy`` [N/rad] at any friction."""
    d = max(peak_friction(fz, tyre_mu, tyre) * fz, 1e-9)
    bx = cy / (tyre.magic_c * d) * alpha
    return d * vecmath.sin(tyre.magic_c * vecmath.atan(bx - tyre.magic_e * (bx - vecmath.atan(bx))))


#: the lateral tyre laws :func:`lateral_force` chooses between (:func:`lateral_law`)
LATERAL_DUGOFF_SLIP, LATERAL_DUGOFF_ELLIPSE, LATERAL_MAGIC_ELLIPSE = 0, 1, 2


@numba.njit(inline="always", **JIT)
def lateral_law(pk, tyre) -> int:
    """The lateral law of the model ``pk`` for the axle ``tyre`` (LATERAL_*): Dugoff's cut by
    the wheel-speed slip without ``pk.force_ellipse``, else the friction ellipse around Dugoff's
    pure-slip force, or around the Magic Formula's where ``tyre.magic_c`` > 0."""
    if not pk.force_ellipse:
        return LATERAL_DUGOFF_SLIP
    return LATERAL_MAGIC_ELLIPSE if tyre.magic_c > 0.0 else LATERAL_DUGOFF_ELLIPSE


@numba.njit(inline="always", **JIT)
def lateral_force(fz, fx, slip, tan_alpha, alpha, tyre_mu, cx, cy, speed, pk, tyre, law: int) -> float:
    """A wheel's lateral force [N] at load ``fz`` [N], tan(slip angle) ``tan_alpha`` and slip angle
    ``alpha`` [rad] (the Magic Formula's) and friction ``tyre_mu`` (k mu) with the
    wheel's axle ``tyre`` by its :func:`lateral_law` ``law`` (a compile-time constant in the lane
    loops of the Magic Formula's law: that loop then has no branch). Dugoff's combined slip cuts
    it by the longitudinal ``slip`` from the wheel speed (the paper's); with ``pk.force_ellipse``
    the pure-slip force (Dugoff's, or the Magic Formula's where ``tyre.magic_c`` > 0,
    :func:`magic_lateral`) is cut by the friction ellipse of the measured longitudinal force
    ``fx`` [N] (|fx| <= tyre_mu fz):
    Fy0 sqrt(1 - (Fx / (mu Fz))^2) (the friction-ellipse combination; Wong, Theory of Ground
    Vehicles, sec. 1.4). A wheel speed swings around the force its wheel carries when torques
    change fast (random torques at 8 m/s: slips of 10-30% while the car holds 0.85 g), and
    Dugoff's cut at that slip removes lateral force the car still has
    (docs/decisions/0034-combined-slip-from-the-measured-force.md)."""
    if law == LATERAL_DUGOFF_SLIP:
        return dugoff(fz, slip, tan_alpha, tyre_mu, cx, cy, speed, pk.eps)[1]
    if law == LATERAL_MAGIC_ELLIPSE:
        pure = magic_lateral(fz, alpha, tyre_mu, cy, tyre)
    else:
        pure = dugoff(fz, 0.0, tan_alpha, tyre_mu, cx, cy, speed, pk.eps)[1]
    share = fx / max(peak_friction(fz, tyre_mu, tyre) * fz, 1e-9)
    return pure * vecmath.sqrt(max(1.0 - share * share, 0.0))


@numba.njit(inline="always", **JIT)
def wheel_drive(torque: float, omega_dot: float, omega: float, pk: ModelKernel) -> tuple[float, float]:
    """A wheel's drive force [N] from its torque balance (eq. 7: a measured force, torque [N m] less
    the wheel inertia times its acceleration ``omega_dot`` [rad/s^2]) and its rolling resistance
    coefficient f_r with the sign of the wheel speed (``omega`` [rad/s]), smoothed below 0.05 m/s
    as in the plant: the wheel's longitudinal force is drive - rolling Fz."""
    wheel_speed = omega * pk.wheel_radius
    rolling = pk.rolling_resistance * wheel_speed / vecmath.sqrt(wheel_speed * wheel_speed + 0.0025)
    return (torque - pk.wheel_inertia * omega_dot) / pk.wheel_radius, rolling


@numba.njit(inline="always", **JIT)
def wheel_operating_point(u, v, r, ax, ay, trig, spin, pk, w, law: int):
    """Wheel w's load fz [N] (from ax, ay), tan(slip angle), longitudinal slip, stiffnesses Cx,
    Cy (:func:`tyre_operating_point`) and slip angle [rad] (the Magic Formula's ``law``, else 0)
    at the state u, v, r, ax, ay: what :func:`wheel_force_at` needs that does not depend on mu."""
    fz = wheel_load(ax, ay, pk, w)
    tan_alpha, slip, cx, cy = tyre_operating_point(u, v, r, fz, trig, spin, pk, w)
    alpha = vecmath.atan(tan_alpha) if law == LATERAL_MAGIC_ELLIPSE else 0.0
    return fz, tan_alpha, slip, cx, cy, alpha


@numba.njit(inline="always", **JIT)
def wheel_force_at(fz, tan_alpha, slip, cx, cy, alpha, u, mu, trig, drive, rolling, pk, w, law: int):
    """Wheel w's force on the body along x and y [N] and its yaw moment [N m] (eq. 4-6, corrected)
    at its :func:`wheel_operating_point` (fz .. alpha) and forward speed u [m/s] with friction
    ``mu``: Fx from :func:`wheel_drive`'s ``drive`` and ``rolling`` limited to +/- k mu Fz against
    sensor noise, Fy from :func:`lateral_force` by the wheel's :func:`lateral_law` ``law``;
    ``trig``: :func:`wheel_trig`."""
    x_w, y_w = wheel_position(pk, w)
    tyre = axle_tyre(pk, w)
    tyre_mu = tyre.mu_scale * mu
    limit = peak_friction(fz, tyre_mu, tyre) * fz
    fx = min(max(drive - rolling * fz, -limit), limit)
    fy = lateral_force(fz, fx, slip, tan_alpha, alpha, tyre_mu, cx, cy, u, pk, tyre, law)
    c, s = trig[0], trig[1]
    f_long, f_lat = fx * c - fy * s, fx * s + fy * c
    return f_long, f_lat, x_w * f_lat - y_w * f_long


@numba.njit(inline="always", **JIT)
def wheel_force(u, v, r, ax, ay, mu, trig, spin, drive, rolling, pk, w, law: int) -> tuple[float, float, float]:
    """Wheel w's :func:`wheel_force_at` at the state u, v, r, ax, ay (its operating point there)
    with friction ``mu``; ``spin``: its speed [rad/s]. The one evaluation :func:`body_forces` and
    :func:`body_forces_lanes` repeat."""
    fz, tan_alpha, slip, cx, cy, alpha = wheel_operating_point(u, v, r, ax, ay, trig, spin, pk, w, law)
    return wheel_force_at(fz, tan_alpha, slip, cx, cy, alpha, u, mu, trig, drive, rolling, pk, w, law)


@numba.njit(inline="always", **JIT)
def body_forces(
    state: np.ndarray,
    mu: np.ndarray,
    steer: np.ndarray,
    omega: np.ndarray,
    torque: np.ndarray,
    omega_dot: np.ndarray,
    pk: ModelKernel,
    out: np.ndarray,
) -> None:
    """Body accelerations ax, ay [m/s^2] and yaw moment Gamma [N m] from the tyre forces (eq. 4-6,
    corrected) for K model evaluations at once: ``state`` (5, K) rows u, v, r, ax, ay and
    ``mu`` (4, K) per wheel; writes the rows of out (3, K): the sum of each wheel's
    :func:`wheel_force`, the drag drag_factor u|u| against ax.
    Loads from the (previous) ax, ay; ``steer``: :func:`steer_trig` of the steer angles.

    Wheel by wheel over all K evaluations (the K loop innermost and branch-free, so the
    compiler runs it in SIMD lanes), each evaluation summing its wheels in order FL, FR, RL,
    RR. Callers pass stack arrays (:func:`fourwis.core.kernels.scratch`): the compiler then knows
    they do not overlap, which it needs before it vectorises."""
    K = state.shape[1]
    out[:, :] = 0.0
    for w in range(4):
        trig, spin = wheel_trig(steer, w), omega[w]
        drive, rolling = wheel_drive(torque[w], omega_dot[w], spin, pk)
        law = lateral_law(pk, axle_tyre(pk, w))
        for k in range(K):
            f_long, f_lat, moment = wheel_force(
                state[0, k], state[1, k], state[2, k], state[3, k], state[4, k], mu[w, k], trig, spin, drive, rolling,
                pk, w, law,
            )  # fmt: skip
            out[0, k] += f_long
            out[1, k] += f_lat
            out[2, k] += moment
    for k in range(K):
        u = state[0, k]
        out[0, k] = (out[0, k] - pk.drag_factor * u * abs(u)) / pk.mass
        out[1, k] /= pk.mass


@numba.njit(**JIT)
def _add_wheel_lanes(state, mu, steer, omega, drive, rolling, pk, w: int, law: int, shared: bool, out, K, lanes):
    """Wheel w's :func:`wheel_force` by ``law`` (its :func:`lateral_law`) at the K evaluations of
    each of ``lanes`` cars, added to out (3, K, lanes) (:func:`body_forces_lanes`' arguments);
    ``shared`` (a constant): each car's state is state[:, 0] for all K evaluations, which then
    differ in mu alone, and the wheel's :func:`wheel_operating_point` is taken once per car.

    Not inlined: compiled once per (``law`` constant or not, ``shared``, ``lanes``) and called, so
    that its loops are not typed and vectorised again at every call site
    (docs/decisions/0051-lane-kernels-compiled-once.md)."""
    point = scratch((6, lanes))
    if shared:
        for lane in range(lanes):
            trig = (steer[0, w, lane], steer[1, w, lane], steer[2, w, lane], steer[3, w, lane])
            fz, tan_alpha, slip, cx, cy, alpha = wheel_operating_point(
                state[0, 0, lane], state[1, 0, lane], state[2, 0, lane], state[3, 0, lane], state[4, 0, lane], trig,
                omega[w, lane], pk, w, law,
            )  # fmt: skip
            point[0, lane], point[1, lane], point[2, lane] = fz, tan_alpha, slip
            point[3, lane], point[4, lane], point[5, lane] = cx, cy, alpha
    for k in range(K):
        for lane in range(lanes):
            trig = (steer[0, w, lane], steer[1, w, lane], steer[2, w, lane], steer[3, w, lane])
            if shared:
                f_long, f_lat, moment = wheel_force_at(
                    point[0, lane], point[1, lane], point[2, lane], point[3, lane], point[4, lane], point[5, lane],
                    state[0, 0, lane], mu[w, k, lane], trig, drive[w, lane], rolling[w, lane], pk, w, law,
                )  # fmt: skip
            else:
                f_long, f_lat, moment = wheel_force(
                    state[0, k, lane], state[1, k, lane], state[2, k, lane], state[3, k, lane], state[4, k, lane],
                    mu[w, k, lane], trig, omega[w, lane], drive[w, lane], rolling[w, lane], pk, w, law,
                )  # fmt: skip
            out[0, k, lane] += f_long
            out[1, k, lane] += f_lat
            out[2, k, lane] += moment


@numba.njit(inline="always", **JIT)
def _body_forces_lanes(state, mu, steer, omega, torque, omega_dot, pk, out, lanes, shared: bool) -> None:
    """:func:`body_forces_lanes` (``shared`` False) and :func:`shared_state_forces_lanes`
    (``shared`` True; a constant in each)."""
    K = mu.shape[1]
    drive, rolling = scratch((4, lanes)), scratch((4, lanes))
    for w in range(4):
        for lane in range(lanes):
            drive[w, lane], rolling[w, lane] = wheel_drive(torque[w, lane], omega_dot[w, lane], omega[w, lane], pk)
    for i in range(3):
        for k in range(K):
            for lane in range(lanes):
                out[i, k, lane] = 0.0
    for w in range(4):
        # the Magic Formula's law (the joint estimator's) chosen outside the loops, a compile-time
        # constant in a loop of its own without branches; Dugoff's laws share one
        law = lateral_law(pk, axle_tyre(pk, w))
        if law == LATERAL_MAGIC_ELLIPSE:
            _add_wheel_lanes(
                state, mu, steer, omega, drive, rolling, pk, w, LATERAL_MAGIC_ELLIPSE, shared, out, K, lanes
            )
        else:
            _add_wheel_lanes(state, mu, steer, omega, drive, rolling, pk, w, law, shared, out, K, lanes)
    for k in range(K):
        row = 0 if shared else k
        for lane in range(lanes):
            u = state[0, row, lane]
            out[0, k, lane] = (out[0, k, lane] - pk.drag_factor * u * abs(u)) / pk.mass
            out[1, k, lane] /= pk.mass


@numba.njit(inline="always", **JIT)
def body_forces_lanes(state, mu, steer, omega, torque, omega_dot, pk: ModelKernel, out, lanes) -> None:
    """:func:`body_forces` for K evaluations of each of ``lanes`` cars, one car per SIMD lane (lane
    axis last, estimation/lanes.py): state (5, K, lanes), mu (4, K, lanes), each car's wheel table
    steer (4, 4, lanes) and its omega, torque, omega_dot (4, lanes); out (3, K, lanes). Each
    evaluation the same operations in the same order as :func:`body_forces`' (bit for bit)."""
    _body_forces_lanes(state, mu, steer, omega, torque, omega_dot, pk, out, lanes, False)


@numba.njit(inline="always", **JIT)
def shared_state_forces_lanes(state, mu, steer, omega, torque, omega_dot, pk: ModelKernel, out, lanes) -> None:
    """:func:`body_forces_lanes` for K evaluations that share each car's state (5, 1, lanes) and
    differ in mu (4, K, lanes) alone (the friction filter's points): each wheel's
    :func:`wheel_operating_point` is taken once per car. Bit for bit :func:`body_forces`' at the
    state repeated K times."""
    _body_forces_lanes(state, mu, steer, omega, torque, omega_dot, pk, out, lanes, True)


@numba.njit(inline="always", **JIT)
def dugoff_lambdas(u, v, r, ax, ay, mu, steer, omega, pk, out) -> None:
    """Each wheel's Dugoff lambda (4,) at the given state without its longitudinal slip: below 1
    its lateral force depends on mu (the lateral demand alone reaches half the grip)."""
    fz = load_tuple(ax, ay, pk)
    for w in range(4):
        tan_alpha, _, cx, cy = tyre_operating_point(u, v, r, fz[w], wheel_trig(steer, w), omega[w], pk, w)
        tyre = axle_tyre(pk, w)
        out[w] = dugoff(fz[w], 0.0, tan_alpha, peak_friction(fz[w], tyre.mu_scale * mu[w], tyre), cx, cy, u, 0.0)[2]


@numba.njit(inline="always", **JIT)
def substeps(dt: float) -> int:
    """How many model steps of at most MODEL_STEP a filter step of ``dt`` [s] integrates in."""
    return max(1, math.ceil(dt / MODEL_STEP - 1e-9))


@numba.njit(inline="always", **JIT)
def euler_step(u, v, ax, ay, r, gamma, h, pk) -> tuple[float, float, float]:
    """eq. 1-3 over a step h [s]: u + h (ax + v r), v + h (ay - u r), r + h Gamma / Iz."""
    return u + h * (ax + v * r), v + h * (ay - u * r), r + h * gamma / pk.yaw_inertia


@numba.njit(inline="always", **JIT)
def transition(points: np.ndarray, out: np.ndarray, args: tuple) -> None:
    """Discrete process model for x_s = [u, v, ax, ay, r, Gamma], paper eq. 1-3, from each row
    of points (K, 6) into the same row of out (K, 6): u+ = u + h (ax + v r),
    v+ = v + h (ay - u r), r+ = r + h Gamma / Iz (Euler at the 2 ms step); ax, ay, Gamma are
    algebraic: recomputed from the tyre model at the new state. A step dt longer than MODEL_STEP
    takes :func:`substeps` of h = dt / n each (the inputs held), so that the model integrates
    alike at every sample rate. ax, ay here are the body's specific forces (what an
    accelerometer reads without roll/pitch). ``args``: :class:`ModelInputs` (mu: the state
    filter's friction (4,))."""
    mu, steer, omega, torque, omega_dot, pk, dt = args
    K = points.shape[0]
    n = substeps(dt)
    h = dt / n
    state, mu_lanes, forces = scratch((5, K)), scratch((4, K)), scratch((3, K))
    for k in range(K):
        for i in range(6):
            out[k, i] = points[k, i]
        for w in range(4):
            mu_lanes[w, k] = mu[w]
    for _ in range(n):
        for k in range(K):
            u, v, ax, ay, r, gamma = out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4], out[k, 5]
            u_new, v_new, r_new = euler_step(u, v, ax, ay, r, gamma, h, pk)
            out[k, 0], out[k, 1], out[k, 4] = u_new, v_new, r_new
            state[0, k], state[1, k], state[2, k], state[3, k], state[4, k] = u_new, v_new, r_new, ax, ay
        body_forces(state, mu_lanes, steer, omega, torque, omega_dot, pk, forces)
        for k in range(K):
            out[k, 2], out[k, 3], out[k, 5] = forces[0, k], forces[1, k], forces[2, k]


@numba.njit(**JIT)
def transition_lanes(points, out, mu, steer, omega, torque, omega_dot, pk: ModelKernel, dt, K, lanes) -> None:
    """:func:`transition` of the K points (K, 6, lanes) of each of ``lanes`` cars (lane axis last;
    K and lanes compile-time constants: the work arrays then stay on the stack)
    into out (K, 6, lanes): each car's friction mu (4, lanes), wheel table steer (4, 4, lanes),
    omega, torque, omega_dot (4, lanes) and step dt (lanes,) [s], each car in its own
    :func:`substeps` (a car with fewer than the most holds its state through the others). Each
    point the same operations as :func:`transition`'s (bit for bit)."""
    state, mu_k, forces = scratch((5, K, lanes)), scratch((4, K, lanes)), scratch((3, K, lanes))
    steps, h = scratch((lanes,), np.int64), scratch((lanes,))
    most = 1
    for lane in range(lanes):
        steps[lane] = substeps(dt[lane])
        most = max(most, steps[lane])
        h[lane] = dt[lane] / steps[lane]
    for k in range(K):
        for i in range(6):
            for lane in range(lanes):
                out[k, i, lane] = points[k, i, lane]
        for w in range(4):
            for lane in range(lanes):
                mu_k[w, k, lane] = mu[w, lane]
    for step in range(most):
        for k in range(K):
            for lane in range(lanes):
                u, v, ax, ay = out[k, 0, lane], out[k, 1, lane], out[k, 2, lane], out[k, 3, lane]
                r, gamma = out[k, 4, lane], out[k, 5, lane]
                u_new, v_new, r_new = euler_step(u, v, ax, ay, r, gamma, h[lane], pk)
                moving = step < steps[lane]
                out[k, 0, lane] = u_new if moving else u
                out[k, 1, lane] = v_new if moving else v
                out[k, 4, lane] = r_new if moving else r
                state[0, k, lane], state[1, k, lane], state[2, k, lane] = u_new, v_new, r_new
                state[3, k, lane], state[4, k, lane] = ax, ay
        body_forces_lanes(state, mu_k, steer, omega, torque, omega_dot, pk, forces, lanes)
        for k in range(K):
            for lane in range(lanes):
                moving = step < steps[lane]
                out[k, 2, lane] = forces[0, k, lane] if moving else out[k, 2, lane]
                out[k, 3, lane] = forces[1, k, lane] if moving else out[k, 3, lane]
                out[k, 5, lane] = forces[2, k, lane] if moving else out[k, 5, lane]


# ---- Python entry points -------------------------------------------------------------------
@numba.njit(**JIT)
def _wheel_loads_flat(ax, ay, pk, out):
    for i in range(ax.shape[0]):
        wheel_loads(ax[i], ay[i], pk, out[i])


def normal_loads(ax, ay, p: ModelParams) -> np.ndarray:
    """Wheel loads (..., 4) [N] (see :func:`wheel_loads`) for arrays ax, ay (...) [m/s^2]."""
    ax, ay = np.broadcast_arrays(np.asarray(ax, dtype=np.float64), np.asarray(ay, dtype=np.float64))
    out = np.empty(ax.shape + (4,))
    _wheel_loads_flat(np.ascontiguousarray(ax).ravel(), np.ascontiguousarray(ay).ravel(), p.kernel, out.reshape(-1, 4))
    return out


def state_transition(x: np.ndarray, mu: np.ndarray, inputs: Inputs, p: ModelParams, dt: float) -> np.ndarray:
    """:func:`transition` of one state x (6,) with mu (4,) and ``inputs``; returns the new state.
    Without tyre relaxation: the lag is the joint estimator's running state (its step), which a
    single transition does not have, so the tyres' ``relaxation_length`` is not used here."""
    out = np.empty((1, 6))
    x = np.ascontiguousarray(x, dtype=np.float64)
    mu, delta, omega, torque, omega_dot = (np.ascontiguousarray(q, dtype=np.float64) for q in (mu, *inputs))
    for name, value, shape in (
        ("x", x, (6,)),
        ("mu", mu, (4,)),
        *zip(Inputs._fields, (delta, omega, torque, omega_dot), [(4,)] * 4),
    ):
        if value.shape != shape:  # (the kernel indexes without bounds checks)
            raise ValueError(f"{name} must have shape {shape}, got {value.shape}: {value!r}")
    transition(x.reshape(1, 6), out, ModelInputs(mu, steer_trig(delta), omega, torque, omega_dot, p.kernel, float(dt)))
    return out[0]

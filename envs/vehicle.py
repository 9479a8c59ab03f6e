"""Truth plant of the 4WID-4WS car: parameters, state layout and the compiled dynamics.

One implementation of the physics, a numba kernel over a leading batch axis; the single
vehicle is a batch of one. The kernel integrates blocks of up to :data:`BLOCK` cars (blocks on
both cores for batches of :data:`PARALLEL_MIN_BATCH` or more); inside a block the per-wheel
work (loads, slips, Magic Formula, wheel and motor dynamics) runs in loops over wheel lanes
that LLVM vectorises, using the polynomial elementary functions of :mod:`fourwis.core.vecmath`.
Each lane's arithmetic depends only on its own car, so a car's trajectory is the same in
any batch (tested to 1e-12). Higher fidelity than, and different from, the
estimator's 3-DOF Dugoff model (no "inverse crime"):

* body: longitudinal u, lateral v, yaw r (ISO 8855) plus global pose X, Y, psi;
* four wheel-spin DOFs, ``J omega_dot = T - R Fx - M_roll``;
* tyres: PAC2002 Magic Formula, combined slip, load dependent, peaks scaled by the
  friction of the road under each wheel (:mod:`envs.tyre`);
* tyre transient slip (relaxation lengths, Pacejka, *Tire and Vehicle Dynamics*, 3rd ed.,
  sec. 7.2): the slips are states, ``sigma dkappa'/dt = (R omega - v_cx) - |v_cx| kappa'``
  and likewise laterally. This is the physics of a tyre carcass, and it also handles the
  stiff wheel spin at low speed: the textbook quasi-static slip ``(R omega - u)/u`` puts an
  eigenvalue ``-Kx R^2 / (J u)`` in the wheel dynamics, beyond any explicit step of 2 ms; with
  relaxation and MF-Tyre's low-speed damping (``VXLOW``) fixed-step RK4 at 2 ms is stable from
  standstill to 45 m/s (tests/test_vehicle.py checks the eigenvalues against RK4's stability
  region; docs/decisions/0003-fixed-2ms-rk4-and-step-limits.md);
* normal loads with longitudinal and lateral load transfer (h = 0.54 m) driven by the
  body accelerations through a first-order lag that stands for pitch/roll dynamics
  (and removes the algebraic loop between loads and forces); the lateral transfer is
  split between the axles in proportion to their static loads; beyond the transfer that
  lifts an inner wheel (track / 2h, 1.31 g at steady speed on this car; roll-over is not modelled)
  that wheel is held at 1 N and the outer one carries the rest of its axle's load (an axle
  lifting as a whole, pitch-over beyond ~2 g of braking on this car, is not modelled);
* aerodynamic drag (1/2) rho Cd A u|u| along the body's x axis, acting at ground level (it
  neither pitches the car nor pushes it sideways when it slides: at 100 km/h the pitch
  moment left out shifts ~90 N, 2% of an axle's load, from front to rear);
* four in-wheel motors: first-order torque lag, peak torque and peak power limits;
* four hydraulic friction brakes: calliper pressure follows its command (clipped to
  [0, ``brake_max_pressure``]) through a first-order lag and a rate limit; the pressure times
  ``brake_gain`` is the largest friction torque the brake can exert. The friction torque opposes
  the wheel's spin and can lock it: it is whatever torque would bring the wheel to rest within
  ``brake_lock_time_constant`` (the other torques cancelled), limited to that capacity. Spinning,
  the limit binds and the brake exerts its full capacity against the spin (sliding friction); near
  standstill it holds the wheel (static friction) with a decay of 1 / ``brake_lock_time_constant``
  that RK4 integrates like any other lag, so a locked wheel neither chatters nor flips its torque's
  sign from one substep to the next (docs/decisions/0038-friction-brakes-and-wheel-lock.md);
* front and rear steering servos with angle and rate limits; the paper's proportional
  4WS law (eq. 20) as a switchable rear-steer feed-forward.

The paper's car has a = b and equal tyres, so it is neutral-steer: its linear understeer
gradient ``K = m/L (b/C_f - a/C_r)`` is zero, the steady-state yaw-rate gain ``u/L`` grows
without bound with speed instead of saturating at the characteristic speed, and near the
limit the rear axle (which carries the same load as the front) saturates as early as the
front, so the uncontrolled car tends to oversteer and spin in aggressive manoeuvres.

Integration: classical RK4 at a fixed step (2 ms by default, the paper's sample time);
the road friction under each wheel is sampled at the start of each step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np

from fourwis.control.reference import eq20_gain  # the 4WS law, written once (control)
from fourwis.core import vecmath
from fourwis.core.checks import is_integer, is_number
from fourwis.core.constants import GRAVITY
from fourwis.core.kernels import JIT, borrowed, run_parallel
from fourwis.core.vecmath import LANE_MULTIPLE
from fourwis.envs.layout import (
    A_ALPHA,
    A_AX,
    A_AY,
    A_BRAKE_TORQUE,
    A_FX,
    A_FY,
    A_FZ,
    A_KAPPA,
    A_MU,
    A_USAGE,
    C_BRAKE,
    C_DELTA_F,
    C_DELTA_R,
    C_TORQUE,
    MU_MAX,
    NAUX,
    NU,
    NX,
    S_AX,
    S_AY,
    S_BRAKE,
    S_DEFL_X,
    S_DEFL_Y,
    S_DELTA_F,
    S_DELTA_R,
    S_OMEGA,
    S_PSI,
    S_R,
    S_TORQUE,
    S_U,
    S_V,
    S_X,
    S_Y,
)
from fourwis.envs.road import RoadTables, road_tables
from fourwis.envs.tyre import TyreCoefficients, TyreParams, combined_forces, relaxation_lengths

#: VehicleParams fields that may be 0 (switching off a resistance or the low-speed damping);
#: every other number must be > 0
MAY_BE_ZERO = ("rolling_resistance", "drag_area", "air_density", "low_speed_damping")
#: the plant's first-order lags: motors, steering servos, load transfer, brake pressure, a locked
#: wheel's hold
LAG_FIELDS = (
    "motor_time_constant",
    "steer_time_constant",
    "load_transfer_time_constant",
    "brake_time_constant",
    "brake_lock_time_constant",
)


@dataclass(frozen=True)
class VehicleParams:
    """Vehicle parameters [SI]. Paper Table 1 where it gives them; sources for the rest."""

    mass: float = 830.0  #: total mass [kg] (paper Table 1)
    yaw_inertia: float = 1110.0  #: yaw moment of inertia Iz [kg m^2] (Table 1)
    cg_to_front: float = 1.17  #: a, CG to front axle [m] (Table 1)
    cg_to_rear: float = 1.17  #: b, CG to rear axle [m] (Table 1; L = 2.34 m)
    track_front: float = 1.416  #: front track [m] (Table 1)
    track_rear: float = 1.416  #: rear track [m] (Table 1)
    wheel_radius: float = 0.278  #: effective rolling radius R [m] (Table 1)
    cg_height: float = 0.54  #: CG height h [m] (Table 1)
    #: wheel + tyre + in-wheel motor rotor spin inertia [kg m^2]: ~0.7 for a 14" wheel
    #: and tyre (Genta & Morello, The Automotive Chassis, vol. 1) plus ~0.3 for an
    #: outer-rotor in-wheel motor.
    wheel_inertia: float = 1.0
    steering_ratio: float = 16.0  #: steering-wheel to road-wheel angle ratio [-] (typical 14-18)
    #: motor peak torque [N m]: the grip-limited torque on dry road at the static load is
    #: mu*Fz*R ~ 566 N m per wheel for this car, the motors are sized just above it. Under hard
    #: braking the front wheels carry more (~750 N m at 0.8 g), so with the power limit the
    #: motors brake the car at most ~0.80 g on a dry road below 10 m/s, 0.57 g at 80 km/h and
    #: 0.47 g at 100 km/h (on mu 0.5, ~mu g up to ~80 km/h); beyond that the friction brakes work.
    motor_peak_torque: float = 600.0
    motor_peak_power: float = 25.0e3  #: per-motor peak power [W] (caps torque above ~42 rad/s)
    motor_time_constant: float = 0.010  #: torque response lag [s] (in-wheel motors: 5-20 ms)
    max_front_steer: float = 0.60  #: front road-wheel angle limit [rad] (~34 deg)
    #: front steer rate limit [rad/s]: 1.6 rad/s at the road wheel is ~1,470 deg/s at the
    #: steering wheel, above the ~1,320 deg/s peak of a 300 deg, 0.7 Hz sine-with-dwell robot.
    front_steer_rate: float = 1.6
    max_rear_steer: float = math.radians(5.0)  #: rear road-wheel angle limit [rad] (active rear steer: 3-10 deg)
    rear_steer_rate: float = 0.5  #: rear steer rate limit [rad/s]
    steer_time_constant: float = 0.010  #: steering servo position lag [s]
    #: friction brake torque per calliper pressure [N m/Pa]: 2 pads x pad friction 0.38 x piston
    #: area 2.29e-3 m^2 (54 mm piston) x effective radius 0.105 m = 1.83e-4 N m/Pa (18 N m/bar),
    #: a small car's floating calliper (Breuer & Bill, Brake Technology Handbook, SAE 2008: pad
    #: friction 0.35-0.45, 14-15" discs)
    brake_gain: float = 1.83e-4
    #: largest calliper pressure [Pa] (120 bar; passenger hydraulics work up to ~100-180 bar): with
    #: brake_gain 2,200 N m per wheel, above the ~830 N m that locks a front wheel at 1 g on dry road
    brake_max_pressure: float = 1.2e7
    #: calliper pressure lag [s] and rate limit [Pa/s] (1,500 bar/s): an ESC/ABS hydraulic unit's
    #: valves build and dump pressure at ~1,000-2,000 bar/s (Bosch, Automotive Handbook, ESP)
    brake_time_constant: float = 0.020
    brake_pressure_rate: float = 1.5e8
    #: time [s] in which a brake that can hold a wheel brings it to rest (the stick phase of the
    #: brake's Coulomb friction, regularised so that RK4 integrates it: 2.5 steps of 2 ms; a wheel
    #: locks from 1 rad/s within ~15 ms)
    brake_lock_time_constant: float = 0.005
    #: rolling resistance coefficient [-] (QSY1 of the tyre's .tir file)
    rolling_resistance: float = 0.01
    drag_area: float = 0.60  #: Cd * A [m^2] (Cd 0.32, A 1.9 m^2: small hatchback)
    air_density: float = 1.206  #: [kg/m^3] (ISO 2533 at 20 deg C)
    load_transfer_time_constant: float = 0.05  #: lag of load transfer behind accelerations [s] (pitch/roll)
    #: low-speed damping of tyre slip [N s/m] at static load, faded out (cosine) by ``low_speed_fade``
    #: (MF-Tyre's VXLOW idea)
    low_speed_damping: float = 1000.0
    low_speed_fade: float = 1.0  #: speed at which the low-speed damping vanishes [m/s] (VXLOW of the .tir)
    min_relaxation_length: float = 0.1  #: floor for the load-dependent relaxation lengths [m]
    width: float = 1.60  #: overall body width [m] (track + tyre width), for cone courses
    front_overhang: float = 0.60  #: front axle to front bumper [m]
    rear_overhang: float = 0.50  #: rear axle to rear bumper [m]
    rear_steer_feedforward: bool = False  #: apply the paper's 4WS law (eq. 20) on top of the rear command
    tyre: TyreParams = field(default_factory=TyreParams)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "tyre":
                if not isinstance(value, TyreParams):
                    raise ValueError(f"VehicleParams.tyre must be an envs.tyre.TyreParams, got {value!r}")
                continue
            if f.name == "rear_steer_feedforward":
                if not isinstance(value, (bool, np.bool_)):
                    raise ValueError(f"VehicleParams.rear_steer_feedforward must be True or False, got {value!r}")
                continue
            if f.name in MAY_BE_ZERO:
                if not (is_number(value) and math.isfinite(value) and value >= 0.0):
                    raise ValueError(f"VehicleParams.{f.name} must be a finite number >= 0, got {value!r}")
            elif not (is_number(value) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"VehicleParams.{f.name} must be a finite number > 0, got {value!r}")
        for name in ("max_front_steer", "max_rear_steer"):  # the steering geometry holds below 90 deg
            if not getattr(self, name) < 0.5 * math.pi:
                raise ValueError(f"VehicleParams.{name} must be below pi/2 rad (90 deg), got {getattr(self, name)!r}")

    def replace(self, **overrides) -> VehicleParams:
        """Copy with ``overrides``; unknown names raise ValueError."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown VehicleParams field(s) {unknown}; known: {sorted(known)}")
        return replace(self, **overrides)

    @property
    def wheelbase(self) -> float:
        """L = a + b [m]."""
        return self.cg_to_front + self.cg_to_rear

    @property
    def static_wheel_loads(self) -> np.ndarray:
        """Static normal loads (4,) [N], order FL, FR, RL, RR."""
        front = self.mass * GRAVITY * self.cg_to_rear / (2.0 * self.wheelbase)
        rear = self.mass * GRAVITY * self.cg_to_front / (2.0 * self.wheelbase)
        return np.array([front, front, rear, rear])

    @cached_property
    def static_relaxation_lengths(self) -> tuple[float, float]:
        """The tyre's relaxation lengths (sigma_kappa, sigma_alpha) [m] at the reference wheel load."""
        sig_k, sig_a = relaxation_lengths(self.tyre.kernel, self.reference_wheel_load)
        return float(sig_k), float(sig_a)

    @property
    def reference_wheel_load(self) -> float:
        """Mean static wheel load [N]: the load at which road mu equals the tyre's peak."""
        return self.mass * GRAVITY / 4.0

    @cached_property
    def axle_cornering_stiffness(self) -> tuple[float, float]:
        """(C_f, C_r): linear cornering stiffness of each axle at static load [N/rad]."""
        fz = self.static_wheel_loads
        c = self.tyre.cornering_stiffness(fz)
        return float(c[0] + c[1]), float(c[2] + c[3])

    @property
    def brake_peak_torque(self) -> float:
        """Largest friction brake torque per wheel [N m]: brake_gain x brake_max_pressure."""
        return self.brake_gain * self.brake_max_pressure

    @property
    def front_extent(self) -> float:
        """Body length ahead of the CG [m] (to the front bumper)."""
        return self.cg_to_front + self.front_overhang

    @property
    def rear_extent(self) -> float:
        """Body length behind the CG [m] (to the rear bumper)."""
        return self.cg_to_rear + self.rear_overhang

    @cached_property
    def fastest_lag(self) -> tuple[str, float]:
        """(field name, time constant [s]) of the shortest of the plant's first-order lags."""
        name = min(LAG_FIELDS, key=lambda f: getattr(self, f))
        return name, float(getattr(self, name))

    @cached_property
    def contact_point_reach(self) -> float:
        """Largest distance [m] of a contact point from the CG (in the body frame)."""
        return float(np.max(np.hypot(*self.wheel_positions.T)))

    @cached_property
    def wheel_positions(self) -> np.ndarray:
        """Contact-point positions (4, 2) [m] in the body frame, (x forward, y left); read-only."""
        a, b = self.cg_to_front, self.cg_to_rear
        tf, tr = self.track_front / 2.0, self.track_rear / 2.0
        positions = np.array([[a, tf], [a, -tf], [-b, tr], [-b, -tr]])
        positions.flags.writeable = False
        return positions

    @cached_property
    def kernel(self) -> Plant:
        """The plant as its compiled kernels take it: these parameters and the tyre's coefficients."""
        mux, muy = self.tyre.peak_friction(self.reference_wheel_load)
        c_f, c_r = self.axle_cornering_stiffness
        values = {
            "mass": self.mass,
            "yaw_inertia": self.yaw_inertia,
            "cg_to_front": self.cg_to_front,
            "cg_to_rear": self.cg_to_rear,
            "track_front": self.track_front,
            "track_rear": self.track_rear,
            "wheel_radius": self.wheel_radius,
            "cg_height": self.cg_height,
            "wheel_inertia": self.wheel_inertia,
            "motor_peak_torque": self.motor_peak_torque,
            "motor_peak_power": self.motor_peak_power,
            "motor_time_constant": self.motor_time_constant,
            "max_front_steer": self.max_front_steer,
            "front_steer_rate": self.front_steer_rate,
            "max_rear_steer": self.max_rear_steer,
            "rear_steer_rate": self.rear_steer_rate,
            "steer_time_constant": self.steer_time_constant,
            "brake_gain": self.brake_gain,
            "brake_max_pressure": self.brake_max_pressure,
            "brake_time_constant": self.brake_time_constant,
            "brake_pressure_rate": self.brake_pressure_rate,
            "brake_lock_time_constant": self.brake_lock_time_constant,
            "rolling_resistance": self.rolling_resistance,
            "drag_area": self.drag_area,
            "air_density": self.air_density,
            "load_transfer_time_constant": self.load_transfer_time_constant,
            "low_speed_damping": self.low_speed_damping,
            "low_speed_fade": self.low_speed_fade,
            "min_relaxation_length": self.min_relaxation_length,
            "rear_steer_feedforward": float(self.rear_steer_feedforward),
            "inv_mux_ref": 1.0 / float(mux),
            "inv_muy_ref": 1.0 / float(muy),
            "axle_stiffness_front": c_f,
            "axle_stiffness_rear": c_r,
            "reference_wheel_load": self.reference_wheel_load,
        }
        return Plant(PlantParams(*(float(values[name]) for name in PARAM_NAMES)), self.tyre.kernel)


PARAM_NAMES = (
    "mass",
    "yaw_inertia",
    "cg_to_front",
    "cg_to_rear",
    "track_front",
    "track_rear",
    "wheel_radius",
    "cg_height",
    "wheel_inertia",
    "motor_peak_torque",
    "motor_peak_power",
    "motor_time_constant",
    "max_front_steer",
    "front_steer_rate",
    "max_rear_steer",
    "rear_steer_rate",
    "steer_time_constant",
    "brake_gain",
    "brake_max_pressure",
    "brake_time_constant",
    "brake_pressure_rate",
    "brake_lock_time_constant",
    "rolling_resistance",
    "drag_area",
    "air_density",
    "load_transfer_time_constant",
    "low_speed_damping",
    "low_speed_fade",
    "min_relaxation_length",
    "rear_steer_feedforward",
    "inv_mux_ref",
    "inv_muy_ref",
    "axle_stiffness_front",
    "axle_stiffness_rear",
    "reference_wheel_load",
)
#: :class:`VehicleParams` as the compiled plant reads it (:attr:`VehicleParams.kernel`): the
#: PARAM_NAMES (floats; rear_steer_feedforward 1 / 0, the reference friction as inverses)
PlantParams = NamedTuple("PlantParams", [(name, float) for name in PARAM_NAMES])


class Plant(NamedTuple):
    """A car as the compiled plant takes it (:attr:`VehicleParams.kernel`)."""

    params: PlantParams
    tyre: TyreCoefficients


# Lane rows of the wheel-lane scratch arrays. Lane ``4 c + i`` is wheel ``i`` of car ``c`` of a
# block; inputs are gathered per car, the tyre work runs in one branch-free loop over lanes
# that LLVM vectorises (:mod:`fourwis.core.vecmath`), outputs are summed back per car.
# The scratch is one flat array of rows of LANES doubles, row k at [k LANES, (k + 1) LANES):
# with a compile-time row stride LLVM proves the rows independent and vectorises the loop.
BLOCK = 16  #: cars per block
LANES = 4 * BLOCK  #: wheel lanes per block: 64, eight AVX-512 registers' worth
(
    L_U,
    L_V,
    L_R,
    L_PSI,
    L_AX,
    L_AY,
    L_DELTA,
    L_OMEGA,
    L_DEFL_X,
    L_DEFL_Y,
    L_MU,
    L_TORQUE,
    L_TCMD,
    L_BRAKE,
    L_BCMD,
    L_WX,
    L_WY,
    L_FZ_STATIC,
    L_FZ_PER_AX,
    L_FZ_PER_AY,
    O_DDEFL_X,
    O_DDEFL_Y,
    O_DOMEGA,
    O_DTORQUE,
    O_DBRAKE,
    O_BRAKE_TORQUE,
    O_FXB,
    O_FYB,
    O_MZ,
    O_COS_PSI,
    O_SIN_PSI,
    O_FZ,
    O_FX,
    O_FY,
    O_KAPPA,
    O_ALPHA,
    O_USAGE,
    O_CAR_AX,
    O_CAR_AY,
    O_COS_DELTA,
    O_SIN_DELTA,
    O_VCX,
    O_VCY,
    O_TAN_ALPHA,
    O_SCALE_X,
    O_SCALE_Y,
) = (k * LANES for k in range(46))
N_LANE_ROWS = 46  # L_*: inputs gathered per car; O_*: outputs (O_CAR_AX/AY: the car's accelerations, in its first lane)


@numba.njit(**JIT)
def _block_lanes(n_cars: int) -> int:
    """Lane count for ``n_cars`` wheels x 4, padded to a multiple of vecmath.LANE_MULTIPLE."""
    return -(-4 * n_cars // LANE_MULTIPLE) * LANE_MULTIPLE


@numba.njit(**JIT)
def _wheel_scratch(p, n_cars: int) -> np.ndarray:
    """Lane scratch (N_LANE_ROWS * LANES,) for a block of ``n_cars``, its per-wheel constants
    filled: contact position (the kernel's one copy of the wheel geometry), static load, load
    transfer per unit acceleration."""
    lanes = np.empty(N_LANE_ROWS * LANES)
    m, a, b, h = p.mass, p.cg_to_front, p.cg_to_rear, p.cg_height
    wheelbase = a + b
    for lane in range(_block_lanes(n_cars)):
        i = lane % 4
        front = i < 2
        side = -1.0 if i % 2 == 0 else 1.0  # left wheels unload in a left turn (ay > 0)
        lanes[L_WX + lane] = a if front else -b
        lanes[L_WY + lane] = -0.5 * side * (p.track_front if front else p.track_rear)
        lanes[L_FZ_STATIC + lane] = m * GRAVITY * (b if front else a) / (2.0 * wheelbase)
        lanes[L_FZ_PER_AX + lane] = (-1.0 if front else 1.0) * m * h / (2.0 * wheelbase)
        lanes[L_FZ_PER_AY + lane] = side * m * h * (b / p.track_front if front else a / p.track_rear) / wheelbase
    return lanes


@numba.njit(**JIT)
def _slip_lanes(p, tp, lanes, n_lanes):
    """Per lane: normal load, contact-centre velocities and the transient slips."""
    sigma_min, inv_mux, inv_muy = p.min_relaxation_length, p.inv_mux_ref, p.inv_muy_ref
    for lane in range(n_lanes):
        u = lanes[L_U + lane]
        v = lanes[L_V + lane]
        r = lanes[L_R + lane]
        delta = lanes[L_DELTA + lane]
        # quasi-static load transfer; a lateral transfer beyond the half-axle load lifts the inner
        # wheel (held at 1 N), the outer one taking the rest, so the axle keeps its load
        half_axle = lanes[L_FZ_STATIC + lane] + lanes[L_FZ_PER_AX + lane] * lanes[L_AX + lane]
        room = max(half_axle - 1.0, 0.0)
        transfer = min(max(lanes[L_FZ_PER_AY + lane] * lanes[L_AY + lane], -room), room)
        fz = max(half_axle + transfer, 1.0)
        sd, cd = vecmath.sin_cos(delta)
        vxb = u - r * lanes[L_WY + lane]
        vyb = v + r * lanes[L_WX + lane]
        sig_k, sig_a = relaxation_lengths(tp, fz)
        lanes[O_FZ + lane] = fz
        lanes[O_COS_DELTA + lane] = cd
        lanes[O_SIN_DELTA + lane] = sd
        lanes[O_VCX + lane] = cd * vxb + sd * vyb
        lanes[O_VCY + lane] = -sd * vxb + cd * vyb
        lanes[O_KAPPA + lane] = lanes[L_DEFL_X + lane] / max(sig_k, sigma_min)
        lanes[O_TAN_ALPHA + lane] = lanes[L_DEFL_Y + lane] / max(sig_a, sigma_min)
        lanes[O_SCALE_X + lane] = lanes[L_MU + lane] * inv_mux
        lanes[O_SCALE_Y + lane] = lanes[L_MU + lane] * inv_muy


@numba.njit(**JIT)
def _wheel_lanes(p, lanes, n_lanes):
    """Per lane, after the tyre forces: low-speed damping, slip, wheel-spin, motor and brake
    derivatives, body-frame forces and yaw moment, diagnostics."""
    # parameters read before the loop: a load inside a conditional would stop if-conversion
    rw, jw, v_low, damping_per_load = (
        p.wheel_radius,
        p.wheel_inertia,
        p.low_speed_fade,
        p.low_speed_damping / p.reference_wheel_load,
    )
    rolling, t_max, p_max, tau_m = p.rolling_resistance, p.motor_peak_torque, p.motor_peak_power, p.motor_time_constant
    gain, pb_max, tau_b, pb_rate, tau_lock = (
        p.brake_gain,
        p.brake_max_pressure,
        p.brake_time_constant,
        p.brake_pressure_rate,
        p.brake_lock_time_constant,
    )
    for lane in range(n_lanes):
        u = lanes[L_U + lane]
        v = lanes[L_V + lane]
        omega = lanes[L_OMEGA + lane]
        fz = lanes[O_FZ + lane]
        vcx = lanes[O_VCX + lane]
        vcy = lanes[O_VCY + lane]
        cd = lanes[O_COS_DELTA + lane]
        sd = lanes[O_SIN_DELTA + lane]
        kappa = lanes[O_KAPPA + lane]
        tan_alpha = lanes[O_TAN_ALPHA + lane]
        slip_velocity = rw * omega - vcx
        # MF-Tyre style low-speed damping, faded out by a half cosine below v_low
        speed = vecmath.sqrt(u * u + v * v)
        fade = 0.5 * (1.0 + vecmath.cos(math.pi * speed / v_low)) if speed < v_low else 0.0
        damping = damping_per_load * fade * fz
        fxw = lanes[O_FX + lane] + damping * slip_velocity
        fyw = lanes[O_FY + lane] - damping * vcy
        lanes[O_DDEFL_X + lane] = slip_velocity - abs(vcx) * kappa
        lanes[O_DDEFL_Y + lane] = vcy - abs(vcx) * tan_alpha
        # wheel spin: motor torque, tyre force, rolling resistance (smoothed sign), brake friction
        wheel_speed = rw * omega
        m_roll = rw * rolling * fz * wheel_speed / vecmath.sqrt(wheel_speed * wheel_speed + 0.0025)
        torque = lanes[L_TORQUE + lane]
        unbraked = torque - rw * fxw - m_roll
        # the brake's friction torque (positive against forward spin): what stops the wheel within
        # tau_lock, up to the calliper's capacity (module docstring)
        capacity = gain * max(lanes[L_BRAKE + lane], 0.0)
        brake = min(max(unbraked + jw * omega / tau_lock, -capacity), capacity)
        lanes[O_DOMEGA + lane] = (unbraked - brake) / jw
        lanes[O_BRAKE_TORQUE + lane] = brake
        pressure_cmd = min(max(lanes[L_BCMD + lane], 0.0), pb_max)
        pressure_rate = (pressure_cmd - lanes[L_BRAKE + lane]) / tau_b
        lanes[O_DBRAKE + lane] = min(max(pressure_rate, -pb_rate), pb_rate)
        # motor: first-order lag towards the torque/power-limited command
        t_lim = min(t_max, p_max / max(abs(omega), 1e-6))
        t_cmd = min(max(lanes[L_TCMD + lane], -t_lim), t_lim)
        lanes[O_DTORQUE + lane] = (t_cmd - torque) / tau_m
        fxb = cd * fxw - sd * fyw
        fyb = sd * fxw + cd * fyw
        lanes[O_FXB + lane] = fxb
        lanes[O_FYB + lane] = fyb
        lanes[O_MZ + lane] = lanes[L_WX + lane] * fyb - lanes[L_WY + lane] * fxb
        lanes[O_SIN_PSI + lane], lanes[O_COS_PSI + lane] = vecmath.sin_cos(lanes[L_PSI + lane])
        lanes[O_FX + lane] = fxw
        lanes[O_FY + lane] = fyw
        lanes[O_ALPHA + lane] = vecmath.atan(tan_alpha)
        lanes[O_USAGE + lane] = vecmath.sqrt(fxw * fxw + fyw * fyw) / (lanes[L_MU + lane] * fz)


@numba.njit(**JIT)
def _tyre_lanes(p, tp, lanes, n_lanes):
    """Wheel kinematics, loads, transient slip, tyre forces and wheel/motor dynamics per lane:
    three loops over lanes, each branch-free and call-free, so LLVM vectorises them."""
    _slip_lanes(p, tp, lanes, n_lanes)
    combined_forces(
        tp,
        lanes[O_FZ : O_FZ + n_lanes],
        lanes[O_KAPPA : O_KAPPA + n_lanes],
        lanes[O_TAN_ALPHA : O_TAN_ALPHA + n_lanes],
        lanes[O_SCALE_X : O_SCALE_X + n_lanes],
        lanes[O_SCALE_Y : O_SCALE_Y + n_lanes],
        lanes[O_FX : O_FX + n_lanes],
        lanes[O_FY : O_FY + n_lanes],
    )
    _wheel_lanes(p, lanes, n_lanes)


@numba.njit(**JIT)
def _derivative_block(x, ctrl, mu, p, tp, dx, lanes):
    """State derivatives ``dx (n, NX)`` of a block of ``n <= BLOCK`` cars ``x (n, NX)``,
    ``ctrl (n, NU)``, ``mu (n, 4)``. ``lanes`` is the scratch from _wheel_scratch; afterwards its O_* rows hold the
    per-wheel
    diagnostics."""
    n_cars = x.shape[0]
    n_lanes = _block_lanes(n_cars)
    for lane in range(n_lanes):
        c = min(lane // 4, n_cars - 1)  # padding lanes repeat the last car; their results are unused
        i = lane % 4
        lanes[L_U + lane] = x[c, S_U]
        lanes[L_V + lane] = x[c, S_V]
        lanes[L_R + lane] = x[c, S_R]
        lanes[L_PSI + lane] = x[c, S_PSI]
        lanes[L_AX + lane] = x[c, S_AX]
        lanes[L_AY + lane] = x[c, S_AY]
        lanes[L_DELTA + lane] = x[c, S_DELTA_F + i // 2]
        lanes[L_OMEGA + lane] = x[c, S_OMEGA + i]
        lanes[L_DEFL_X + lane] = x[c, S_DEFL_X + i]
        lanes[L_DEFL_Y + lane] = x[c, S_DEFL_Y + i]
        lanes[L_MU + lane] = mu[c, i]
        lanes[L_TORQUE + lane] = x[c, S_TORQUE + i]
        lanes[L_TCMD + lane] = ctrl[c, C_TORQUE + i]
        lanes[L_BRAKE + lane] = x[c, S_BRAKE + i]
        lanes[L_BCMD + lane] = ctrl[c, C_BRAKE + i]
    _tyre_lanes(p, tp, lanes, n_lanes)
    m, iz, a, b = p.mass, p.yaw_inertia, p.cg_to_front, p.cg_to_rear
    for c in range(n_cars):
        fx_sum = 0.0
        fy_sum = 0.0
        mz_sum = 0.0
        for i in range(4):
            lane = 4 * c + i
            fx_sum += lanes[O_FXB + lane]
            fy_sum += lanes[O_FYB + lane]
            mz_sum += lanes[O_MZ + lane]
            dx[c, S_DEFL_X + i] = lanes[O_DDEFL_X + lane]
            dx[c, S_DEFL_Y + i] = lanes[O_DDEFL_Y + lane]
            dx[c, S_OMEGA + i] = lanes[O_DOMEGA + lane]
            dx[c, S_TORQUE + i] = lanes[O_DTORQUE + lane]
            dx[c, S_BRAKE + i] = lanes[O_DBRAKE + lane]
        u, v, r = x[c, S_U], x[c, S_V], x[c, S_R]
        drag = 0.5 * p.air_density * p.drag_area * u * abs(u)
        ax = (fx_sum - drag) / m
        ay = fy_sum / m
        lanes[O_CAR_AX + 4 * c] = ax
        lanes[O_CAR_AY + 4 * c] = ay
        cos_psi, sin_psi = lanes[O_COS_PSI + 4 * c], lanes[O_SIN_PSI + 4 * c]
        dx[c, S_X] = u * cos_psi - v * sin_psi
        dx[c, S_Y] = u * sin_psi + v * cos_psi
        dx[c, S_PSI] = r
        dx[c, S_U] = ax + v * r
        dx[c, S_V] = ay - u * r
        dx[c, S_R] = mz_sum / iz
        dx[c, S_AX] = (ax - x[c, S_AX]) / p.load_transfer_time_constant
        dx[c, S_AY] = (ay - x[c, S_AY]) / p.load_transfer_time_constant
        # steering servos with angle and rate limits; optional 4WS feed-forward (paper eq. 20)
        delta_f, delta_r = x[c, S_DELTA_F], x[c, S_DELTA_R]
        target_f = min(max(ctrl[c, C_DELTA_F], -p.max_front_steer), p.max_front_steer)
        rate_f = (target_f - delta_f) / p.steer_time_constant
        dx[c, S_DELTA_F] = min(max(rate_f, -p.front_steer_rate), p.front_steer_rate)
        target_r = ctrl[c, C_DELTA_R]
        if p.rear_steer_feedforward > 0.0:
            target_r += eq20_gain(u, a, b, m, p.axle_stiffness_front, p.axle_stiffness_rear) * delta_f
        target_r = min(max(target_r, -p.max_rear_steer), p.max_rear_steer)
        rate_r = (target_r - delta_r) / p.steer_time_constant
        dx[c, S_DELTA_R] = min(max(rate_r, -p.rear_steer_rate), p.rear_steer_rate)


@numba.njit(**JIT)
def _fill_aux(mu, lanes, aux):
    """Diagnostics (n, NAUX) of a block from the derivative just evaluated."""
    for c in range(aux.shape[0]):
        aux[c, A_AX] = lanes[O_CAR_AX + 4 * c]
        aux[c, A_AY] = lanes[O_CAR_AY + 4 * c]
        for i in range(4):
            lane = 4 * c + i
            aux[c, A_FZ + i] = lanes[O_FZ + lane]
            aux[c, A_FX + i] = lanes[O_FX + lane]
            aux[c, A_FY + i] = lanes[O_FY + lane]
            aux[c, A_KAPPA + i] = lanes[O_KAPPA + lane]
            aux[c, A_ALPHA + i] = lanes[O_ALPHA + lane]
            aux[c, A_MU + i] = mu[c, i]
            aux[c, A_USAGE + i] = lanes[O_USAGE + lane]
            aux[c, A_BRAKE_TORQUE + i] = lanes[O_BRAKE_TORQUE + lane]


@numba.njit(**JIT)
def _wheel_mu(x, lanes, base_mu, rects, mu):
    """Road friction under each wheel from a rectangle table (later rows win); the contact
    positions come from the scratch ``lanes`` of _wheel_scratch."""
    c, s = math.cos(x[S_PSI]), math.sin(x[S_PSI])
    for i in range(4):
        xi, yi = lanes[L_WX + i], lanes[L_WY + i]
        gx = x[S_X] + c * xi - s * yi
        gy = x[S_Y] + s * xi + c * yi
        value = base_mu
        for k in range(rects.shape[0]):
            if rects[k, 4] > 0.0 and rects[k, 0] <= gx < rects[k, 1] and rects[k, 2] <= gy < rects[k, 3]:
                value = rects[k, 4]
        mu[i] = value


@numba.njit(**JIT)
def advance_block(x, ctrl, plant: Plant, road: RoadTables, dt, n_steps, aux, status):
    """RK4 over ``n_steps`` steps of ``dt`` [s] for a block of cars ``x (n, NX)``, in place, with
    controls ``ctrl`` (n, NU) held, on the roads ``road`` (n rows); the diagnostics at the
    returned state into ``aux`` (n, NAUX).

    Sets ``status`` (n,) to 1 (non-finite control), 2 (friction outside (0, MU_MAX]) or 3
    (state turned non-finite) for the first failing car and stops the block.
    """
    p, tp = plant
    base_mu, rects, mu_given, use_map = road
    n_cars = x.shape[0]
    for c in range(n_cars):
        for j in range(NU):
            if not math.isfinite(ctrl[c, j]):
                status[c] = 1
                return
    lanes = _wheel_scratch(p, n_cars)
    k1 = np.empty((n_cars, NX))
    k2 = np.empty((n_cars, NX))
    k3 = np.empty((n_cars, NX))
    k4 = np.empty((n_cars, NX))
    tmp = np.empty((n_cars, NX))
    mu = np.empty((n_cars, 4))
    for step_index in range(n_steps + 1):
        for c in range(n_cars):
            if use_map:
                _wheel_mu(x[c], lanes, base_mu[c], rects[c], mu[c])
            else:
                mu[c, :] = mu_given[c]
            for i in range(4):
                if not (0.0 < mu[c, i] <= MU_MAX):
                    status[c] = 2
                    return
        _derivative_block(x, ctrl, mu, p, tp, k1, lanes)
        if step_index == n_steps:  # diagnostics at the returned state
            _fill_aux(mu, lanes, aux)
            return
        for c in range(n_cars):
            for j in range(NX):
                tmp[c, j] = x[c, j] + 0.5 * dt * k1[c, j]
        _derivative_block(tmp, ctrl, mu, p, tp, k2, lanes)
        for c in range(n_cars):
            for j in range(NX):
                tmp[c, j] = x[c, j] + 0.5 * dt * k2[c, j]
        _derivative_block(tmp, ctrl, mu, p, tp, k3, lanes)
        for c in range(n_cars):
            for j in range(NX):
                tmp[c, j] = x[c, j] + dt * k3[c, j]
        _derivative_block(tmp, ctrl, mu, p, tp, k4, lanes)
        for c in range(n_cars):
            for j in range(NX):
                x[c, j] += dt / 6.0 * (k1[c, j] + 2.0 * k2[c, j] + 2.0 * k3[c, j] + k4[c, j])
                if not math.isfinite(x[c, j]):
                    status[c] = 3
                    return


@numba.njit(nogil=True, **JIT)
def _advance_blocks(blocks, x, ctrl, plant: Plant, road: RoadTables, dt, n_steps, aux, status):
    """:func:`advance_block` of each block of BLOCK cars in ``blocks`` (indices of blocks; every
    array :func:`fourwis.core.kernels.borrowed` for the call)."""
    x, ctrl, road, aux, status = borrowed((x, ctrl, road, aux, status))
    for block in blocks:
        lo, hi = block * BLOCK, min((block + 1) * BLOCK, x.shape[0])
        rows = RoadTables(road.base_mu[lo:hi], road.rects[lo:hi], road.mu_given[lo:hi], road.use_map)
        advance_block(x[lo:hi], ctrl[lo:hi], plant, rows, dt, n_steps, aux[lo:hi], status[lo:hi])


@numba.njit(**JIT)
def _derivatives_batch(x, ctrl, mu, plant: Plant, dx, aux):
    p, tp = plant
    for lo in range(0, x.shape[0], BLOCK):
        hi = min(lo + BLOCK, x.shape[0])
        lanes = _wheel_scratch(p, hi - lo)
        _derivative_block(x[lo:hi], ctrl[lo:hi], mu[lo:hi], p, tp, dx[lo:hi], lanes)
        _fill_aux(mu[lo:hi], lanes, aux[lo:hi])


PARALLEL_MIN_BATCH = 64  #: batches at least this large run on all cores (:func:`step`)
#: largest RK4 step [s] :func:`step` takes; closed loops run at 2 ms. It is half the 20 ms at which
#: runs still match those at 2 ms, leaving room for stiffer parameters (faster lags:
#: :func:`check_lag_step`; lighter wheels) (docs/decisions/0003-fixed-2ms-rk4-and-step-limits.md)
MAX_DT = 0.01


@numba.njit(inline="always", **JIT)
def sideslip(u: float, v: float) -> float:
    """Sideslip angle [rad] of a body moving at u, v [m/s]: atan2(v, |u|) (libm's, in compiled and
    Python code alike, so that the two loops' truths agree bit for bit on every machine)."""
    return math.atan2(v, abs(u))


@numba.njit(**JIT)
def _sideslips(u, v, out) -> None:
    for i in range(u.size):
        out[i] = sideslip(u[i], v[i])


def sideslip_angles(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`sideslip` of (B,) speeds [m/s]: (B,) [rad]."""
    u, v = np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(v, dtype=float)
    out = np.empty(u.shape)
    _sideslips(u.ravel(), v.ravel(), out.ravel())
    return out


def check_plant_step(dt) -> float:
    """``dt`` [s] as a float if it is a step in (0, :data:`MAX_DT`]; else ValueError naming it."""
    if not (is_number(dt) and 0.0 < dt <= MAX_DT):
        raise ValueError(f"dt must be a step in (0, {MAX_DT}] s (the plant's largest RK4 step), got {dt!r}")
    return float(dt)


#: largest |lambda dt| of a real, negative eigenvalue inside classical RK4's stability region
RK4_REAL_LIMIT = 2.78


def check_lag_step(params: VehicleParams, dt: float) -> None:
    """ValueError naming ``dt`` and the lag if a first-order lag (:data:`LAG_FIELDS`; eigenvalue
    -1 / tau) is too fast for RK4 at this step: past dt = RK4_REAL_LIMIT tau the lag's state
    grows without bound, with no other error. Near the limit RK4 is stable but the lag barely
    decays per step: keep dt <= tau for its response (the shipped 10 ms lags at the 10 ms
    MAX_DT; docs/decisions/0003-fixed-2ms-rk4-and-step-limits.md)."""
    name, tau = params.fastest_lag
    if dt > RK4_REAL_LIMIT * tau:
        raise ValueError(
            f"dt = {dt!r} s is too long for VehicleParams.{name} = {tau!r} s: RK4 is unstable past "
            f"dt = {RK4_REAL_LIMIT} tau = {RK4_REAL_LIMIT * tau:.3g} s; use a shorter dt or a slower lag"
        )


def check_relaxation_step(state: np.ndarray, params: VehicleParams, dt: float) -> None:
    """ValueError naming ``dt`` and the speed if the tyres' relaxation is too fast for RK4.

    The relaxed slips decay at rate |v_cx| / sigma, and sigma falls with the load down to
    ``min_relaxation_length``: a lightly loaded wheel at 70 m/s relaxes at ~700 1/s, and at
    dt = 10 ms RK4 then amplifies the tyre deflections every step (finite, so nothing else stops
    the run). Bounded with the fastest contact point's speed, at most sqrt(u^2 + v^2) + |r| times
    the farthest contact point's distance from the CG (docs/decisions/0003-fixed-2ms-rk4-and-step-limits.md)."""
    arm = params.contact_point_reach
    if len(state) == 1:  # one car (the single env's every substep): scalar arithmetic, ~1 us
        x = state[0]
        fastest = math.hypot(x[S_U], x[S_V]) + abs(x[S_R]) * arm
        if not math.isfinite(fastest):  # a non-finite state: the kernel names it, as for a batch
            return
    else:
        speed = np.hypot(state[:, S_U], state[:, S_V]) + np.abs(state[:, S_R]) * arm
        fastest = float(np.max(speed, initial=0.0, where=np.isfinite(speed)))
    limit = RK4_REAL_LIMIT * params.min_relaxation_length / dt
    if fastest > limit:
        safe_dt = RK4_REAL_LIMIT * params.min_relaxation_length / fastest
        raise ValueError(
            f"dt = {dt!r} s is too long at {fastest:.1f} m/s: the tyres relax at up to speed / "
            f"min_relaxation_length ({params.min_relaxation_length:g} m), outside RK4's stability region "
            f"beyond {limit:.1f} m/s; use dt <= {safe_dt:.4g} s"
        )


def _check_array(name: str, value: np.ndarray, width: int) -> np.ndarray:
    value = np.ascontiguousarray(value, dtype=np.float64)
    if value.ndim != 2 or value.shape[1] != width:
        raise ValueError(f"{name} must have shape (batch, {width}), got {value.shape}")
    if not np.all(np.isfinite(value)):
        bad = np.argwhere(~np.isfinite(value))[0]
        raise ValueError(f"{name} has a non-finite value {value[tuple(bad)]!r} at index {tuple(int(i) for i in bad)}")
    return value


def derivatives(
    state: np.ndarray, controls: np.ndarray, mu: np.ndarray, params: VehicleParams
) -> tuple[np.ndarray, np.ndarray]:
    """Pure batched dynamics: ``state (B, NX), controls (B, NU), mu (B, 4)`` -> ``(state_dot, aux)``.

    ``aux (B, NAUX)`` holds the diagnostics named in :data:`AUX_NAMES`.
    """
    state = _check_array("state", state, NX)
    controls = _check_array("controls", controls, NU)
    mu = _check_array("mu", mu, 4)
    if state.shape[0] != controls.shape[0] or state.shape[0] != mu.shape[0]:
        raise ValueError(f"batch sizes differ: state {state.shape}, controls {controls.shape}, mu {mu.shape}")
    _check_mu(mu)
    dx = np.empty_like(state)
    aux = np.empty((state.shape[0], NAUX))
    _derivatives_batch(state, controls, mu, params.kernel, dx, aux)
    return dx, aux


def _check_mu(mu: np.ndarray) -> None:
    bad = ~((mu > 0.0) & (mu <= MU_MAX))
    if np.any(bad):
        raise ValueError(f"road friction mu must lie in (0, {MU_MAX}], got {mu[bad][0]!r}")


class PlantStep(NamedTuple):
    """Result of :func:`step`: the new state (B, NX) and diagnostics at it (B, NAUX)."""

    state: np.ndarray
    aux: np.ndarray


def step(
    state: np.ndarray, controls: np.ndarray, params: VehicleParams, road, dt: float = 0.002, n_steps: int = 1
) -> PlantStep:
    """Advance a batch ``n_steps`` RK4 steps of ``dt`` [s] with controls held; returns a new state.

    ``road``: a friction map (:mod:`envs.road`: one for the whole batch, or a sequence of B maps)
    or precomputed :class:`envs.road.RoadTables` (the fast path for repeated calls). Table maps
    are evaluated inside the kernel at every step; user callables are evaluated in Python at
    the start of the call (held over its steps: call with ``n_steps=1`` for them when a wheel
    may cross a friction boundary) and again at the returned state for the diagnostics (not
    when handed in as precomputed tables, which hold the start's friction). ``dt`` at most
    :data:`MAX_DT` (10 ms), and short enough for the tyres' relaxation at the car's speed
    (:func:`check_relaxation_step`: 10 ms up to ~100 km/h, 2 ms up to ~500 km/h) and for its
    first-order lags (:func:`check_lag_step`).
    Non-finite controls or road friction outside (0, 2] raise ValueError; a state that turns
    non-finite raises FloatingPointError (a run never silently produces NaN).
    """
    state = np.asarray(state, dtype=np.float64)
    controls = np.ascontiguousarray(controls, dtype=np.float64)
    if state.ndim != 2 or state.shape[1] != NX:
        raise ValueError(f"state must have shape (batch, {NX}), got {state.shape}")
    batch = state.shape[0]
    if controls.shape != (batch, NU):
        raise ValueError(f"controls must have shape ({batch}, {NU}), got {controls.shape}")
    check_plant_step(dt)
    check_lag_step(params, dt)
    check_relaxation_step(state, params, dt)
    if not (is_integer(n_steps) and n_steps >= 1):
        raise ValueError(f"n_steps must be a positive integer, got {n_steps!r}")
    tables = road if isinstance(road, RoadTables) else road_tables(road, state, params)
    if tables.base_mu.shape[0] != batch:
        raise ValueError(f"road tables are for a batch of {tables.base_mu.shape[0]}, state batch is {batch}")
    out = state.copy()
    aux = np.empty((batch, NAUX))
    status = np.zeros(batch, dtype=np.int64)
    blocks = np.arange(-(-batch // BLOCK))
    road_rows = RoadTables(tables.base_mu, tables.rects, tables.mu_given, bool(tables.use_map))
    run_parallel(
        _advance_blocks, blocks, out, controls, params.kernel, road_rows, float(dt), int(n_steps), aux, status,
        min_items=-(-PARALLEL_MIN_BATCH // BLOCK),
    )  # fmt: skip
    if np.count_nonzero(status):
        b = int(np.flatnonzero(status)[0])
        raise plant_error(b, int(status[b]), state[b], controls[b], out[b])
    if not tables.use_map and not isinstance(road, RoadTables):  # a callable map: the diagnostics see the
        aux = derivatives(out, controls, road_tables(road, out, params).mu_given, params)[1]  # friction here now
    return PlantStep(out, aux)


def plant_error(b: int, code: int, start: np.ndarray, controls: np.ndarray, reached: np.ndarray) -> Exception:
    """The error for vehicle b's kernel status ``code`` (1-3, :func:`advance_block`): its state
    ``start`` (NX,) at the step's start, ``controls`` (NU,) and the state ``reached`` when it stopped."""
    if code == 1:
        return ValueError(f"controls[{b}] has a non-finite value: {controls!r}")
    if code == 2:
        return ValueError(
            f"road friction under vehicle {b} is outside (0, {MU_MAX}] at x={reached[S_X]:.3f} m, "
            f"y={reached[S_Y]:.3f} m"
        )
    if not np.all(np.isfinite(start)):
        return ValueError(f"state[{b}] has a non-finite value: {start!r}")
    return FloatingPointError(f"plant state of vehicle {b} became non-finite (last finite state {start!r})")


def initial_state(
    params: VehicleParams,
    speed: float | np.ndarray,
    batch_size: int = 1,
    x: float = 0.0,
    y: float = 0.0,
    heading: float = 0.0,
) -> np.ndarray:
    """Straight free-rolling state (batch_size, NX) at ``speed`` [m/s] (scalar or (batch_size,))."""
    speed = np.broadcast_to(np.asarray(speed, dtype=np.float64), (batch_size,))
    if not np.all(np.isfinite(speed)) or np.any(speed < 0.0):
        raise ValueError(f"initial speed must be finite and >= 0, got {speed!r}")
    state = np.zeros((batch_size, NX))
    state[:, S_X] = x
    state[:, S_Y] = y
    state[:, S_PSI] = heading
    state[:, S_U] = speed
    state[:, S_OMEGA : S_OMEGA + 4] = speed[:, None] / params.wheel_radius
    return state

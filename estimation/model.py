"""The estimator's own vehicle model (paper section 2): 3-DOF body, Dugoff tyres with
load-dependent stiffness (eq. 17), quasi-static normal loads. Simpler than, and different
from, the truth plant (PAC2002 tyres with relaxation, wheel dynamics, lags): no inverse crime.

All functions broadcast over leading axes, so a filter can pass (B, K, ...) cubature point
sets. Corrections to the paper (standard textbook forms, Rajamani 2012 ch. 13; Dugoff,
Fancher & Segel 1970):

* eq. 4-6: each wheel's force is rotated by its own steer angle and the moment arms are
  +/- t/2 laterally and +a / -b longitudinally with the signs of ISO 8855 (the paper's rear-
  wheel signs slip);
* eq. 8-10: the Dugoff parameter carries mu*Fz (the paper's eq. 10 omits it);
* eq. 11-14: the rear slip angles use -b (the paper's eq. 14 writes b/l).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from typing import NamedTuple

import numpy as np

GRAVITY = 9.81  #: [m/s^2]
MIN_SPEED = 1.0  #: denominator floor for slip quantities [m/s]


def _load_fit() -> dict:
    return json.loads(resources.files("estimation").joinpath("data/dugoff_fit.json").read_text())


@dataclass(frozen=True)
class ModelParams:
    """Estimator model parameters (SI). Stiffness C(Fz) = m Fz - n Fz^2 (eq. 17): m1, n1
    longitudinal [N/unit slip per N], m2, n2 lateral [N/rad per N]; eps: Dugoff's speed
    reduction of friction [s/m]."""

    mass: float
    yaw_inertia: float
    cg_to_front: float
    cg_to_rear: float
    track_front: float
    track_rear: float
    wheel_radius: float
    cg_height: float
    wheel_inertia: float
    m1: float
    n1: float
    m2: float
    n2: float
    eps: float = 0.0

    @classmethod
    def from_vehicle(cls, vehicle, fit: dict | None = None) -> "ModelParams":
        """From a duck-typed VehicleParams and the eq. 17 fit (estimation/data/dugoff_fit.json)."""
        fit = fit or _load_fit()
        return cls(vehicle.mass, vehicle.yaw_inertia, vehicle.cg_to_front, vehicle.cg_to_rear, vehicle.track_front,
                   vehicle.track_rear, vehicle.wheel_radius, vehicle.cg_height, vehicle.wheel_inertia,
                   fit["m1"], fit["n1"], fit["m2"], fit["n2"])

    @property
    def wheelbase(self) -> float:
        return self.cg_to_front + self.cg_to_rear

    @property
    def wheel_x(self) -> np.ndarray:
        """Longitudinal wheel positions from the CG (4,) [m]."""
        return np.array([self.cg_to_front, self.cg_to_front, -self.cg_to_rear, -self.cg_to_rear])

    @property
    def wheel_y(self) -> np.ndarray:
        """Lateral wheel positions from the CG (4,) [m] (left positive)."""
        return np.array([self.track_front, -self.track_front, self.track_rear, -self.track_rear]) / 2


class Inputs(NamedTuple):
    """Measured inputs of one step: road-wheel steer angles (..., 4) [rad], wheel speeds
    (..., 4) [rad/s], motor torques (..., 4) [N m], wheel angular accelerations (..., 4) [rad/s^2]."""

    delta: np.ndarray
    omega: np.ndarray
    torque: np.ndarray
    omega_dot: np.ndarray


def normal_loads(ax: np.ndarray, ay: np.ndarray, p: ModelParams) -> np.ndarray:
    """Quasi-static wheel loads (..., 4) [N] from body accelerations ax, ay (...) [m/s^2]:
    static share plus longitudinal (m ax h / L) and lateral (m ay h / t, split by axle
    static share) transfer; floored at 5% of the static load."""
    m, a, b, h, L = p.mass, p.cg_to_front, p.cg_to_rear, p.cg_height, p.wheelbase
    ax, ay = np.asarray(ax)[..., None], np.asarray(ay)[..., None]
    front = m * GRAVITY * b / L - m * ax * h / L
    rear = m * GRAVITY * a / L + m * ax * h / L
    d_front = m * ay * h * (b / L) / p.track_front
    d_rear = m * ay * h * (a / L) / p.track_rear
    fz = np.concatenate([front / 2 - d_front, front / 2 + d_front, rear / 2 - d_rear, rear / 2 + d_rear], axis=-1)
    static = m * GRAVITY * np.array([b, b, a, a]) / (2 * L)
    return np.maximum(fz, 0.05 * static)


def wheel_kinematics(u, v, r, delta, p: ModelParams) -> tuple[np.ndarray, np.ndarray]:
    """Slip angles (..., 4) [rad] and wheel-centre speeds along each wheel's heading (..., 4) [m/s]
    (eq. 11-14, standard form: alpha_i = delta_i - atan((v + x_i r) / (u - y_i r)))."""
    u, v, r = (np.asarray(q)[..., None] for q in (u, v, r))
    vx = u - r * p.wheel_y
    vy = v + r * p.wheel_x
    vx_safe = np.maximum(np.abs(vx), MIN_SPEED)
    alpha = delta - np.arctan2(vy, vx_safe)
    speed_along = vx * np.cos(delta) + vy * np.sin(delta)
    return alpha, speed_along


def dugoff_forces(fz, slip, alpha, mu, cx, cy, speed, eps: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Dugoff combined-slip forces Fx, Fy [N] (standard form; DESIGN.md):
    lambda = mu Fz (1 - eps u sqrt(Cx^2 s^2 + Cy^2 tan^2 a)) (1 - s) / (2 sqrt(Cx^2 s^2 + Cy^2 tan^2 a)),
    f = (2 - lambda) lambda if lambda < 1 else 1; Fx = Cx s/(1-s) f, Fy = Cy tan(a)/(1-s) f."""
    tan_a = np.tan(alpha)
    one_minus_s = np.maximum(1.0 - slip, 0.05)
    demand = np.sqrt((cx * slip) ** 2 + (cy * tan_a) ** 2)
    lam = mu * fz * (1.0 - eps * speed * demand) * one_minus_s / (2.0 * np.maximum(demand, 1e-9))
    f = np.where(lam < 1.0, (2.0 - lam) * lam, 1.0)
    return cx * slip / one_minus_s * f, cy * tan_a / one_minus_s * f


def dugoff_lambda(fz, slip, alpha, mu, cx, cy) -> np.ndarray:
    """Dugoff's lambda: below 1 the force depends on mu (the tyre is saturating)."""
    demand = np.sqrt((cx * slip) ** 2 + (cy * np.tan(alpha)) ** 2)
    return mu * fz * np.maximum(1.0 - slip, 0.05) / (2.0 * np.maximum(demand, 1e-9))


class TyreState(NamedTuple):
    """Per-wheel tyre operating point (..., 4): load [N], slip angle [rad], longitudinal slip,
    longitudinal and lateral stiffness (eq. 17)."""

    fz: np.ndarray
    alpha: np.ndarray
    slip: np.ndarray
    cx: np.ndarray
    cy: np.ndarray


def tyre_state(u, v, r, ax, ay, inputs: Inputs, p: ModelParams) -> TyreState:
    """The tyres' operating point at body state (u, v, r), accelerations (ax, ay) and ``inputs``."""
    fz = normal_loads(ax, ay, p)
    alpha, speed_along = wheel_kinematics(u, v, r, inputs.delta, p)
    wheel_speed = inputs.omega * p.wheel_radius
    slip = (wheel_speed - speed_along) / np.maximum(np.maximum(np.abs(wheel_speed), np.abs(speed_along)), MIN_SPEED)
    return TyreState(fz, alpha, slip, p.m1 * fz - p.n1 * fz**2, p.m2 * fz - p.n2 * fz**2)


def body_forces(u, v, r, ax, ay, mu, inputs: Inputs, p: ModelParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body accelerations ax, ay [m/s^2] and yaw moment Gamma [N m] from the tyre forces (eq. 4-6,
    corrected). Fx from the wheel's torque balance (eq. 7), limited by the Dugoff friction
    ellipse; Fy from Dugoff with the slip angle and mu. Loads from the (previous) ax, ay."""
    fz, alpha, slip, cx, cy = tyre_state(u, v, r, ax, ay, inputs, p)
    fx_torque = (inputs.torque - p.wheel_inertia * inputs.omega_dot) / p.wheel_radius
    _, fy = dugoff_forces(fz, slip, alpha, mu, cx, cy, np.asarray(u)[..., None], p.eps)
    limit = mu * fz
    fx = np.clip(fx_torque, -limit, limit)
    c, s = np.cos(inputs.delta), np.sin(inputs.delta)
    f_long = fx * c - fy * s
    f_lat = fx * s + fy * c
    ax_new = f_long.sum(-1) / p.mass
    ay_new = f_lat.sum(-1) / p.mass
    gamma = (p.wheel_x * f_lat - p.wheel_y * f_long).sum(-1)
    return ax_new, ay_new, gamma


def state_transition(x: np.ndarray, mu: np.ndarray, inputs: Inputs, p: ModelParams, dt: float) -> np.ndarray:
    """Discrete process model for x_s = [u, v, ax, ay, r, Gamma] (..., 6), paper eq. 1-3:
    u+ = u + dt (ax + v r), v+ = v + dt (ay - u r), r+ = r + dt Gamma / Iz (Euler at the 2 ms
    step); ax, ay, Gamma are algebraic: recomputed from the tyre model at the new state.
    ax, ay here are the body's specific forces (what an accelerometer reads without roll/pitch)."""
    u, v, ax, ay, r, gamma = np.moveaxis(x, -1, 0)
    u_new = u + dt * (ax + v * r)
    v_new = v + dt * (ay - u * r)
    r_new = r + dt * gamma / p.yaw_inertia
    ax_new, ay_new, gamma_new = body_forces(u_new, v_new, r_new, ax, ay, mu, inputs, p)
    return np.stack([u_new, v_new, ax_new, ay_new, r_new, gamma_new], axis=-1)

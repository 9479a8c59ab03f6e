"""Upper-layer references: desired yaw rate and sideslip bound, and the paper's 4WS law.

Vehicle parameters are duck-typed (a VehicleParams-like object: mass, yaw_inertia,
cg_to_front, cg_to_rear, wheelbase, axle_cornering_stiffness, max_rear_steer).
"""

from __future__ import annotations

import numpy as np

GRAVITY = 9.81  #: [m/s^2]
FRICTION_USE = 0.85  #: share of mu*g the reference may ask for (Rajamani 2012, sec. 8.5)
MIN_SPEED = 1.0  #: speed floor in divisions [m/s]


def understeer_gradient(params) -> float:
    """K_us = (m / L) (b / C_f - a / C_r) [rad s^2/m] of the linear 2-DOF model (per-axle
    stiffnesses); zero for this car (a = b, equal tyres): neutral steer."""
    c_f, c_r = params.axle_cornering_stiffness
    return params.mass / params.wheelbase * (params.cg_to_rear / c_f - params.cg_to_front / c_r)


def reference_yaw_rate(u: np.ndarray, delta_f: np.ndarray, mu: np.ndarray, params,
                       understeer: float | None = None) -> np.ndarray:
    """Desired yaw rate (B,) [rad/s]: the 2-DOF steady state u delta / (L + K_us u^2), bounded by
    the friction limit 0.85 mu g / u with mu the mean of the estimated per-wheel mu (B, 4)."""
    k = understeer_gradient(params) if understeer is None else understeer
    u = np.asarray(u, dtype=float)
    steady = u * delta_f / (params.wheelbase + k * u**2)
    limit = FRICTION_USE * np.mean(mu, axis=-1) * GRAVITY / np.maximum(np.abs(u), MIN_SPEED)
    return np.clip(steady, -limit, limit)


def sideslip_bound(mu: np.ndarray) -> np.ndarray:
    """Largest acceptable |beta| (B,) [rad]: atan(0.02 mu g), ~10 deg on dry and ~3.4 deg on
    ice-like roads (the mu-dependent bound of ESC practice; van Zanten, SAE 2000-01-1633)."""
    return np.arctan(0.02 * np.mean(mu, axis=-1) * GRAVITY)


def rear_steer_gain(u: np.ndarray, params) -> np.ndarray:
    """Paper eq. 20 (zero-sideslip proportional 4WS), with positive per-axle stiffnesses:
    k = (-b + m a u^2 / (C_r L)) / (a + m b u^2 / (C_f L)). Opposite phase (k < 0) below
    u0 = sqrt(b C_r L / (m a)), in phase above. (The paper prints the stiffnesses with the
    sign convention of negative cornering stiffness; this is the same law.)"""
    c_f, c_r = params.axle_cornering_stiffness
    m, a, b, L = params.mass, params.cg_to_front, params.cg_to_rear, params.wheelbase
    u2 = np.asarray(u, dtype=float) ** 2
    return (-b + m * a * u2 / (c_r * L)) / (a + m * b * u2 / (c_f * L))


def rear_steer_feedforward(u: np.ndarray, delta_f: np.ndarray, params) -> np.ndarray:
    """Rear road-wheel angle (B,) [rad] of the eq. 20 law, limited to the actuator range."""
    return np.clip(rear_steer_gain(u, params) * delta_f, -params.max_rear_steer, params.max_rear_steer)

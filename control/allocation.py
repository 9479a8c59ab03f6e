"""Lower layer: the four wheel torques that add a yaw moment to the driver's drive torques.

The moment comes from left/right torque differences (differential drive): a wheel force
change dFx_i at lateral arm y_i gives dMz = -y_i dFx_i (ISO axes, y left), so more drive on
the right wheels yaws the car left. The request is shared over the wheels in proportion to
their friction capacity mu_i Fz_i (estimated), each torque is limited by the motor and by
the tyre's friction (|T| <= R mu Fz), and the achieved moment is returned so callers see
saturation. Closed form + clipping: it runs every 2 ms step for a batch.
"""

from __future__ import annotations

import numpy as np

SIDE = np.array([-1.0, 1.0, -1.0, 1.0])  #: -1 left wheels, +1 right wheels


def allocate_torques(base_torques: np.ndarray, yaw_moment: np.ndarray, fz: np.ndarray, mu: np.ndarray,
                     params) -> tuple[np.ndarray, np.ndarray]:
    """Wheel torques (B, 4) [N m] = base + differential share of ``yaw_moment`` (B,) [N m], and the
    yaw moment actually achieved (B,) after motor and friction limits (straight-wheel arms)."""
    base_torques = np.asarray(base_torques, dtype=float)
    yaw_moment = np.asarray(yaw_moment, dtype=float)
    if base_torques.ndim != 2 or base_torques.shape[1] != 4:
        raise ValueError(f"base_torques must have shape (B, 4), got {base_torques.shape}")
    if not (np.all(np.isfinite(base_torques)) and np.all(np.isfinite(yaw_moment))):
        raise ValueError("base torques and yaw moment must be finite")
    arm = np.array([params.track_front, params.track_front, params.track_rear, params.track_rear]) / 2
    capacity = np.maximum(mu * fz, 1e-6)
    share = capacity / capacity.sum(axis=1, keepdims=True)  # (B, 4), sums to 1
    # dMz = sum_i arm_i * SIDE_i * dFx_i with dFx_i = SIDE_i * share_i * X  =>  X = Mz / sum(arm_i share_i)
    force_scale = yaw_moment / np.sum(arm * share, axis=1)
    delta_force = SIDE * share * force_scale[:, None]
    limit = np.minimum(params.motor_peak_torque, params.wheel_radius * capacity)
    torques = np.clip(base_torques + delta_force * params.wheel_radius, -limit, limit)
    base_clipped = np.clip(base_torques, -limit, limit)
    achieved = np.sum(arm * SIDE * (torques - base_clipped), axis=1) / params.wheel_radius
    return torques, achieved

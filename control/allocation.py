"""Lower layer: the four wheel torques that add a yaw moment to the driver's drive torques.

The moment comes from left/right torque differences (differential drive): a wheel force
change dFx_i at lateral arm y_i gives dMz = -y_i dFx_i (ISO axes, y left), so more drive on
the right wheels yaws the car left. The request is shared over the wheels in proportion to
their friction capacity mu_i Fz_i (estimated), each torque is limited by the motor and by
the tyre's friction (|T| <= R mu Fz), and the achieved moment is returned so callers see
saturation. Closed form + clipping, compiled: it runs every 2 ms step for a batch.
"""

from __future__ import annotations


import numba
import numpy as np

SIDE = (-1.0, 1.0, -1.0, 1.0)  #: -1 left wheels, +1 right wheels


@numba.njit(cache=True, error_model="numpy")
def _allocate(base_torques, yaw_moment, fz, mu, arm, motor_limit, wheel_radius, torques, achieved) -> None:
    for b in range(base_torques.shape[0]):
        capacity = np.empty(4)
        for w in range(4):
            capacity[w] = max(mu[b, w] * fz[b, w], 1e-6)
        total = capacity.sum()
        # dMz = sum_i arm_i SIDE_i dFx_i with dFx_i = SIDE_i share_i X  =>  X = Mz / sum(arm_i share_i)
        lever = 0.0
        for w in range(4):
            lever += arm[w] * capacity[w] / total
        force_scale = yaw_moment[b] / lever
        moment = 0.0
        for w in range(4):
            limit = min(motor_limit, wheel_radius * capacity[w])
            share = capacity[w] / total
            torque = base_torques[b, w] + SIDE[w] * share * force_scale * wheel_radius
            torques[b, w] = min(max(torque, -limit), limit)
            moment += arm[w] * SIDE[w] * (torques[b, w] - min(max(base_torques[b, w], -limit), limit))
        achieved[b] = moment / wheel_radius


def allocate_torques(base_torques: np.ndarray, yaw_moment: np.ndarray, fz: np.ndarray, mu: np.ndarray,
                     params) -> tuple[np.ndarray, np.ndarray]:
    """Wheel torques (B, 4) [N m] = base + differential share of ``yaw_moment`` (B,) [N m], and the
    yaw moment actually achieved (B,) after motor and friction limits (straight-wheel arms).
    ``fz``, ``mu`` (B, 4): estimated wheel loads [N] and friction. Compiled (numba)."""
    base_torques = np.ascontiguousarray(base_torques, dtype=np.float64)
    if base_torques.ndim != 2 or base_torques.shape[1] != 4:
        raise ValueError(f"base_torques must have shape (B, 4), got {base_torques.shape}")
    B = base_torques.shape[0]
    yaw_moment, fz, mu = (np.ascontiguousarray(q, dtype=np.float64) for q in (yaw_moment, fz, mu))
    if yaw_moment.shape != (B,) or fz.shape != (B, 4) or mu.shape != (B, 4):
        raise ValueError(f"yaw_moment must have shape ({B},) and fz, mu ({B}, 4), got {yaw_moment.shape}, "
                         f"{fz.shape}, {mu.shape}")
    if not (np.isfinite(base_torques).all() and np.isfinite(yaw_moment).all()):
        raise ValueError("base torques and yaw moment must be finite")
    arm = np.array([params.track_front, params.track_front, params.track_rear, params.track_rear]) / 2
    torques, achieved = np.empty((B, 4)), np.empty(B)
    _allocate(base_torques, yaw_moment, fz, mu, arm, float(params.motor_peak_torque), float(params.wheel_radius),
              torques, achieved)
    return torques, achieved

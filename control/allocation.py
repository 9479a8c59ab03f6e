"""Lower layer: the four net wheel torques (in-wheel motor plus friction brake) that deliver the
driver's drive force and the corrective yaw moment with the least tyre workload.

Decision variables are the longitudinal tyre forces Fx_i = T_i / R (wheel inertia neglected).
With the lateral forces Fy_i as they are, the tyre workload

    J = sum_i (Fx_i^2 + Fy_i^2) / (mu_i Fz_i)^2

is minimised over Fx subject to

    sum_i w_i Fx_i = Fx_total         (the driver's drive force along the body, from the base torques)
    sum_i c_i Fx_i = Mz               (the corrective yaw moment)
    -min((T_motor(u) + T_brake) / R, G_i) <= Fx_i <= min(T_motor(u) / R, G_i)
    G_i = sqrt((mu_i Fz_i)^2 - Fy_i^2)   (motor, motor and friction brake, friction ellipse)

with the steered wheels' body-frame share w_i = cos(delta_i) and lever arm
c_i = x_i sin(delta_i) - y_i cos(delta_i) (wheel i at (x_i, y_i), ISO axes: -/+ the half-track
for left/right wheels when straight; a steered front wheel's drive force also turns the car,
as in the plant), T_motor(u) = min(peak torque, peak power / (u / R)) and T_brake the friction
brake's peak torque (a wheel drives with its motor alone and brakes with both: the wheel
actuators, :mod:`fourwis.control.wheel_slip`, split each net torque). When no bound
is active this is the closed-form weighted least squares Fx = W^-1 A^T (A W^-1 A^T)^-1 d. When
a bound binds, the small bounded QP is solved exactly: the optimum lies on one face of the box
(each force free, at its lower or at its upper bound, 3^4 = 81 faces), on each face the
equality-constrained least squares is closed form, and the cheapest feasible face solution is
the optimum (strict convexity). It is compiled and batched (timings: benchmarks/bench_allocation.py,
docs/results/benchmarks.md); scipy's SLSQP on the same QPs serves as the tests' reference
(docs/decisions/0027-torque-allocation.md).

Infeasible demands degrade in a priority set per vehicle: while the car is inside its stable
region the driver comes first, the drive force clipped to what the bounds allow, then the yaw
moment to the largest one feasible with that drive force (an exact greedy linear programme over
the box, by lever per unit of drive force; |delta| < 90 deg); outside it (``stability_first``,
:func:`fourwis.control.reference.outside_stable_region`) stability comes first, the yaw moment
clipped to the largest the bounds allow at any drive force, then the drive force to the one
nearest the driver's that still delivers that moment (exact: the achievable (force, moment) set
is the convex hull of the box vertices' images). Outside it the driver's drive also yields
whether or not the demand is feasible: the drive force asked is at most zero (a production ESC's
engine-torque request; braking passes). The result reports what was delivered and flags it.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numba
import numpy as np

from fourwis.control.reference import GRAVITY
from fourwis.core.kernels import JIT, dot, scratch

#: the 3^4 = 81 activity patterns (81, 4): each wheel free (0), at its lower (1) or upper (2) bound
_FACES = np.array([[(face // 3**w) % 3 for w in range(4)] for face in range(81)], dtype=np.int64)


class Allocation(NamedTuple):
    """Allocator output for a batch of B vehicles: wheel torques [N m] (B, 4), the yaw moment
    [N m] (B,) and drive force [N] (B,) they deliver, and whether the demand was met (B,) bool."""

    torques: np.ndarray
    yaw_moment: np.ndarray
    drive_force: np.ndarray
    feasible: np.ndarray


class AllocationInputs(NamedTuple):
    """The allocator's demand for B vehicles: the driver's base torques (B, 4) [N m] (their drive
    force), the yaw moment (B,) [N m], the estimated wheel loads (B, 4) [N], friction (B, 4) and
    lateral tyre forces (B, 4) [N] (the friction ellipse; zero: the circle), the speed (B,)
    [m/s] (the motors' power limit), the front and rear road-wheel angles (B,) [rad], and
    whether the yaw moment comes before the drive force when both cannot be met, and the drive force
    yields to at most zero (B,) bool."""

    base_torques: np.ndarray
    yaw_moment: np.ndarray
    fz: np.ndarray
    mu: np.ndarray
    lateral: np.ndarray
    speed: np.ndarray
    front_steer: np.ndarray
    rear_steer: np.ndarray
    stability_first: np.ndarray


class AllocatorLimits(NamedTuple):
    """The car the allocator drives: contact-point positions (4, 2) [m] (body frame), motor peak
    torque [N m] and power [W], wheel radius [m], friction brake peak torque [N m] (0: no brakes)."""

    positions: np.ndarray
    motor_peak_torque: float
    motor_peak_power: float
    wheel_radius: float
    brake_peak_torque: float


@numba.njit(**JIT)
def _greedy_moment(weight, lever, lower, upper, force, sign, x) -> float:
    """Largest (sign = +1) or smallest (-1) sum lever_i x_i over lower <= x <= upper with
    sum weight_i x_i = force (weights > 0; force within [weight.lower, weight.upper]): fill the
    wheels with the best lever per unit weight first. Writes that x (4,) and returns its moment."""
    order = scratch((4,), np.int64)  # wheels by -sign lever_i / weight_i, ties in wheel order (a stable sort)
    for i in range(4):
        k, j = i, i
        while j > 0 and -sign * lever[k] / weight[k] < -sign * lever[order[j - 1]] / weight[order[j - 1]]:
            order[j] = order[j - 1]
            j -= 1
        order[j] = k
    x[:] = lower
    remaining = force - dot(weight, lower)
    for w in order:
        step = min(max(remaining, 0.0) / weight[w], upper[w] - lower[w])
        x[w] += step
        remaining -= weight[w] * step
    return dot(lever, x)


@numba.njit(**JIT)
def _solve_box_qp(capacity_sq, weight, lever, lower, upper, force, moment, faces, x_best) -> bool:
    """min sum x_i^2 / capacity_sq_i s.t. sum weight_i x_i = force, sum lever_i x_i = moment,
    lower <= x <= upper, over the first ``faces`` activity patterns of ``_FACES`` (all 81: the
    exact optimum; 1: only the all-free closed form); False if none of them is feasible."""
    abs_lower = abs_upper = 0.0  # (np.abs(...).sum() without the temporaries)
    for w in range(4):
        abs_lower += abs(lower[w])
        abs_upper += abs(upper[w])
    scale_f = abs_lower + abs_upper + abs(force) + 1.0
    scale_m = scale_f * (max(abs(lever[0]), abs(lever[1]), abs(lever[2]), abs(lever[3])) + 1.0)
    x = scratch((4,))
    best_cost = np.inf
    for face in range(faces):
        f_rest, m_rest = force, moment
        s0 = s1 = s2 = 0.0
        for w in range(4):
            if _FACES[face, w] == 0:
                s0 += capacity_sq[w] * weight[w] ** 2
                s1 += capacity_sq[w] * weight[w] * lever[w]
                s2 += capacity_sq[w] * lever[w] ** 2
            else:
                x[w] = lower[w] if _FACES[face, w] == 1 else upper[w]
                f_rest -= weight[w] * x[w]
                m_rest -= lever[w] * x[w]
        # free x_i = capacity_sq_i (l0 weight_i + l1 lever_i): the stationary point on this face
        det = s0 * s2 - s1 * s1
        if det > 1e-12 * s0 * s2:
            l0 = (s2 * f_rest - s1 * m_rest) / det
            l1 = (s0 * m_rest - s1 * f_rest) / det
        elif s0 > 0.0:  # free levers proportional to the weights: only the force row is independent
            l0, l1 = f_rest / s0, 0.0
        else:
            l0 = l1 = 0.0
        cost = 0.0
        ok = True
        for w in range(4):
            if _FACES[face, w] == 0:
                x[w] = capacity_sq[w] * (l0 * weight[w] + l1 * lever[w])
                slack = 1e-9 * (upper[w] - lower[w] + 1.0)
                if x[w] < lower[w] - slack or x[w] > upper[w] + slack:
                    ok = False
            cost += x[w] ** 2 / capacity_sq[w]
        if not ok or cost >= best_cost:
            continue
        if abs(dot(weight, x) - force) > 1e-9 * scale_f or abs(dot(lever, x) - moment) > 1e-9 * scale_m:
            continue
        best_cost = cost
        for w in range(4):
            x_best[w] = min(max(x[w], lower[w]), upper[w])
    return best_cost < np.inf


@numba.njit(**JIT)
def _force_range(weight, lever, lower, upper, moment, x_low, x_high) -> tuple[float, float]:
    """Smallest and largest sum weight_i x_i over lower <= x <= upper with sum lever_i x_i = moment
    (within the box's moment range); writes an x of each into ``x_low`` and ``x_high`` (4,). The
    (force, moment) pairs the box reaches are the convex hull of its 16 vertices' images, so each
    end lies on a segment between two vertices whose moments straddle ``moment``."""
    corners_f, corners_m, corners = scratch((16,)), scratch((16,)), scratch((16, 4))
    for v in range(16):
        force_v = moment_v = 0.0
        for w in range(4):
            corners[v, w] = upper[w] if (v >> w) & 1 else lower[w]
            force_v += weight[w] * corners[v, w]
            moment_v += lever[w] * corners[v, w]
        corners_f[v], corners_m[v] = force_v, moment_v
    tolerance = 1e-9 * (1.0 + abs(moment))
    f_low, f_high = np.inf, -np.inf
    for i in range(16):
        for j in range(16):
            if corners_m[i] > moment + tolerance or corners_m[j] < moment - tolerance:
                continue
            span = corners_m[j] - corners_m[i]
            t = min(max((moment - corners_m[i]) / span, 0.0), 1.0) if span > tolerance else 0.0
            force = corners_f[i] + t * (corners_f[j] - corners_f[i])
            if force < f_low or force > f_high:
                for w in range(4):
                    x = corners[i, w] + t * (corners[j, w] - corners[i, w])
                    if force < f_low:
                        x_low[w] = x
                    if force > f_high:
                        x_high[w] = x
                f_low, f_high = min(f_low, force), max(f_high, force)
    return f_low, f_high


NEGATIVE_LOAD, NONPOSITIVE_FRICTION = -1, -2  #: statuses of allocation_kernel for out-of-range inputs


@numba.njit(**JIT)
def allocation_kernel(inputs: AllocationInputs, limits: AllocatorLimits, out: Allocation) -> int:
    base_torques, yaw_moment, fz, mu, lateral, speed, front_steer, rear_steer, stability_first = inputs
    positions, motor_peak_torque, motor_peak_power, wheel_radius, brake_peak_torque = limits
    torques, delivered_moment, delivered_force, feasible = out
    """Fills ``out`` (its rows as ``inputs``'); returns 0, 1 + the index of the first non-finite
    input (AllocationInputs order), or NEGATIVE_LOAD / NONPOSITIVE_FRICTION."""
    for i, value in enumerate(
        (
            base_torques.sum(),
            yaw_moment.sum(),
            fz.sum(),
            mu.sum(),
            lateral.sum(),
            speed.sum(),
            front_steer.sum(),
            rear_steer.sum(),
        )
    ):
        if not np.isfinite(value):
            return 1 + i
    if fz.min() < 0.0:
        return NEGATIVE_LOAD
    if mu.min() <= 0.0:
        return NONPOSITIVE_FRICTION
    upper, lower, x, capacity_sq = scratch((4,)), scratch((4,)), scratch((4,)), scratch((4,))
    weight, lever = scratch((4,)), scratch((4,))
    brake_force = brake_peak_torque / wheel_radius
    for b in range(base_torques.shape[0]):
        _wheel_force_map(positions, front_steer[b], rear_steer[b], weight, lever)
        spin = abs(speed[b]) / wheel_radius  # wheel speed [rad/s] if rolling
        motor_force = min(motor_peak_torque, motor_peak_power / max(spin, 1e-9)) / wheel_radius
        drive_force = 0.0
        for w in range(4):
            capacity = max(mu[b, w] * fz[b, w], 1e-6)
            capacity_sq[w] = capacity * capacity
            grip = np.sqrt(max(capacity_sq[w] - lateral[b, w] ** 2, 0.0))
            upper[w] = min(motor_force, grip)
            lower[w] = -min(motor_force + brake_force, grip)
            drive_force += weight[w] * base_torques[b, w] / wheel_radius
        if stability_first[b]:  # the driver's drive yields (a production ESC's engine-torque request)
            drive_force = min(drive_force, 0.0)
        # no bound active: the closed-form weighted least squares is the optimum
        feasible[b] = _solve_box_qp(capacity_sq, weight, lever, lower, upper, drive_force, yaw_moment[b], 1, x)
        if not feasible[b]:
            x_high, x_low = scratch((4,)), scratch((4,))
            if stability_first[b]:  # the largest moment at any force, then the force nearest the driver's
                moment_low = moment_high = 0.0
                for w in range(4):
                    moment_low += min(lever[w] * lower[w], lever[w] * upper[w])
                    moment_high += max(lever[w] * lower[w], lever[w] * upper[w])
                moment = min(max(yaw_moment[b], moment_low), moment_high)
                force_low, force_high = _force_range(weight, lever, lower, upper, moment, x_low, x_high)
                force = min(max(drive_force, force_low), force_high)
                vertex_high = force >= 0.5 * (force_high + force_low)
            else:  # the force within the bounds, then the largest moment with it
                force = min(max(drive_force, dot(weight, lower)), dot(weight, upper))
                moment_high = _greedy_moment(weight, lever, lower, upper, force, 1.0, x_high)
                moment_low = _greedy_moment(weight, lever, lower, upper, force, -1.0, x_low)
                moment = min(max(yaw_moment[b], moment_low), moment_high)
                vertex_high = moment >= 0.5 * (moment_high + moment_low)
            tolerance = 1e-9 * (abs(drive_force) + abs(yaw_moment[b]) + upper.sum() - lower.sum() + 1.0)
            feasible[b] = abs(force - drive_force) <= tolerance and abs(moment - yaw_moment[b]) <= tolerance
            if not _solve_box_qp(capacity_sq, weight, lever, lower, upper, force, moment, len(_FACES), x):
                # only at a vertex of the achievable set, within rounding: take the LP's vertex
                x[:] = x_high if vertex_high else x_low
        delivered_force[b] = delivered_moment[b] = 0.0
        for w in range(4):
            torques[b, w] = x[w] * wheel_radius
            delivered_force[b] += weight[w] * x[w]
            delivered_moment[b] += lever[w] * x[w]
    return 0


@numba.njit(inline="always", **JIT)
def _wheel_force_map(positions, front_steer, rear_steer, weight, lever) -> None:
    """Body-frame effect of a unit longitudinal force at each wheel (4,): weight = cos(delta_i)
    along the body's x axis, lever = x_i sin(delta_i) - y_i cos(delta_i) [m] about the CG."""
    for w in range(4):
        delta = front_steer if w < 2 else rear_steer
        c, s = np.cos(delta), np.sin(delta)
        weight[w] = c
        lever[w] = positions[w, 0] * s - positions[w, 1] * c


@numba.njit(**JIT)
def _wheel_force_maps(positions, front_steer, rear_steer, weight, lever) -> None:
    for b in range(front_steer.size):
        _wheel_force_map(positions, front_steer[b], rear_steer[b], weight[b], lever[b])


def wheel_force_map(params, front_steer, rear_steer) -> tuple[np.ndarray, np.ndarray]:
    """(weight, lever) (B, 4): the body-x force [-] and the yaw moment [m] a unit longitudinal tyre
    force at each wheel makes, with the front wheels at ``front_steer`` and the rear wheels at
    ``rear_steer`` (B,) [rad] (straight: weight 1, lever -/+ the half-track for left/right)."""
    front = np.atleast_1d(np.asarray(front_steer, dtype=np.float64))
    rear = np.broadcast_to(np.asarray(rear_steer, dtype=np.float64), front.shape).copy()
    weight, lever = np.empty((front.size, 4)), np.empty((front.size, 4))
    _wheel_force_maps(params.wheel_positions, front, rear, weight, lever)
    return weight, lever


@functools.lru_cache(maxsize=16)
def _zeros(batch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read-only zero arrays (batch, 4), (batch,) and (batch,) bool."""
    wheels, cars, flags = np.zeros((batch, 4)), np.zeros(batch), np.zeros(batch, dtype=np.bool_)
    wheels.flags.writeable = cars.flags.writeable = flags.flags.writeable = False
    return wheels, cars, flags


#: how errors name AllocationInputs' fields
_INPUTS = (
    "base torques",
    "yaw moment",
    "wheel loads",
    "friction",
    "lateral forces",
    "speed",
    "front steer",
    "rear steer",
    "stability first",
)


def allocate_torques(
    base_torques: np.ndarray,
    yaw_moment: np.ndarray,
    fz: np.ndarray,
    mu: np.ndarray,
    params,
    lateral_forces: np.ndarray | None = None,
    speed: np.ndarray | None = None,
    front_steer: np.ndarray | None = None,
    rear_steer: np.ndarray | None = None,
    stability_first: np.ndarray | None = None,
) -> Allocation:
    """Minimum-workload wheel torques for the drive force of ``base_torques`` (B, 4) [N m]
    (what they push the body forward with) plus the yaw moment ``yaw_moment`` (B,) [N m].

    ``fz``, ``mu`` (B, 4): estimated wheel loads [N] and friction; ``lateral_forces`` (B, 4)
    [N]: estimated tyre lateral forces for the friction ellipse (None: zero, the friction
    circle's full radius is available longitudinally); ``speed`` (B,) [m/s]: for the motors'
    power limit (None: peak torque at any speed); ``front_steer``, ``rear_steer`` (B,) [rad]:
    road-wheel angles, for the wheels' lever arms and drive directions (None: straight);
    ``stability_first`` (B,) bool: the yaw moment before the drive force where both cannot be met
    (None: the drive force first). Compiled (numba)."""
    base_torques = np.ascontiguousarray(base_torques, dtype=np.float64)
    if base_torques.ndim != 2 or base_torques.shape[1] != 4:
        raise ValueError(f"base_torques must have shape (B, 4), got {base_torques.shape}")
    B = base_torques.shape[0]
    wheels, cars, flags = _zeros(B)  # read-only defaults, shared: this runs at every 2 ms substep
    inputs = AllocationInputs(
        base_torques,
        np.ascontiguousarray(yaw_moment, dtype=np.float64),
        np.ascontiguousarray(fz, dtype=np.float64),
        np.ascontiguousarray(mu, dtype=np.float64),
        wheels if lateral_forces is None else np.ascontiguousarray(lateral_forces, dtype=np.float64),
        cars if speed is None else np.ascontiguousarray(speed, dtype=np.float64),
        cars if front_steer is None else np.ascontiguousarray(front_steer, dtype=np.float64),
        cars if rear_steer is None else np.ascontiguousarray(rear_steer, dtype=np.float64),
        flags if stability_first is None else np.ascontiguousarray(stability_first, dtype=np.bool_),
    )
    shapes = tuple(q.shape for q in inputs[1:])
    if shapes != ((B,), (B, 4), (B, 4), (B, 4), (B,), (B,), (B,), (B,)):
        raise ValueError(
            f"yaw_moment, speed, the steer angles and stability_first must have shape ({B},) and fz, mu, "
            f"lateral_forces ({B}, 4); got " + ", ".join(f"{name} {shape}" for name, shape in zip(_INPUTS[1:], shapes))
        )
    out = Allocation(np.empty((B, 4)), np.empty(B), np.empty(B), np.empty(B, dtype=np.bool_))
    bad = allocation_kernel(inputs, allocator_limits(params), out)
    if bad:
        raise allocation_error(bad, inputs)
    return out


def allocator_limits(params) -> AllocatorLimits:
    """The :class:`AllocatorLimits` of duck-typed vehicle ``params`` (without ``brake_peak_torque``:
    a car without friction brakes)."""
    return AllocatorLimits(
        np.ascontiguousarray(params.wheel_positions, dtype=np.float64),
        float(params.motor_peak_torque),
        float(params.motor_peak_power),
        float(params.wheel_radius),
        float(getattr(params, "brake_peak_torque", 0.0)),
    )


def allocation_error(bad: int, inputs: AllocationInputs) -> ValueError:
    """The error for :func:`allocation_kernel`'s status ``bad`` (not 0) on ``inputs``."""
    if bad == NEGATIVE_LOAD:
        return ValueError(f"wheel loads must be >= 0 N, got {inputs[2][inputs[2] < 0.0][:4]}")
    if bad == NONPOSITIVE_FRICTION:
        return ValueError(f"friction must be > 0, got {inputs[3][inputs[3] <= 0.0][:4]}")
    value = inputs[bad - 1]
    return ValueError(f"{_INPUTS[bad - 1]} must be finite, got {value[~np.isfinite(value)][:4]}")


def allocate_for_estimate(
    base_torques: np.ndarray,
    yaw_moment: np.ndarray,
    estimate,
    params,
    friction_ellipse: bool = False,
    mu: np.ndarray | None = None,
    front_steer: np.ndarray | None = None,
    rear_steer: np.ndarray | None = None,
    stability_first: np.ndarray | None = None,
) -> Allocation:
    """:func:`allocate_torques` fed from an Estimate-like object (u, ay, mu, fz); ``mu`` (B, 4)
    replaces the estimate's friction when given; the steer angles [rad] (B,) and
    ``stability_first`` (B,) bool as there.

    ``friction_ellipse``: bound each tyre's Fx by what its lateral force leaves, with the
    quasi-static lateral forces Fy_i = Fz_i a_y / g (each tyre carries lateral force in
    proportion to its load, as in steady cornering). Off by default: where mu_hat is too low, a
    tyre the estimate sees as laterally saturated gets no longitudinal force, which removes the
    authority stability control needs most (braking a saturated tyre trades its lateral force
    for yaw moment); with good estimates the two differ little. Off, the bound is the friction
    circle |Fx_i| <= mu_i Fz_i (docs/decisions/0027-torque-allocation.md).
    """
    lateral = estimate.fz * (estimate.ay / GRAVITY)[:, None] if friction_ellipse else None
    mu = estimate.mu if mu is None else mu
    return allocate_torques(
        base_torques, yaw_moment, estimate.fz, mu, params, lateral, estimate.u, front_steer, rear_steer, stability_first
    )

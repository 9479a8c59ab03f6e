"""Stability control: yaw-rate reference, direct yaw-moment laws (LQR, sliding mode), torque
allocation and the paper's 4WS law, combined in :class:`StabilityController`. Uses only what
an estimator provides (an Estimate-like object: u, v, beta, r, ay, mu, fz; mu_std if it has one)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fourwis.control.allocation import (
    Allocation,
    allocate_for_estimate,
    allocate_torques,
    allocation_error,
    allocator_limits,
)
from fourwis.control.dyc import (
    ACTIVE_SPEED,
    MIN_PLANNING_MU,
    YAW_DEADBAND,
    DycKernel,
    DycMemory,
    DycSettings,
    LQRWeights,
    LQRYawController,
    SlidingModeYawController,
    actuator_lag_terms,
    clear_memory,
    fresh_memory,
    inputs_row,
    planning_friction,
    stability_commands,
)
from fourwis.control.esc import BrakeESC
from fourwis.control.reference import understeer_gradient
from fourwis.core.checks import check_controller, check_step, check_vehicle_params, import_factory, is_number
from fourwis.core.types import Command, Estimate

CONTROLLERS = ("none", "dyc-lqr", "dyc-smc", "dyc-lqr-4ws", "dyc-smc-4ws", "esc")
#: default StabilityController.mu_margin [standard deviations]: the controller plans with
#: mu_hat - MU_MARGIN mu_std, so a friction the estimator has not confirmed is not taken for granted;
#: chosen on an earlier design and not re-tuned on the evaluation matrix
#: (docs/decisions/0026-cautious-friction-margin.md)
MU_MARGIN = 1.0


@dataclass(frozen=True)
class StabilityController:
    """Reference + yaw-moment law + allocation (+ optional eq. 20 rear steer).

    ``law``: ``"lqr"`` or ``"smc"``; ``mu_margin`` finite and >= 0; ``reference_understeer`` None or
    >= 0; ``dt`` [s] finite and > 0; anything else raises ValueError.

    The yaw-rate reference is the 2-DOF steady state, bounded by the weaker axle's friction
    (:func:`control.reference.weaker_axle_friction`) and lagged like the car's natural yaw response
    (:func:`control.reference.yaw_time_constant`), so the controller corrects deviations from how a
    stable car responds, not the response delay itself (docs/decisions/0023-yaw-reference.md). With
    the eq. 20 rear steer the controller's rear angle moves at most at ``params.rear_steer_rate``,
    so the reference is built on an angle the car has.

    The LQR law is told the moment the allocation delivered (:func:`control.dyc.delivered_next`),
    which reaches the car through the actuator lag (:func:`control.dyc.actuator_lag`) it was
    designed with (docs/decisions/0024-lag-aware-lqr.md).

    As in production ESC, the law acts on the yaw-rate error outside a deadband of 0.02 rad/s
    (smoothly: the error is shrunk by the deadband) and on sideslip beyond half the mu-dependent
    bound, so that it does not fight sensor noise; moments that turn the car further into the bend
    (understeer correction) fade out linearly as |beta| approaches that bound. Both laws see the
    shrunk state, the sliding mode's model terms included: inside the deadbands its equivalent
    control is that of a car on its reference, so it does not answer the linear model's mismatch
    with saturating tyres where no correction is asked (docs/decisions/0025-sliding-mode-guards.md).

    The law's moment is the whole yaw moment of the four longitudinal tyre forces: the allocator
    meets it with the steered wheels' lever arms (a zero moment also cancels the small moment of
    equal drive forces on steered front wheels), at the commanded road-wheel angles (not the servos'
    lagged positions; a rear angle the plant adds itself, ``VehicleParams.rear_steer_feedforward``,
    is not seen; docs/decisions/0027-torque-allocation.md).

    ``last_allocation`` holds the latest :class:`control.allocation.Allocation`: the yaw moment
    and drive force the wheels delivered and whether the demand was feasible (None before the
    first call). The fields are fixed at construction (frozen; ``dataclasses.replace`` makes a
    changed copy): the compiled step reads them as its settings.

    Cautious friction: the controller plans (reference, sideslip bound, the sliding mode's axle
    saturation, allocation; the LQR's gains depend on speed only) with ``mu - mu_margin * mu_std``
    (the margin stops at MIN_PLANNING_MU; an estimate already below it, ice, is kept). An estimate
    without ``mu_std``, or with zero (the oracle, fixed-mu filters), is used as it is; ``mu_margin=0``
    plans with the point estimate (docs/decisions/0026-cautious-friction-margin.md).

    Each call runs the compiled kernel :func:`control.dyc.stability_command` per vehicle, as the
    compiled closed loop (:mod:`fourwis.envs.loop`) does, on the controller's own per-vehicle memory
    (reference, rear angle, delivered moment, latest allocation), so the two loops can hand the
    controller over mid-run; the numpy functions of :mod:`control.dyc` and :mod:`control.reference`
    evaluate the same code (docs/decisions/0008-compiled-closed-loop-and-dyc.md)."""

    params: object
    law: str = "lqr"
    rear_steer: bool = False
    dt: float = 0.002
    friction_ellipse: bool = False  #: see :func:`control.allocation.allocate_for_estimate`
    mu_margin: float = MU_MARGIN  #: standard deviations below mu_hat the controller plans with
    #: understeer gradient of the yaw reference [rad s^2/m]; None: the car's own, floored at 0 (neutral)
    reference_understeer: float | None = None

    def __post_init__(self) -> None:
        check_vehicle_params(self.params)
        check_step(self.dt)
        for name in ("rear_steer", "friction_ellipse"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if not (is_number(self.mu_margin) and np.isfinite(self.mu_margin) and self.mu_margin >= 0.0):
            raise ValueError(f"mu_margin must be a finite number >= 0, got {self.mu_margin!r}")
        if self.reference_understeer is not None and not (
            is_number(self.reference_understeer)
            and np.isfinite(self.reference_understeer)
            and self.reference_understeer >= 0.0
        ):
            raise ValueError(
                f"reference_understeer must be a finite gradient >= 0 [rad s^2/m], got {self.reference_understeer!r}"
            )
        if self.law == "lqr":
            law = LQRYawController(self.params, LQRWeights()).law
        elif self.law == "smc":
            law = SlidingModeYawController(self.params).law
        else:
            raise ValueError(f"unknown yaw-moment law {self.law!r}; known: ['lqr', 'smc']")
        p = self.params
        c_f, c_r = p.axle_cornering_stiffness
        understeer = self.reference_understeer
        if understeer is None:  # the car's own, floored at neutral
            understeer = max(understeer_gradient(p), 0.0)
        motor_lag, sigma_kappa = actuator_lag_terms(p)
        settings = DycSettings(
            rear_steer=bool(self.rear_steer),
            friction_ellipse=bool(self.friction_ellipse),
            dt=float(self.dt),
            mu_margin=float(self.mu_margin),
            understeer=float(understeer),
            wheelbase=float(p.wheelbase),
            max_rear_steer=float(p.max_rear_steer) if self.rear_steer else 0.0,
            rear_steer_rate=float(getattr(p, "rear_steer_rate", np.inf)),
            motor_lag=float(motor_lag),
            sigma_kappa=float(sigma_kappa),
            c_f=float(c_f),
            c_r=float(c_r),
            mass=float(p.mass),
            yaw_inertia=float(p.yaw_inertia),
            cg_to_front=float(p.cg_to_front),
            cg_to_rear=float(p.cg_to_rear),
        )
        # (frozen: the fields are the settings, so these are set once)
        object.__setattr__(self, "_parts", (settings, allocator_limits(p), law))
        object.__setattr__(self, "_memory", None)

    def reset(self, members: np.ndarray | None = None) -> None:
        """Forget the past of every vehicle, or of those selected by ``members`` (B,) bool."""
        if members is None or self._memory is None:
            object.__setattr__(self, "_memory", None)
        else:
            clear_memory(self._memory, np.asarray(members, dtype=bool))

    def kernel(self, batch: int) -> DycKernel:
        """This controller as its compiled step and the compiled closed loop take it, for a batch
        of ``batch`` vehicles: its settings, the allocator's limits (this controller's vehicle
        parameters), its law and its memory (the arrays themselves, updated in place)."""
        if self._memory is None:
            object.__setattr__(self, "_memory", fresh_memory(batch))
        elif len(self._memory.rear) != batch:
            raise ValueError(f"the controller steers {len(self._memory.rear)} vehicles, not {batch}: reset() it first")
        return DycKernel(*self._parts, self._memory)

    @property
    def reference(self) -> np.ndarray | None:
        """The lagged yaw-rate reference (B,) [rad/s] of the latest call (None before it)."""
        return None if self._memory is None else self._memory.reference.copy()

    @property
    def last_allocation(self) -> Allocation | None:
        """The latest :class:`fourwis.control.allocation.Allocation` (None before the first call;
        a vehicle held in every call so far has NaN rows)."""
        if self._memory is None or np.isnan(self._memory.allocation.yaw_moment).all():
            return None
        return Allocation(*(field.copy() for field in self._memory.allocation))

    def planning_mu(self, estimate) -> np.ndarray:
        """Per-wheel friction (B, 4) the controller plans with (see the class docstring)."""
        mu = np.asarray(estimate.mu, dtype=float)
        mu_std = getattr(estimate, "mu_std", None)
        return mu if mu_std is None else planning_friction(mu, np.asarray(mu_std, dtype=float), self.mu_margin)

    def __call__(self, t: np.ndarray, estimate, front_steer: np.ndarray, base_torques: np.ndarray) -> Command:
        """The command (B vehicles) at the estimate (an Estimate-like object; without ``mu_std``
        the friction is taken as certain), the driver's front road-wheel angles (B,) [rad] and
        base torques (B, 4) [N m]. A call that fails (ValueError naming the allocator's bad
        input) changes nothing."""
        u = np.ascontiguousarray(estimate.u, dtype=float)
        B = u.shape[0] if u.ndim == 1 else -1
        given = {name: getattr(estimate, name, None) for name in Estimate._fields}
        if given["mu_std"] is None:
            given["mu_std"] = np.zeros((max(B, 0), 4))
        if given["v"] is None or given["ax"] is None or given["beta_std"] is None:  # (unread by the controller)
            given["v"] = given["ax"] = given["beta_std"] = np.zeros(max(B, 0))
        inputs = {name: np.ascontiguousarray(value, dtype=float) for name, value in given.items()}
        steer = {"front_steer": np.ascontiguousarray(front_steer, dtype=float),
                 "base_torques": np.ascontiguousarray(base_torques, dtype=float)}  # fmt: skip
        shapes = {name: value.shape for name, value in (inputs | steer).items()}
        expected = {name: (B, 4) if name in ("mu", "mu_std", "fz", "base_torques") else (B,) for name in shapes}
        if B < 0 or shapes != expected:
            raise ValueError(
                "the estimate's u, beta, r, ay, and front_steer must have shape (B,), mu, mu_std, fz and base_torques "
                f"(B, 4); got {shapes}"
            )
        dyc = self.kernel(B)
        before = _copied(dyc.memory)
        bad, vehicle = stability_commands(dyc, Estimate(**inputs), steer["front_steer"], steer["base_torques"])
        if bad:
            failed = inputs_row(dyc.memory.inputs, vehicle)
            failed = type(failed)(*(field.copy() for field in failed))
            object.__setattr__(self, "_memory", before)
            raise allocation_error(bad, failed)
        return Command(dyc.memory.allocation.torques.copy(), dyc.memory.rear.copy())


def _copied(memory: DycMemory) -> DycMemory:
    """A deep copy of ``memory``."""
    return DycMemory(
        *(type(part)(*(field.copy() for field in part)) if isinstance(part, tuple) else part.copy() for part in memory)
    )


#: the DYC controllers' (law, rear steer) by name
_DYC = {
    "dyc-lqr": ("lqr", False),
    "dyc-smc": ("smc", False),
    "dyc-lqr-4ws": ("lqr", True),
    "dyc-smc-4ws": ("smc", True),
}
#: the StabilityController settings make_controller passes on
DYC_OPTIONS = ("friction_ellipse", "mu_margin", "reference_understeer")


def make_controller(name: str, params, dt: float = 0.002, **options):
    """Controller ``name`` (see :data:`CONTROLLERS`) for duck-typed vehicle ``params``; None for
    "none". ``options`` (:data:`DYC_OPTIONS`) set the DYC's :class:`StabilityController`
    fields, e.g. ``mu_margin=0``. Your own: ``module:factory`` returns ``factory(params, dt)``,
    an object with the interface of :class:`envs.simulation.Controller` (``reset`` and a call
    returning a :class:`Command`); the name then works in ``fourwis compare --controllers`` too."""
    if not isinstance(name, str):
        raise ValueError(f"controller must be a name (str; 'none' for none), got {name!r}; known: {list(CONTROLLERS)}")
    unknown = sorted(set(options) - set(DYC_OPTIONS))
    if unknown:
        raise ValueError(f"unknown controller option(s) {unknown}; known: {list(DYC_OPTIONS)}")
    if options and name not in _DYC:
        raise ValueError(f"options {sorted(options)} are the DYC controllers' ({list(_DYC)}), not {name!r}'s")
    if name == "none":
        return None
    check_vehicle_params(params)
    if ":" in name:
        controller = import_factory(name, "controller")(params, dt)
        check_controller(controller, name)
        return controller
    if name == "esc":
        return BrakeESC(params, dt)
    if name not in _DYC:
        raise ValueError(f"unknown controller {name!r}; known: {list(CONTROLLERS)}")
    law, rear_steer = _DYC[name]
    return StabilityController(params, law, rear_steer=rear_steer, dt=dt, **options)


__all__ = [
    "ACTIVE_SPEED",
    "CONTROLLERS",
    "MIN_PLANNING_MU",
    "YAW_DEADBAND",
    "Allocation",
    "BrakeESC",
    "Command",
    "StabilityController",
    "allocate_for_estimate",
    "allocate_torques",
    "check_controller",
    "make_controller",
]

"""Stability control: yaw-rate reference, direct yaw-moment laws (LQR, sliding mode), torque
allocation and the paper's 4WS law, combined in :class:`StabilityController`. Uses only what
an estimator provides (an Estimate-like object: u, v, beta, r, ay, mu, fz; mu_std if it has one)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from control.allocation import Allocation, allocate_for_estimate, allocate_torques
from control.dyc import LQRYawController, LQRWeights, SlidingModeYawController
from control.reference import (rear_steer_feedforward, reference_yaw_rate, sideslip_bound, weaker_axle_friction,
                               yaw_time_constant)
from estimation.types import check_step, check_vehicle_params, import_factory, is_number

CONTROLLERS = ("none", "dyc-lqr", "dyc-smc", "dyc-lqr-4ws", "dyc-smc-4ws")
ACTIVE_SPEED = 2.0  #: below this speed [m/s] the law's moment is zero (the allocator still shares the drive)
YAW_DEADBAND = 0.02  #: |r - r_ref| [rad/s] tolerated without intervention (ESC practice)
MIN_PLANNING_MU = 0.1  #: the margin's floor: it lowers no planning friction below this (nor lifts one)
#: default StabilityController.mu_margin. Measured on the headline matrix before the yaw
#: reference took the weaker axle's friction (DYC-LQR + joint,
#: 2 seeds, peak sideslip [deg] on paper_step / swd_wet / mu_jump / ISO 3888-2 at 70 km/h):
#: margin 0: 0.6 / 2.1 / 1.8 / 3.7; 1: 0.5 / 1.8 / 1.5 / 3.4; 2: 0.5 / 1.7 / 1.4 / 3.1 (ISO
#: 3888-2 cones 4 / 5 / 6; README, "Control"). On the earlier design and plant margin 2 had
#: let the planning friction sink towards MIN_PLANNING_MU after the mu jump (11.4 deg); the
#: default stays 1, chosen then and not re-tuned on the evaluation matrix.
MU_MARGIN = 1.0


def _deadband(x: np.ndarray, width) -> np.ndarray:
    """``x`` shrunk towards zero by ``width`` (zero inside the band, continuous outside)."""
    return np.sign(x) * np.maximum(np.abs(x) - width, 0.0)


class Command(NamedTuple):
    """Controller output for a batch: wheel torques [N m] (B, 4) and rear steer [rad] (B,)."""

    torques: np.ndarray
    rear_steer: np.ndarray


@dataclass
class StabilityController:
    """Reference + yaw-moment law + allocation (+ optional eq. 20 rear steer).

    The yaw-rate reference is the 2-DOF steady state, bounded by the weaker axle's friction
    (:func:`control.reference.weaker_axle_friction`: with the four wheels' mean, a car whose front
    axle had reached an icy patch was turned further in by its rear wheels), passed through a
    first-order lag of the car's natural yaw response (:func:`control.reference.yaw_time_constant`:
    0.036 s at 20 km/h, 0.14 s at 80 km/h), so the controller corrects deviations from how a
    stable car responds rather than the response delay itself. (A fixed 0.15 s, right at
    80-90 km/h, made the controller brake the car's own, faster response at low speed.)
    With the eq. 20 rear steer the controller's rear angle moves at most at the rear servo's
    rate (``params.rear_steer_rate``), so the reference is built on an angle the car has.

    The LQR law is told the moment the allocation delivered (:meth:`LQRYawController.note_delivered`),
    which reaches the car through the actuator lag (:func:`control.dyc.actuator_lag`) it was
    designed with.

    The law acts on the yaw-rate error outside a deadband of 0.02 rad/s (smoothly: the error
    is shrunk by the deadband) and on sideslip beyond half the mu-dependent bound, so that
    it does not fight sensor noise in normal driving, as production ESC does. Moments that
    turn the car further into the bend (understeer correction) fade out linearly as |beta|
    approaches the mu-dependent sideslip bound. Both laws see the shrunk state, the sliding
    mode's model terms included: inside the deadbands its equivalent control is that of a car
    on its reference, so it does not answer the linear model's mismatch with saturating tyres
    where no correction is asked (a review measured a steady 0.48 g turn at 80 km/h: -128 N m,
    against -293 N m with the model terms on the estimate itself).

    The law's moment is the whole yaw moment the four longitudinal tyre forces make: the
    allocator meets it with the steered wheels' lever arms, so a zero moment also cancels the
    small moment that equal drive forces make on steered front wheels (the 2-DOF model the laws
    are designed on has no drive forces). The allocator works with the commanded road-wheel
    angles (the driver's front angle, the controller's own rear angle), not the servos' lagged
    positions, and does not see a rear angle that the plant adds itself
    (``VehicleParams.rear_steer_feedforward``).

    ``last_allocation`` holds the latest :class:`control.allocation.Allocation`: the yaw moment
    and drive force the wheels delivered and whether the demand was feasible (None before the
    first call).

    Cautious friction: the controller plans (reference, sideslip bound, the sliding mode's axle
    saturation, allocation; the LQR's gains depend on speed only) with the lower confidence
    bound ``mu - mu_margin * mu_std`` of the estimate (the margin stops at MIN_PLANNING_MU; an
    estimate already below it, ice, is kept), so a friction the estimator has not yet
    confirmed is not taken for granted. An estimate without
    ``mu_std``, or with zero (the oracle, fixed-mu filters), is used as it is. ``mu_margin=0``
    plans with the point estimate."""

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
        if self.reference_understeer is not None and not (is_number(self.reference_understeer)
                                                          and np.isfinite(self.reference_understeer)
                                                          and self.reference_understeer >= 0.0):
            raise ValueError(f"reference_understeer must be a finite gradient >= 0 [rad s^2/m], got "
                             f"{self.reference_understeer!r}")
        if self.law == "lqr":
            self._law = LQRYawController(self.params, LQRWeights())
        elif self.law == "smc":
            self._law = SlidingModeYawController(self.params)
        else:
            raise ValueError(f"unknown yaw-moment law {self.law!r}; known: ['lqr', 'smc']")
        self._reference = None
        self._rear = None
        self.last_allocation: Allocation | None = None

    def reset(self) -> None:
        self._reference = None
        self._rear = None
        self.last_allocation = None
        self._law.reset()

    def planning_mu(self, estimate) -> np.ndarray:
        """Per-wheel friction (B, 4) the controller plans with (see the class docstring)."""
        mu_std = getattr(estimate, "mu_std", None)
        if mu_std is None or self.mu_margin == 0.0:
            return np.asarray(estimate.mu, dtype=float)
        mu = np.asarray(estimate.mu, dtype=float)
        # the margin stops at the floor; a friction the estimate itself puts below it stays (ice)
        return np.maximum(mu - self.mu_margin * np.asarray(mu_std, dtype=float), np.minimum(mu, MIN_PLANNING_MU))

    def __call__(self, t: np.ndarray, estimate, front_steer: np.ndarray, base_torques: np.ndarray) -> Command:
        u, beta, r = estimate.u, estimate.beta, estimate.r
        mu = self.planning_mu(estimate)
        rear = np.zeros_like(u)
        if self.rear_steer:
            target = rear_steer_feedforward(u, front_steer, self.params)
            if self._rear is None:
                self._rear = np.zeros_like(target)
            step = getattr(self.params, "rear_steer_rate", np.inf) * self.dt
            self._rear = rear = self._rear + np.clip(target - self._rear, -step, step)
        # the 2-DOF steady state of the car as steered (front minus rear road-wheel angle), bounded
        # by the weaker axle's friction: the planning friction of the yaw reference
        steady = reference_yaw_rate(u, front_steer - rear, weaker_axle_friction(mu)[:, None], self.params,
                                    self.reference_understeer)
        # first-order lag: the reference a well-behaved car can follow, not a step it cannot
        if self._reference is None:
            self._reference = steady.copy()
        self._reference = self._reference + (steady - self._reference) * np.minimum(
            self.dt / yaw_time_constant(u, self.params), 1.0)
        r_ref = self._reference
        bound = sideslip_bound(mu)
        shrunk_error = _deadband(r - r_ref, YAW_DEADBAND)
        shrunk_beta = _deadband(beta, 0.5 * bound)
        moment = self._law(u, shrunk_beta, r_ref + shrunk_error, r_ref, front_steer, rear, self.dt, mu)
        # a moment that turns the car further (understeer correction) is faded out as |beta|
        # approaches its bound: at the friction limit more yaw moment only spins the car
        turning_further = np.sign(moment) == np.sign(r_ref)
        fade = np.clip(1.0 - np.abs(beta) / bound, 0.0, 1.0)
        moment = np.where(turning_further, moment * fade, moment)
        moment = np.where(np.abs(u) > ACTIVE_SPEED, moment, 0.0)
        self.last_allocation = allocate_for_estimate(base_torques, moment, estimate, self.params,
                                                     self.friction_ellipse, mu, front_steer, rear)
        if isinstance(self._law, LQRYawController):
            self._law.note_delivered(self.last_allocation.yaw_moment, u, self.dt)
        return Command(self.last_allocation.torques, rear.copy())


def check_controller(controller, source) -> None:
    """ValueError naming ``source`` (a name, or the object) unless ``controller`` has the
    interface of :class:`envs.simulation.Controller` (``reset`` and a call)."""
    if not (callable(controller) and callable(getattr(controller, "reset", None))):
        raise ValueError(f"controller {source!r} lacks reset() or a call, got {controller!r}: give a Controller, "
                         "a name from control.CONTROLLERS or None")


#: the DYC controllers' (law, rear steer) by name
_DYC = {"dyc-lqr": ("lqr", False), "dyc-smc": ("smc", False), "dyc-lqr-4ws": ("lqr", True),
        "dyc-smc-4ws": ("smc", True)}
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
    if name not in _DYC:
        raise ValueError(f"unknown controller {name!r}; known: {list(CONTROLLERS)}")
    law, rear_steer = _DYC[name]
    return StabilityController(params, law, rear_steer=rear_steer, dt=dt, **options)


__all__ = ["CONTROLLERS", "Allocation", "Command", "StabilityController", "allocate_for_estimate", "allocate_torques",
           "check_controller", "make_controller"]

"""A user's own estimator and controller, for the tests that plug them in by ``module:factory``
name (tests/test_custom_models.py): this folder is on sys.path under pytest."""

import numpy as np

from fourwis.core.constants import GRAVITY
from fourwis.core.types import Command
from fourwis.estimation import Estimate, make_estimator


class BiasedFriction:
    """The shipped ``ckf`` reporting mu ``bias`` too high: a friction estimator's typical error."""

    needs_truth = False

    def __init__(self, params, dt, bias=0.1):
        self.inner, self.bias, self.dt = make_estimator("ckf", params, dt), bias, dt

    def reset(self, reading, initial_speed, mask=None):
        self.inner.reset(reading, initial_speed, mask)

    def step(self, reading, truth=None, members=None):
        estimate = self.inner.step(reading, truth, members)
        return estimate._replace(mu=estimate.mu + self.bias)


def biased_friction(params, dt):
    return BiasedFriction(params, dt)


class WrongShape(BiasedFriction):
    """Returns one mu per car instead of one per wheel."""

    def step(self, reading, truth=None, members=None):
        estimate = super().step(reading, truth, members)
        return estimate._replace(mu=estimate.mu[:, 0])


class YawDamper:
    """Differential torque against the estimated yaw rate: Mz = -gain r, split over the axles."""

    def __init__(self, params, dt, gain=2000.0):
        self.params, self.gain = params, gain

    def reset(self):
        pass

    def __call__(self, t, estimate, front_steer, base_torques):
        moment = -self.gain * estimate.r  # [N m]
        force = moment / self.params.track_front / 2  # per wheel, left negative / right positive
        torques = base_torques + np.outer(force * self.params.wheel_radius, [-1.0, 1.0, -1.0, 1.0])
        return Command(torques, np.zeros(len(torques)))


def yaw_damper(params, dt):
    return YawDamper(params, dt)


def bad_gain(params, dt):
    """A factory whose own check rejects its setting (where the run is built: in the worker)."""
    gain = -1.0
    if gain <= 0:
        raise ValueError(f"gain must be > 0, got {gain}")
    return YawDamper(params, dt, gain)


class Diverging(BiasedFriction):
    """Loses the yaw rate: NaN from the first step."""

    def step(self, reading, truth=None, members=None):
        estimate = super().step(reading, truth, members)
        return estimate._replace(r=estimate.r * np.nan)


class ReusesArrays:
    """A complementary sideslip-free filter that writes its estimate into the same arrays every
    step (a common habit of hand-written filters) and has no ``needs_truth``: yaw rate from the
    gyro, speed from the wheels, mu held at 0.8 with no covariance."""

    def __init__(self, params, dt):
        self.params, self.dt = params, dt

    def reset(self, reading, initial_speed, mask=None):
        B = len(reading.values)
        zeros, wheels = np.zeros(B), np.zeros((B, 4))
        self.estimate = Estimate(
            zeros.copy(),
            zeros.copy(),
            zeros.copy(),
            zeros.copy(),
            zeros.copy(),
            zeros.copy(),
            wheels + 0.8,
            wheels + self.params.mass * GRAVITY / 4,
            zeros.copy(),
            wheels.copy(),
        )

    def step(self, reading, truth=None, members=None):
        e, values = self.estimate, reading.values
        e.u[:] = values[:, 3:7].mean(axis=1) * self.params.wheel_radius
        e.r[:], e.ax[:], e.ay[:] = values[:, 2], values[:, 0], values[:, 1]
        return e if members is None else Estimate(*(field[members] for field in e))


def takes_params_only(params):
    return ReusesArrays(params, 0.002)


class NegativeLoads(BiasedFriction):
    """Reports the normal loads with the wrong sign."""

    def step(self, reading, truth=None, members=None):
        estimate = super().step(reading, truth, members)
        return estimate._replace(fz=-estimate.fz)

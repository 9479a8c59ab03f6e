"""State and road-friction estimators on the estimation model, one step interface.

Every estimator here takes a sensor reading (values (B, 13), valid (B, 13): ax, ay, yaw rate,
four wheel speeds, front and rear road-wheel steer, four motor torques) and returns an
:class:`estimation.types.Estimate`. Variants (``StateEstimator(kind=...)``):

* ``ekf``: extended Kalman filter (finite-difference Jacobians of the same model), all
  measurements, nominal mu;
* ``ckf``: one cubature Kalman filter, all measurements, nominal mu;
* ``fkf``: federated CKF, sub-filter 1 [ax, ay, r, wheel speeds], sub-filter 2 [ay, r];
* ``alo-fkf``: the paper's section 3: robust (Huber) sub-filters, Q/R from the ALO tuning
  (estimation/data/tuned_noise.json when present, else the defaults), nominal mu;
* ``joint``: the paper's section 4: the robust state FKF plus a mu FKF (random-walk mu per
  wheel, measured [ax, ay, r] / [ay, r] predicted from the tyre forces) exchanging estimates
  every step.

Deviation from the paper, on purpose: its measurement sets [ax, ay, r] leave u unobservable
(it is only integrated from ax and drifts); sub-filter 1 also measures the four wheel-centre
speeds R*omega (zero-slip model, variance allowing 2% slip) as production ESC speed observers do.

mu is held, not drifting, when it is unobservable: with Dugoff's lambda >= 1 (force demand
below mu*Fz/2) dF/dmu = 0. The cubature points of a wide mu prior still straddle lambda = 1,
so model mismatch would leak into mu: a wheel's mu is therefore updated only while its
lambda at the current estimate is below 1 (all four while any wheel is), and its random-walk
variance growth is capped. The four mu share a correlated prior and random walk (correlation
0.8): a saturating outer wheel informs the lightly loaded inner one, while a split road still
separates left from right over time.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from importlib import resources

import numpy as np

from estimation.ckf import DROPOUT_VARIANCE, ckf_predict, ckf_update
from estimation.federated import SubMeasurement, federated_step
from estimation.model import (Inputs, ModelParams, body_forces, dugoff_lambda, normal_loads, state_transition,
                              tyre_state, wheel_kinematics)
from estimation.types import Estimate

N_STATE = 6
I_U, I_V, I_AX, I_AY, I_R, I_GAMMA = range(N_STATE)
KINDS = ("ekf", "ckf", "fkf", "alo-fkf", "joint")
MU_BOUNDS = (0.1, 1.2)  #: estimated mu stays inside these bounds
EXCITATION_LAMBDA = 1.0  #: a wheel's mu is updated only while its Dugoff lambda is below this


MU_CORRELATION = 0.8  #: prior/random-walk correlation of the four wheels' mu (roads vary smoothly)


def _diag(variances) -> np.ndarray:
    """Diagonal matrices (..., m, m) of m variances, each a scalar or a (B,) array."""
    v = np.stack(np.broadcast_arrays(*[np.asarray(x, dtype=float) for x in variances]), axis=-1)
    return v[..., :, None] * np.eye(v.shape[-1])


def _correlated(variance: float) -> np.ndarray:
    """4x4 covariance with ``variance`` on the diagonal and MU_CORRELATION between wheels."""
    return variance * (MU_CORRELATION + (1.0 - MU_CORRELATION) * np.eye(4))


@dataclass(frozen=True)
class NoiseParams:
    """Filter noise (standard deviations, SI). Process: per 2 ms step on u, v, ax, ay, r, Gamma;
    measurement: accelerometer, gyro (sensor noise plus model error), wheel-speed pseudo
    measurement; mu random walk per step. ALO tuning rescales these."""

    process_std: tuple[float, ...] = (0.01, 0.001, 0.3, 0.3, 0.002, 80.0)
    accel_std: float = 0.15
    gyro_std: float = 0.005
    wheel_speed_std: float = 0.15
    mu_walk_std: float = 2e-3
    mu_accel_std: float = 0.3
    mu_max_std: float = 0.3

    def scaled(self, log10_factors: np.ndarray) -> "NoiseParams":
        """Scale (process_std, accel_std, gyro_std, wheel_speed_std) by 10**factors: (4,) for
        one filter, or (B, 4) for a batch whose members each get their own noise (the scaled
        fields become arrays: process_std (B, 6), the others (B,))."""
        f = 10.0 ** np.asarray(log10_factors, dtype=float)
        if f.shape[-1:] != (4,) or f.ndim > 2 or not np.all(np.isfinite(f)):
            raise ValueError(f"log10 noise factors must be finite with shape (4,) or (B, 4), got {log10_factors!r}")
        if f.ndim == 1:
            return replace(self, process_std=tuple(float(s * f[0]) for s in self.process_std),
                           accel_std=self.accel_std * f[1], gyro_std=self.gyro_std * f[2],
                           wheel_speed_std=self.wheel_speed_std * f[3])
        return replace(self, process_std=np.asarray(self.process_std) * f[:, :1], accel_std=self.accel_std * f[:, 1],
                       gyro_std=self.gyro_std * f[:, 2], wheel_speed_std=self.wheel_speed_std * f[:, 3])


TUNED_NOISE_FILE = "data/tuned_noise.json"  #: inside the estimation package; written by ``fourwis tune``


def tuned_noise(path=None) -> NoiseParams | None:
    """The tuned noise in ``path`` (default: the package's :data:`TUNED_NOISE_FILE`, shipped with
    the ALO result of ``fourwis tune``); None only if that file does not exist (then alo-fkf
    runs the hand-set noise, as documented in make_estimator). A corrupted file raises
    ValueError naming it, never a silent default."""
    path = resources.files("estimation").joinpath(TUNED_NOISE_FILE) if path is None else path
    if not path.is_file():
        return None
    try:
        factors = np.asarray(json.loads(path.read_text())["log10_factors"], dtype=float)
        return NoiseParams().scaled(factors)
    except (ValueError, KeyError, TypeError) as err:
        raise ValueError(f"corrupted tuning file {path}: {err!r}; rerun `fourwis tune` or delete it") from None


STATE_FIELDS = ("x", "P", "mu", "P_mu", "beta", "beta_mu", "omega_prev", "omega_dot", "last_nll")


@dataclass
class StateEstimator:
    """Batched estimator of ``kind`` (see module doc) for model ``params`` at step ``dt`` [s]."""

    params: ModelParams
    kind: str = "joint"
    dt: float = 0.002
    noise: NoiseParams = field(default_factory=NoiseParams)
    nominal_mu: float = 0.8
    huber_c: float = 1.5
    needs_truth: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown estimator kind {self.kind!r}; known: {list(KINDS)}")
        if not (MU_BOUNDS[0] <= self.nominal_mu <= MU_BOUNDS[1]):
            raise ValueError(f"nominal_mu must lie in {MU_BOUNDS}, got {self.nominal_mu!r}")
        if not self.dt > 0:
            raise ValueError(f"dt must be > 0, got {self.dt!r}")
        self.robust = self.kind in ("alo-fkf", "joint")
        self.federated = self.kind in ("fkf", "alo-fkf", "joint")
        self.estimate_mu = self.kind == "joint"
        self.set_noise(self.noise)

    def set_noise(self, noise: NoiseParams) -> None:
        """Use ``noise`` from the next step on (shared, or per member: see NoiseParams.scaled)."""
        self.noise = noise
        var = np.square(np.asarray(noise.process_std, dtype=float))  # (6,) or (B, 6)
        self.Q = var[..., :, None] * np.eye(N_STATE)

    # ---- set-up -------------------------------------------------------------------------
    def reset(self, reading, initial_speed: np.ndarray, mask: np.ndarray | None = None) -> None:
        values = np.asarray(reading.values, dtype=float)
        B = values.shape[0]
        initial_speed = np.broadcast_to(np.asarray(initial_speed, dtype=float), (B,))
        x0 = np.zeros((B, N_STATE))
        x0[:, I_U] = initial_speed
        x0[:, I_AX], x0[:, I_AY], x0[:, I_R] = values[:, 0], values[:, 1], values[:, 2]
        P0 = np.broadcast_to(np.diag([0.5, 0.3, 1.0, 1.0, 0.02, 500.0]) ** 2, (B, N_STATE, N_STATE))
        mu0 = np.full((B, 4), self.nominal_mu)
        Pmu0 = np.broadcast_to(_correlated(0.3**2), (B, 4, 4))
        if mask is None or not hasattr(self, "x"):
            self.x, self.P = x0, P0.copy()
            self.mu, self.P_mu = mu0, Pmu0.copy()
            self.beta = np.full((B, 2), 0.5)
            self.beta_mu = np.full((B, 2), 0.5)
            self.omega_prev = values[:, 3:7].copy()
            self.omega_dot = np.zeros((B, 4))
        else:
            for name, new in (("x", x0), ("P", P0), ("mu", mu0), ("P_mu", Pmu0), ("omega_prev", values[:, 3:7])):
                getattr(self, name)[mask] = new[mask]
            self.beta[mask] = 0.5
            self.beta_mu[mask] = 0.5
            self.omega_dot[mask] = 0.0
        self.last_nll = np.zeros(B)

    # ---- one step -----------------------------------------------------------------------
    def _inputs(self, values: np.ndarray) -> Inputs:
        omega = values[:, 3:7]
        # wheel angular acceleration for eq. 7: differentiated wheel speed, 20 ms low-pass
        raw = (omega - self.omega_prev) / self.dt
        self.omega_dot += (raw - self.omega_dot) * (self.dt / 0.02)
        self.omega_prev = omega.copy()
        delta = np.stack([values[:, 7], values[:, 7], values[:, 8], values[:, 8]], axis=1)
        return Inputs(delta, omega, values[:, 9:13], self.omega_dot.copy())

    def step(self, reading, truth: Estimate | None = None, members: np.ndarray | None = None) -> Estimate:
        """One filter step on ``reading`` (values and valid (B, 13)); with ``members`` (M,) indices
        only those rows step (the others keep their state) and the estimate has M rows."""
        values = np.asarray(reading.values, dtype=float)
        valid = np.asarray(reading.valid, dtype=bool)
        if values.shape != (self.x.shape[0], 13):
            raise ValueError(f"sensor reading must have shape {(self.x.shape[0], 13)}, got {values.shape}")
        if members is None:
            return self._step(values, valid)
        full = {name: getattr(self, name) for name in STATE_FIELDS}
        try:
            for name, value in full.items():
                setattr(self, name, value[members])
            estimate = self._step(values[members], valid[members])
            for name, value in full.items():
                value[members] = getattr(self, name)
        finally:
            for name, value in full.items():
                setattr(self, name, value)
        return estimate

    def _step(self, values: np.ndarray, valid: np.ndarray) -> Estimate:
        inputs = self._inputs(values)
        p, dt, n = self.params, self.dt, self.noise
        # inputs broadcast over the cubature point axis
        point_inputs = Inputs(*(q[:, None, :] for q in inputs))
        mu_points = self.mu[:, None, :]

        def f(points: np.ndarray) -> np.ndarray:
            return state_transition(points, mu_points, point_inputs, p, dt)

        wheel_speed_z = values[:, 3:7] * p.wheel_radius

        def h_wheels(points: np.ndarray) -> np.ndarray:
            _, along = wheel_kinematics(points[..., I_U], points[..., I_V], points[..., I_R], point_inputs.delta, p)
            return along

        def h1(points):
            return np.concatenate([points[..., [I_AX, I_AY, I_R]], h_wheels(points)], axis=-1)

        def h2(points):
            return points[..., [I_AY, I_R]]

        z1 = np.concatenate([values[:, 0:3], wheel_speed_z], axis=1)
        valid1 = np.concatenate([valid[:, 0:3], valid[:, 3:7]], axis=1)
        R1 = _diag([n.accel_std**2, n.accel_std**2, n.gyro_std**2] + [n.wheel_speed_std**2] * 4)
        z2, valid2 = values[:, 1:3], valid[:, 1:3]
        R2 = _diag([n.accel_std**2, n.gyro_std**2])
        huber = self.huber_c if self.robust else None

        if self.federated:
            out = federated_step(self.x, self.P, f, self.Q,
                                 [SubMeasurement(z1, h1, R1, valid1), SubMeasurement(z2, h2, R2, valid2)],
                                 self.beta, huber_c=huber)
            self.x, self.P, self.beta = out.x, out.P, out.beta
            self.last_nll = out.nll[0] + out.nll[1]
        elif self.kind == "ckf":
            x_pred, P_pred = ckf_predict(self.x, self.P, f, self.Q)
            upd = ckf_update(x_pred, P_pred, z1, h1, R1, valid=valid1)
            self.x, self.P, self.last_nll = upd.x, upd.P, upd.nll
        else:
            self._ekf_step(f, h1, z1, R1, valid1)
        if self.estimate_mu:
            self._mu_step(values, valid, inputs)
        return self._estimate()

    def _ekf_step(self, f, h, z, R, valid) -> None:
        """EKF on the same model: central-difference Jacobians (the cubature points with a
        small spread give exactly those differences)."""
        B, N = self.x.shape
        eps = 1e-4 * np.maximum(np.abs(self.x), 1e-2)  # (B, n)
        probe = self.x[:, None, :] + np.concatenate([np.eye(N)[None] * eps[:, None, :],
                                                      -np.eye(N)[None] * eps[:, None, :]], axis=1)
        probe = np.concatenate([self.x[:, None, :], probe], axis=1)
        fx = f(probe)
        F = np.swapaxes((fx[:, 1:N + 1] - fx[:, N + 1:]) / (2 * eps[:, :, None]), 1, 2)
        x_pred = fx[:, 0]
        P_pred = F @ self.P @ np.swapaxes(F, 1, 2) + self.Q
        probe = x_pred[:, None, :] + np.concatenate([np.eye(N)[None] * eps[:, None, :],
                                                      -np.eye(N)[None] * eps[:, None, :]], axis=1)
        probe = np.concatenate([x_pred[:, None, :], probe], axis=1)
        hx = h(probe)
        H = np.swapaxes((hx[:, 1:N + 1] - hx[:, N + 1:]) / (2 * eps[:, :, None]), 1, 2)
        Rv = np.broadcast_to(R, (B,) + R.shape[-2:]).copy()
        idx = np.arange(z.shape[1])
        Rv[:, idx, idx] = np.where(valid, Rv[:, idx, idx], DROPOUT_VARIANCE)
        nu = np.where(valid, z - hx[:, 0], 0.0)
        S = H @ P_pred @ np.swapaxes(H, 1, 2) + Rv
        K = np.swapaxes(np.linalg.solve(S, H @ P_pred), 1, 2)
        self.x = x_pred + np.einsum("bij,bj->bi", K, nu)
        I_KH = np.eye(N) - K @ H
        self.P = I_KH @ P_pred @ np.swapaxes(I_KH, 1, 2) + K @ Rv @ np.swapaxes(K, 1, 2)
        self.last_nll = 0.5 * np.einsum("bi,bi->b", nu, np.linalg.solve(S, nu[..., None])[..., 0])

    def _mu_step(self, values: np.ndarray, valid: np.ndarray, inputs: Inputs) -> None:
        """mu FKF: random walk; sub-filter 1 measures [ax, ay, r], sub-filter 2 [ay, r], both
        predicted by the tyre model at the state filter's estimate (r one step ahead)."""
        p, dt, n = self.params, self.dt, self.noise
        x = self.x
        point_inputs = Inputs(*(q[:, None, :] for q in inputs))
        u, v, r = (x[:, None, i] for i in (I_U, I_V, I_R))
        ax, ay = x[:, None, I_AX], x[:, None, I_AY]
        r_prev = r - dt * x[:, None, I_GAMMA] / p.yaw_inertia

        def predicted(mu_points: np.ndarray) -> np.ndarray:
            ax_m, ay_m, gamma = body_forces(u, v, r, ax, ay, mu_points, point_inputs, p)
            return np.stack([ax_m, ay_m, r_prev + dt * gamma / p.yaw_inertia], axis=-1)

        def h2(mu_points):
            return predicted(mu_points)[..., 1:]

        Q_mu = _correlated(n.mu_walk_std**2)
        R1 = _diag([n.mu_accel_std**2, n.mu_accel_std**2, n.gyro_std**2])
        R2 = _diag([n.mu_accel_std**2, n.gyro_std**2])
        out = federated_step(self.mu, self.P_mu, lambda m: m, Q_mu,
                             [SubMeasurement(values[:, 0:3], predicted, R1, valid[:, 0:3]),
                              SubMeasurement(values[:, 1:3], h2, R2, valid[:, 1:3])],
                             self.beta_mu, huber_c=self.huber_c)
        # hold mu where the tyre is far from saturation (Dugoff lambda >= EXCITATION_LAMBDA)
        excited = np.any(self._excitation(inputs) < EXCITATION_LAMBDA, axis=1, keepdims=True)
        self.mu = np.where(excited, np.clip(out.x, *MU_BOUNDS), self.mu)
        # cap the random walk's growth where mu is unobservable
        var = np.diagonal(out.P, axis1=1, axis2=2)
        scale = np.sqrt(np.minimum(var, n.mu_max_std**2) / np.maximum(var, 1e-300))
        self.P_mu = out.P * scale[:, :, None] * scale[:, None, :]
        self.beta_mu = out.beta

    def _excitation(self, inputs: Inputs) -> np.ndarray:
        """Dugoff lambda (B, 4) of each wheel at the current estimates: small = saturating."""
        x = self.x
        tyre = tyre_state(x[:, I_U], x[:, I_V], x[:, I_R], x[:, I_AX], x[:, I_AY], inputs, self.params)
        return dugoff_lambda(tyre.fz, tyre.slip, tyre.alpha, self.mu, tyre.cx, tyre.cy)

    def _estimate(self) -> Estimate:
        x, P = self.x, self.P
        u, v = x[:, I_U], x[:, I_V]
        denom = np.maximum(u**2 + v**2, 1.0)
        grad_u, grad_v = -v / denom, u / denom
        beta_var = grad_u**2 * P[:, I_U, I_U] + 2 * grad_u * grad_v * P[:, I_U, I_V] + grad_v**2 * P[:, I_V, I_V]
        mu_std = np.sqrt(np.diagonal(self.P_mu, axis1=1, axis2=2)) if self.estimate_mu else np.zeros_like(self.mu)
        return Estimate(u=u.copy(), v=v.copy(), beta=np.arctan2(v, np.abs(u)), r=x[:, I_R].copy(),
                        ax=x[:, I_AX].copy(), ay=x[:, I_AY].copy(), mu=self.mu.copy(),
                        fz=normal_loads(x[:, I_AX], x[:, I_AY], self.params),
                        beta_std=np.sqrt(np.maximum(beta_var, 0.0)), mu_std=mu_std)

"""Online re-tuning of a filter's noise on a sliding window of its own innovations.

The paper's real-time rule (section 3.3): the antlion optimizer (or CMA-ES / random search,
``method``) re-tunes Q and R while the filter runs, and a result takes effect only when an
optimizer run finishes; until then the filter keeps the noise it has. Here every ``window`` steps the readings of
the last window
and the filter's state at its start are handed to an optimizer run. Each candidate (log10
factors on the base noise, as in the offline tuning) is scored by replaying the window from
that state, all candidates of a population at once (one batched filter with per-member
noise), and summing the innovation negative log-likelihood
``0.5 (nu^T S^-1 nu + log det S + m log 2 pi)`` of every step.

Why the likelihood: a fixed-weight sum of squared innovations is minimised by scaling Q and R
down together (the filter becomes overconfident and the innovations do not change), while
the log det S term penalises exactly that; the NLL is the criterion of maximum-likelihood
noise identification (Mehra 1970).

Compute budget: each filter step advances the replay by at most ``replay_per_step`` steps of
the batched population (one compiled step of a batch of ``n_agents`` filters; with the
defaults one run takes (iterations + 1) x ceil(window / replay_per_step) filter steps, 2.5 s of
driving). The optimizer itself runs in a helper thread that only computes while the filter
waits for its next population, so results are deterministic.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from fourwis.core.checks import is_integer
from fourwis.core.types import Estimate
from fourwis.estimation.joint import FilterState, StateEstimator
from fourwis.estimation.optimizers import METHODS, minimize

BOUNDS = [(-1.0, 1.0)] * 4  #: log10 factors on (process, accelerometer, gyro, wheel-speed) noise


class _Abort(Exception):
    """Stops an optimizer run (reset of the tuned filter)."""


class WindowReplay:
    """Scores noise candidates on a window: replays readings ``values``/``valid`` (W, N_CHANNELS) from
    filter state ``snapshot`` (a single vehicle's :class:`FilterState`) with one batched filter whose
    members use ``template``'s base noise scaled by ``factors`` (N, 4); ``cost`` (N,) sums
    each member's innovation NLL (inf for a member whose filter failed; the others replay on).
    :meth:`advance` runs a bounded number of steps, so the work can be spread over filter steps."""

    def __init__(
        self,
        template: StateEstimator,
        base_noise,
        snapshot: FilterState,
        values: np.ndarray,
        valid: np.ndarray,
        factors: np.ndarray,
    ):
        n = len(factors)
        self.filter = replace(template, noise=base_noise.scaled(factors))  # its settings, fresh state
        self.filter.state = FilterState(*(np.repeat(value, n, axis=0) for value in snapshot))
        self.values, self.valid = values, valid
        self.k, self.cost = 0, np.zeros(n)

    @property
    def done(self) -> bool:
        return self.k >= len(self.values)

    def advance(self, steps: int) -> int:
        """Replay up to ``steps`` more steps; returns how many ran."""
        ran = 0
        n = len(self.cost)
        while ran < steps and not self.done:
            reading = SimpleNamespace(
                values=np.repeat(self.values[self.k][None], n, 0), valid=np.repeat(self.valid[self.k][None], n, 0)
            )
            alive = np.flatnonzero(np.isfinite(self.cost))
            try:
                self.filter.step(reading, members=alive)
            except ValueError:  # a member failed: its last_nll is NaN, its cost inf; the others stepped
                pass
            except (FloatingPointError, np.linalg.LinAlgError):
                self.cost[:] = np.inf
            nll = self.filter.state.last_nll[alive]
            self.cost[alive] += np.where(np.isfinite(nll), nll, np.inf)
            self.k = self.k + 1 if np.isfinite(self.cost).any() else len(self.values)
            ran += 1
        return ran


class OnlineTuner:
    """Wraps a single-vehicle :class:`StateEstimator` and re-tunes its noise while it runs
    (see the module docstring). ``factors`` holds the log10 factors in force (None: base
    noise); ``runs_completed`` counts finished optimizer runs."""

    needs_truth = False

    def __init__(
        self,
        estimator: StateEstimator,
        window: int = 250,
        n_agents: int = 6,
        iterations: int = 4,
        replay_per_step: int = 1,
        seed: int = 0,
        bounds=BOUNDS,
        method: str = "alo",
    ):
        for name, value in (
            ("window", window),
            ("n_agents", n_agents),
            ("iterations", iterations),
            ("replay_per_step", replay_per_step),
        ):
            if not (is_integer(value) and value >= 1):
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if method not in METHODS:
            raise ValueError(f"unknown optimizer {method!r}; known: {list(METHODS)}")
        if not isinstance(estimator, StateEstimator):
            raise ValueError(
                f"OnlineTuner wraps a StateEstimator (make_estimator('joint', params, dt)), got {estimator!r}"
            )
        self.estimator, self.base_noise, self.method = estimator, estimator.noise, method
        self.window, self.n_agents, self.iterations = window, n_agents, iterations
        self.replay_per_step, self.seed, self.bounds = replay_per_step, seed, bounds
        self.factors: np.ndarray | None = None
        self.runs_completed = 0
        self.max_replay_steps_in_a_step = 0
        self._thread: threading.Thread | None = None

    # ---- the filter side ----------------------------------------------------------------
    @property
    def dt(self) -> float:
        """The tuned filter's step [s]."""
        return self.estimator.dt

    def reset(self, reading, initial_speed: np.ndarray, mask: np.ndarray | None = None) -> None:
        if np.asarray(reading.values).shape[0] != 1:
            raise ValueError("OnlineTuner tunes one vehicle's filter; use one tuner per vehicle")
        self._stop()
        self.estimator.set_noise(self.base_noise)
        self.estimator.reset(reading, initial_speed, mask)
        self.factors, self.runs_completed, self._k, self._seed_counter = None, 0, 0, self.seed
        self._snapshot = self._state()
        self._values, self._valid = [], []

    def step(self, reading, truth: Estimate | None = None, members: np.ndarray | None = None) -> Estimate:
        if members is not None:
            raise ValueError("OnlineTuner runs a single vehicle; members is not supported")
        self._advance_replay()
        estimate = self.estimator.step(reading)
        self._values.append(np.array(reading.values[0], dtype=float))
        self._valid.append(np.array(reading.valid[0], dtype=bool))
        self._k += 1
        if self._k % self.window == 0:
            if self._thread is None:
                self._start(self._snapshot, np.array(self._values), np.array(self._valid))
            self._snapshot, self._values, self._valid = self._state(), [], []
        return estimate

    def _state(self) -> FilterState:
        return FilterState(*(np.array(value, copy=True) for value in self.estimator.state))

    # ---- optimizer runs -----------------------------------------------------------------
    def _start(self, snapshot: FilterState, values: np.ndarray, valid: np.ndarray) -> None:
        self._run_data = (snapshot, values, valid)
        self._jobs: queue.Queue = queue.Queue()
        self._results: queue.Queue = queue.Queue()
        seed = self._seed_counter
        self._seed_counter += 1

        def objective(X: np.ndarray) -> np.ndarray:
            self._jobs.put(("job", np.array(X)))
            costs = self._results.get()
            if costs is None:
                raise _Abort
            return costs

        def run() -> None:
            try:
                result = minimize(objective, self.bounds, self.method, self.n_agents, self.iterations, seed)
            except _Abort:
                return
            self._jobs.put(("done", result.x))

        self._thread = threading.Thread(target=run, daemon=True, name="online-noise-tuning")
        self._thread.start()
        self._take_message()

    def _take_message(self) -> None:
        """Wait for the optimizer's next population (or its result) and set up its replay."""
        kind, payload = self._jobs.get()
        if kind == "done":
            self._thread.join()
            self._thread = None
            self.factors = payload
            self.estimator.set_noise(self.base_noise.scaled(payload))
            self.runs_completed += 1
            return
        snapshot, values, valid = self._run_data
        self._replay = WindowReplay(self.estimator, self.base_noise, snapshot, values, valid, payload)

    def _advance_replay(self) -> None:
        """At most ``replay_per_step`` batched replay steps; hands costs back when a window is done."""
        if self._thread is None:
            return
        ran = self._replay.advance(self.replay_per_step)
        self.max_replay_steps_in_a_step = max(self.max_replay_steps_in_a_step, ran)
        if self._replay.done:
            self._results.put(self._replay.cost.copy())
            self._take_message()

    def _stop(self) -> None:
        if self._thread is not None:
            self._results.put(None)
            self._thread.join()
            self._thread = None

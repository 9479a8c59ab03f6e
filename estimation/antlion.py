"""Antlion optimizer (Mirjalili, "The Ant Lion Optimizer", Adv. Eng. Software 83, 2015),
as the paper uses it to tune its filters' noise (section 3.3), with a batched objective.

Each iteration every ant walks randomly (cumulative sums of +/-1 steps, min-max normalised
into a box around an antlion that shrinks as the iterations go: the ant sliding into the
trap), around an antlion chosen by roulette and around the elite; its position is the mean
of the two walks. Fitter ants replace antlions; the elite is kept (elitism).

Minimisation: roulette weights are 1 / rank (rank 1 = lowest cost), a scale-free choice
that works for costs of any sign (Mirjalili's weights assume positive fitness to maximise).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from fourwis.core.checks import is_integer


@dataclass(frozen=True)
class OptimizeResult:
    """Best point ``x`` (d,), its cost ``fun``, best cost per iteration ``history``, evaluations."""

    x: np.ndarray
    fun: float
    history: np.ndarray
    n_evaluations: int


def check_bounds(bounds) -> tuple[np.ndarray, np.ndarray]:
    b = np.asarray(bounds, dtype=float)
    if b.ndim != 2 or b.shape[1] != 2 or not np.all(np.isfinite(b)):
        raise ValueError(f"bounds must be a finite (d, 2) array, got {b!r}")
    if np.any(b[:, 0] >= b[:, 1]):
        raise ValueError(f"every lower bound must be below its upper bound, got {b.tolist()}")
    return b[:, 0], b[:, 1]


def evaluate_population(fun: Callable[[np.ndarray], np.ndarray], X: np.ndarray) -> np.ndarray:
    costs = np.asarray(fun(X), dtype=float).reshape(-1)
    if costs.shape != (len(X),):
        raise ValueError(f"objective must return {len(X)} costs, got shape {costs.shape}")
    return np.where(np.isnan(costs), np.inf, costs)  # a failed candidate is the worst one


def _shrink_ratio(t: int, iterations: int) -> float:
    """I = 10^w t / T with w = 2, 3, 4, 5, 6 after 10, 50, 75, 90, 95% of the iterations."""
    frac = t / iterations
    w = 0
    for threshold, value in ((0.1, 2), (0.5, 3), (0.75, 4), (0.9, 5), (0.95, 6)):
        if frac > threshold:
            w = value
    return max(1.0, 10.0**w * frac)


def _walk(
    rng: np.random.Generator,
    steps: int,
    t: int,
    around: np.ndarray,
    half_width: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    ratio: float,
) -> np.ndarray:
    """Positions at step ``t`` of random walks for each row of ``around`` (n, d): the walk is
    min-max normalised into [around - half_width / I, around + half_width / I] and clipped to
    the bounds (Mirjalili's eq. 2.1-2.3 and 2.10-2.11 with the box centred on the antlion)."""
    n, d = around.shape
    walks = np.cumsum(np.where(rng.random((n, steps, d)) > 0.5, 1.0, -1.0), axis=1)
    a, b, value = walks.min(axis=1), walks.max(axis=1), walks[:, t - 1]
    lo, hi = around - half_width / ratio, around + half_width / ratio
    span = np.where(b > a, b - a, 1.0)
    return np.clip((value - a) / span * (hi - lo) + lo, lower, upper)


def check_budget(n_agents, iterations) -> None:
    """ValueError unless ``n_agents`` >= 2 and ``iterations`` >= 1 are integers."""
    if not (is_integer(n_agents) and is_integer(iterations) and n_agents >= 2 and iterations >= 1):
        raise ValueError(f"need integers n_agents >= 2 and iterations >= 1, got {n_agents!r}, {iterations!r}")


def antlion(
    fun: Callable[[np.ndarray], np.ndarray],
    bounds,
    n_agents: int = 20,
    iterations: int = 50,
    rng: np.random.Generator | int = 0,
    progress: bool = False,
) -> OptimizeResult:
    """Minimise ``fun`` (K, d) -> (K,) over the box ``bounds`` (d, 2); one ``fun`` call per iteration."""
    lower, upper = check_bounds(bounds)
    check_budget(n_agents, iterations)
    rng = np.random.default_rng(rng)
    d = len(lower)
    antlions = lower + rng.random((n_agents, d)) * (upper - lower)
    costs = evaluate_population(fun, antlions)
    order = np.argsort(costs)
    antlions, costs = antlions[order], costs[order]
    history, evaluations = [], n_agents
    for t in tqdm(range(1, iterations + 1), disable=not progress, desc="antlion", unit="iter"):
        ratio = _shrink_ratio(t, iterations)
        weights = 1.0 / np.arange(1, n_agents + 1)
        chosen = rng.choice(n_agents, size=n_agents, p=weights / weights.sum())
        half_width = (upper - lower) / 2
        walk_chosen = _walk(rng, iterations, t, antlions[chosen], half_width, lower, upper, ratio)
        walk_elite = _walk(
            rng, iterations, t, np.repeat(antlions[:1], n_agents, axis=0), half_width, lower, upper, ratio
        )
        ants = np.clip((walk_chosen + walk_elite) / 2, lower, upper)
        ant_costs = evaluate_population(fun, ants)
        evaluations += n_agents
        pool = np.vstack([antlions, ants])
        pool_costs = np.concatenate([costs, ant_costs])
        best = np.argsort(pool_costs, kind="stable")[:n_agents]
        antlions, costs = pool[best], pool_costs[best]
        history.append(costs[0])
    return OptimizeResult(antlions[0].copy(), float(costs[0]), np.array(history), evaluations)

"""One interface to the noise-tuning optimizers, each evaluating a whole population per call.

``minimize(fun, bounds, method, n_agents, iterations, seed)`` with ``fun`` (K, d) -> (K,):

* ``alo``: the antlion optimizer (the paper's; :mod:`estimation.antlion`);
* ``cmaes``: CMA-ES (Hansen's ``cma`` package, ask/tell), population ``n_agents``, start at
  the box centre with step size a quarter of the mean box width, box bounds handled by
  ``cma``'s boundary transformation; non-finite costs are replaced by a large finite value
  (``cma`` needs finite ranks);
* ``random``: uniform random search in the box, the baseline any tuner must beat.

All get the same budget: ``n_agents * (iterations + 1)`` evaluations (ALO's initial
population plus one per iteration). ``history`` is the best cost so far per iteration.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from tqdm import tqdm

from fourwis.core.checks import is_integer
from fourwis.estimation.antlion import OptimizeResult, antlion, check_bounds, check_budget, evaluate_population

METHODS = ("alo", "cmaes", "random")
CMA_SIGMA_FRACTION = 0.25  #: CMA-ES initial step size as a fraction of the mean box width
NON_FINITE_COST = 1e30  #: stands in for inf/NaN costs in CMA-ES's ranking


def minimize(
    fun: Callable[[np.ndarray], np.ndarray],
    bounds,
    method: str = "alo",
    n_agents: int = 20,
    iterations: int = 50,
    seed: int = 0,
    progress: bool = False,
) -> OptimizeResult:
    """Minimise ``fun`` over the box ``bounds`` (d, 2) with ``method`` (see module docstring)."""
    if method not in METHODS:
        raise ValueError(f"unknown optimizer {method!r}; known: {list(METHODS)}")
    if not (is_integer(seed) and seed >= 0):  # (cma takes seed + 1 = 0 as "draw one at random")
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if method == "alo":
        return antlion(fun, bounds, n_agents=n_agents, iterations=iterations, rng=seed, progress=progress)
    lower, upper = check_bounds(bounds)
    check_budget(n_agents, iterations)
    # cma reseeds numpy's global generator: give it back after
    global_state = np.random.get_state()  # noqa: NPY002
    try:
        return _search(fun, lower, upper, method, n_agents, iterations, seed, progress)
    finally:
        np.random.set_state(global_state)  # noqa: NPY002


def _search(fun, lower, upper, method, n_agents, iterations, seed, progress) -> OptimizeResult:
    """CMA-ES or random search over the box [lower, upper] (see :func:`minimize`)."""
    best_x, best, history = None, np.inf, []
    if method == "cmaes":
        import cma

        es = cma.CMAEvolutionStrategy(
            (lower + upper) / 2,
            CMA_SIGMA_FRACTION * float(np.mean(upper - lower)),
            {"bounds": [list(lower), list(upper)], "popsize": n_agents, "seed": seed + 1, "verbose": -9},
        )

        def population() -> np.ndarray:
            return np.array(es.ask())
    else:
        rng = np.random.default_rng(seed)

        def population() -> np.ndarray:
            return lower + rng.random((n_agents, len(lower))) * (upper - lower)

    for _ in tqdm(range(iterations + 1), disable=not progress, desc=method, unit="iter"):
        X = np.clip(population(), lower, upper)
        costs = evaluate_population(fun, X)
        if method == "cmaes":
            es.tell(list(X), list(np.where(np.isfinite(costs), costs, NON_FINITE_COST)))
        k = int(np.argmin(costs))
        if costs[k] < best:
            best, best_x = float(costs[k]), X[k].copy()
        history.append(best)
    if best_x is None:
        raise FloatingPointError("every evaluation returned a non-finite cost")
    return OptimizeResult(best_x, best, np.array(history[1:]), n_agents * (iterations + 1))

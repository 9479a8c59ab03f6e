"""Antlion optimizer: finds minima, beats random search at equal budget, deterministic, errors."""

import numpy as np
import pytest

from fourwis.estimation.antlion import antlion


def sphere(X):
    return np.sum((X - 0.3) ** 2, axis=1)


def rastrigin(X):
    Z = X - 0.5
    return 10 * Z.shape[1] + np.sum(Z**2 - 10 * np.cos(2 * np.pi * Z), axis=1)


def test_finds_the_minimum_of_a_shifted_sphere():
    res = antlion(sphere, [(-5, 5)] * 4, n_agents=20, iterations=100, rng=1)
    assert res.fun < 1e-4
    np.testing.assert_allclose(res.x, 0.3, atol=0.02)
    assert np.all(np.diff(res.history) <= 0)  # elitism: the best never gets worse
    assert res.n_evaluations == 20 * 101


def test_beats_random_search_at_the_same_budget():
    bounds = [(-5.12, 5.12)] * 3
    alo = [antlion(rastrigin, bounds, 20, 60, rng=s).fun for s in range(5)]
    rand = []
    for s in range(5):
        X = np.random.default_rng(s).uniform(-5.12, 5.12, (20 * 61, 3))
        rand.append(rastrigin(X).min())
    assert np.median(alo) < np.median(rand)


def test_deterministic_under_a_seed_and_within_bounds():
    a = antlion(rastrigin, [(-2, 3), (0, 1)], 10, 20, rng=5)
    b = antlion(rastrigin, [(-2, 3), (0, 1)], 10, 20, rng=5)
    np.testing.assert_array_equal(a.x, b.x)
    assert -2 <= a.x[0] <= 3 and 0 <= a.x[1] <= 1


def test_nan_costs_lose_and_bad_bounds_raise():
    res = antlion(lambda X: np.where(X[:, 0] > 0, np.nan, X[:, 0] ** 2), [(-1, 1)], 10, 20, rng=0)
    assert np.isfinite(res.fun) and res.x[0] <= 0
    with pytest.raises(ValueError, match="lower bound"):
        antlion(sphere, [(1, 0)])
    with pytest.raises(ValueError, match="finite"):
        antlion(sphere, [(0, np.nan)])

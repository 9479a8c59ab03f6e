"""State and road-friction estimation: the paper's joint antlion-federated cubature Kalman
estimator, its building blocks and baselines, behind one factory and one step interface."""

from __future__ import annotations

from estimation.oracle import Oracle
from estimation.types import Estimate

ESTIMATORS = ("oracle",)


def make_estimator(name: str, params, dt: float = 0.002, **kwargs):
    """Build the estimator ``name`` for vehicle ``params`` (duck-typed VehicleParams) and step ``dt`` [s]."""
    if name == "oracle":
        return Oracle()
    raise ValueError(f"unknown estimator {name!r}; known: {list(ESTIMATORS)}")


__all__ = ["ESTIMATORS", "Estimate", "make_estimator"]

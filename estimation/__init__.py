"""State and road-friction estimation: the paper's joint antlion-federated cubature Kalman
estimator, its building blocks and baselines, behind one factory and one step interface."""

from __future__ import annotations

from estimation.joint import KINDS, NoiseParams, StateEstimator, tuned_noise
from estimation.model import ModelParams
from estimation.online import OnlineTuner
from estimation.oracle import Oracle
from estimation.types import Estimate

ESTIMATORS = ("oracle",) + KINDS  #: names accepted by make_estimator; "joint" is the paper's full system


def make_estimator(name: str, params, dt: float = 0.002, noise: NoiseParams | None = None, **kwargs):
    """Build the estimator ``name`` (see :data:`ESTIMATORS`) for vehicle ``params`` (duck-typed
    VehicleParams) at step ``dt`` [s]. ``alo-fkf`` and ``joint`` (the paper's antlion-tuned
    filters) use the ALO-tuned noise shipped in estimation/data/tuned_noise.json (``fourwis
    tune`` rewrites it; without the file they run the hand-set noise); ``noise`` overrides it."""
    if name == "oracle":
        return Oracle()
    if name not in KINDS:
        raise ValueError(f"unknown estimator {name!r}; known: {list(ESTIMATORS)}")
    if noise is None:
        noise = (tuned_noise() if name in ("alo-fkf", "joint") else None) or NoiseParams()
    return StateEstimator(ModelParams.from_vehicle(params), kind=name, dt=dt, noise=noise, **kwargs)


__all__ = ["ESTIMATORS", "Estimate", "ModelParams", "NoiseParams", "OnlineTuner", "StateEstimator",
           "make_estimator", "tuned_noise"]

"""State and road-friction estimation: the paper's joint antlion-federated cubature Kalman
estimator, its building blocks and baselines, behind one factory and one step interface."""

from __future__ import annotations

from dataclasses import fields

from fourwis.core.checks import check_estimator, check_step, check_vehicle_params, import_factory
from fourwis.core.types import Estimate
from fourwis.estimation.baselines import BASELINES, make_baseline
from fourwis.estimation.joint import KINDS, TUNED_KINDS, NoiseParams, StateEstimator, tuned_noise
from fourwis.estimation.model import AxleTyre, ModelParams
from fourwis.estimation.online import OnlineTuner
from fourwis.estimation.oracle import TRUE_SUFFIX, TRUTH_GROUPS, Oracle, PartialOracle, parse_truth_groups

#: the estimators' names (make_estimator); "joint-paper" is the paper's full system as shipped before
#: issue 41, "joint" the same system with the fixes of docs/decisions/0034-0036
ESTIMATORS = ("oracle",) + KINDS
#: make_estimator also builds the BASELINES (estimation.baselines): a linear single-track Kalman
#: observer, the steady-state single-track sideslip and beta = 0


def parse_estimator_name(name: str) -> tuple[str, tuple[str, ...]]:
    """(base estimator, truth groups) of ``name`` (see :func:`check_estimator_name`)."""
    if not isinstance(name, str):
        raise ValueError(
            f"an estimator is given by name, got {name!r}: pass your own as 'module:factory' "
            "(factory(params, dt) -> estimator), or the object itself to envs.simulate"
        )
    base, sep, groups = name.partition(TRUE_SUFFIX)
    if ":" in base:
        import_factory(base, "estimator")
    elif base not in ESTIMATORS + BASELINES:
        raise ValueError(
            f"unknown estimator {name!r}; known: {list(ESTIMATORS + BASELINES)} or 'module:factory' for your own, "
            f"each optionally with '{TRUE_SUFFIX}<group>[-<group>...]', groups {list(TRUTH_GROUPS)}"
        )
    return base, parse_truth_groups(groups) if sep else ()


def check_estimator_name(name: str) -> str:
    """``name`` if make_estimator accepts it: one of :data:`ESTIMATORS` or :data:`BASELINES` or ``module:factory``,
    optionally followed by ``+true-<group>[-<group>...]`` (:data:`TRUTH_GROUPS`); else
    ValueError naming it."""
    parse_estimator_name(name)
    return name


def make_estimator(
    name: str,
    params,
    dt: float = 0.002,
    noise: NoiseParams | None = None,
    tyre_relaxation: bool | None = None,
    tyres: tuple[AxleTyre, AxleTyre] | None = None,
    **kwargs,
):
    """Build the estimator ``name`` (see :data:`ESTIMATORS` and :data:`BASELINES`) for vehicle
    ``params`` (duck-typed VehicleParams) at step ``dt`` [s] (its nominal step: fourwis's
    estimators step by the readings' times). ``alo-fkf``, ``joint-paper`` and ``joint`` (the paper's
    antlion-tuned filters) use the ALO-tuned noise shipped in estimation/data/tuned_noise.json
    (``fourwis tune`` rewrites it; without the file they run the hand-set noise); ``noise``
    overrides it. ``<name>+true-<group>[-<group>...]`` (e.g. ``joint+true-mu``) reports the
    truth for those groups (:class:`PartialOracle`, :data:`TRUTH_GROUPS`): which estimated
    quantity a closed-loop loss comes from. ``tyre_relaxation``: the model's slip angles lag by
    the tyres' relaxation length (:meth:`ModelParams.from_vehicle`; off: the paper's model); None:
    on for ``joint`` where its tyres have one (fourwis's own do; a vehicle file's only if it gives
    one), off for the others. ``joint``'s tyres take the Magic Formula shape
    (``ModelParams.from_vehicle(..., shape="magic")``; docs/decisions/0045).
    ``tyres``: the model's (front, rear) :class:`AxleTyre` (another car's, e.g. from a vehicle
    file: fourwis.training.vehicle_file); default: both axles the fit of fourwis's own tyre.
    The baselines take ``nominal_mu`` (and ``baseline-kf`` the ``noise``) only.

    Your own estimator: ``module:factory`` (e.g. ``my_filters:BiasedCKF``) imports ``factory``
    and returns ``factory(params, dt)``, an object with the step interface of
    :class:`envs.simulation.Estimator` (``reset``, ``step``, optionally ``needs_truth``); the
    name then works wherever a name does: ``fourwis compare --estimators``, the comparison's
    worker processes, the Gymnasium env's ``estimator``."""
    base, groups = parse_estimator_name(name)
    check_vehicle_params(params)
    if noise is not None and not isinstance(noise, NoiseParams):
        raise ValueError(f"noise must be an estimation.NoiseParams or None, got {noise!r}")
    if tyre_relaxation is not None and not isinstance(tyre_relaxation, bool):
        raise ValueError(f"tyre_relaxation must be True, False or None (the kind's default), got {tyre_relaxation!r}")
    if groups:
        return PartialOracle(make_estimator(base, params, dt, noise, tyre_relaxation, tyres, **kwargs), groups)
    # (options only the model filters take)
    extra = sorted(kwargs) + ["tyre_relaxation"] * bool(tyre_relaxation) + ["tyres"] * (tyres is not None)
    if ":" in base:
        if noise is not None or extra:
            raise ValueError(
                f"estimator {name!r} is built as factory(params, dt): it takes no noise or keyword "
                f"arguments, got {extra or ['noise']}"
            )
        estimator = import_factory(base, "estimator")(params, dt)
        check_estimator(estimator, name)
        return estimator
    if name == "oracle":
        check_step(dt)
        if noise is not None or extra:
            raise ValueError(f"the oracle takes no noise or keyword arguments, got {extra or ['noise']}")
        return Oracle()
    if base in BASELINES:
        unknown = sorted(set(kwargs) - {"nominal_mu"}) + ["tyre_relaxation"] * bool(tyre_relaxation)
        if unknown:
            raise ValueError(f"the baseline {name!r} takes nominal_mu (and tyres) only, got {unknown}")
        model = ModelParams.from_vehicle(params, tyres=tyres)
        return make_baseline(base, model, check_step(dt), noise, **kwargs)
    options = {f.name for f in fields(StateEstimator) if f.init} - {"params", "kind", "dt", "noise", "needs_truth"}
    if set(kwargs) - options:
        raise ValueError(
            f"unknown keyword argument(s) {sorted(set(kwargs) - options)} for estimator {name!r}; "
            f"known: {sorted(options)}"
        )
    if noise is None:
        noise = (tuned_noise() if name in TUNED_KINDS else None) or NoiseParams()
    if tyre_relaxation is None:  # (joint: on where the tyres have a relaxation length, docs/decisions/0045)
        tyre_relaxation = name == "joint" and (tyres is None or all(t.relaxation_length > 0 for t in tyres))
    # (joint: the combined slip from the measured longitudinal force, docs/decisions/0034, and the
    # Magic Formula's lateral shape, docs/decisions/0045)
    model = ModelParams.from_vehicle(
        params,
        relaxation=tyre_relaxation,
        tyres=tyres,
        force_ellipse=name == "joint",
        shape="magic" if name == "joint" else "dugoff",
    )
    return StateEstimator(model, kind=name, dt=dt, noise=noise, **kwargs)


def relaxed_joint(params, dt: float = 0.002):
    """The joint estimator with the tyre relaxation in its model (``make_estimator("joint", params,
    dt, tyre_relaxation=True)``; the joint estimator's default since docs/decisions/0045, kept for
    the names that use it), as a factory, so that a name reaches it wherever names go:
    ``fourwis compare --estimators joint fourwis.estimation:relaxed_joint``, ``gym.make(...,
    estimator="fourwis.estimation:relaxed_joint")``."""
    return make_estimator("joint", params, dt, tyre_relaxation=True)


__all__ = [
    "BASELINES",
    "ESTIMATORS",
    "TRUTH_GROUPS",
    "AxleTyre",
    "Estimate",
    "ModelParams",
    "NoiseParams",
    "OnlineTuner",
    "PartialOracle",
    "StateEstimator",
    "check_estimator_name",
    "make_estimator",
    "parse_estimator_name",
    "relaxed_joint",
    "tuned_noise",
]

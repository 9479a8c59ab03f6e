"""Input checks shared by every layer: numbers, steps, vehicle parameters, a user's factory,
estimator and controller objects and what they return, and the rows a batched step works on.
Each raises ValueError naming the bad value."""

from __future__ import annotations

import importlib
import inspect
import math
import numbers
from functools import lru_cache

import numpy as np

from fourwis.core.types import Command, Estimate


def import_factory(name: str, kind: str):
    """The callable a ``module:attribute`` name points to (a user's ``kind``, e.g. "estimator",
    built as ``factory(params, dt)``), imported; ValueError naming what is missing."""
    module_name, _, attribute = name.partition(":")
    try:
        target = importlib.import_module(module_name)
        for part in attribute.split("."):
            target = getattr(target, part)
    except Exception as err:  # a missing or broken module (a syntax error in it too), a missing attribute
        raise ValueError(
            f"{kind} {name!r}: cannot import {attribute!r} from {module_name!r} ({type(err).__name__}: {err})"
        ) from None
    if not callable(target):
        raise ValueError(f"{kind} {name!r} is not callable: give a factory(params, dt) -> {kind}")
    try:
        inspect.signature(target).bind(None, None)
    except TypeError as err:
        raise ValueError(f"{kind} {name!r} cannot be called as factory(params, dt): {err}") from None
    except ValueError:  # no signature to read (a builtin): the call will tell
        pass
    return target


def check_vehicle_params(params) -> None:
    """ValueError unless ``params`` looks like vehicle parameters (duck-typed
    :class:`envs.vehicle.VehicleParams`: mass, wheel radius, steering ratio)."""
    if not all(hasattr(params, name) for name in ("mass", "wheel_radius", "steering_ratio")):
        raise ValueError(f"params must be vehicle parameters (an envs.vehicle.VehicleParams), got {params!r}")


def check_estimator(estimator, source) -> None:
    """ValueError naming ``source`` (a name, or the object) unless ``estimator`` has the step
    interface of :class:`fourwis.core.types.Estimator` (``reset`` and ``step``)."""
    if not (callable(getattr(estimator, "step", None)) and callable(getattr(estimator, "reset", None))):
        raise ValueError(
            f"estimator {source!r} lacks reset() and step(), got {estimator!r}: give an Estimator, "
            "a name for estimation.make_estimator or None"
        )


PER_WHEEL = ("mu", "fz", "mu_std")  #: the Estimate fields with a wheel axis (B, 4)
#: (low, high, rule) of the Estimate fields with physical bounds: a road friction coefficient
#: (the plant's range), a normal load, one-sigma uncertainties
ESTIMATE_BOUNDS = {
    "mu": (0.0, 2.0, "in (0, 2]"),
    "fz": (0.0, math.inf, ">= 0 N"),
    "beta_std": (0.0, math.inf, ">= 0"),
    "mu_std": (0.0, math.inf, ">= 0"),
}


def check_estimate(estimate, batch: int, source) -> None:
    """ValueError naming ``source`` (an estimator) and the field unless ``estimate`` is an
    :class:`Estimate` of ``batch`` rows ((B,) fields, (B, 4) per wheel) with finite values
    inside :data:`ESTIMATE_BOUNDS` (mu in (0, 2], loads and sigmas >= 0). Runs every step of a
    user's estimator, so the numbers are checked in one pass, and fields one by one only to name
    the first bad one."""
    if not isinstance(estimate, Estimate):
        raise ValueError(f"estimator {source!r} returned {type(estimate).__name__}, not an Estimate")
    arrays = []
    for name, value in zip(Estimate._fields, estimate):
        array = value if isinstance(value, np.ndarray) else np.asarray(value)
        shape = (batch, 4) if name in PER_WHEEL else (batch,)
        if array.shape != shape:
            raise ValueError(f"estimator {source!r} returned {name} of shape {array.shape}, expected {shape}")
        if array.dtype.kind not in "fiu":
            raise ValueError(f"estimator {source!r} returned {name} of dtype {array.dtype}, not real numbers")
        arrays.append(array)
    if np.isfinite(np.concatenate([a.ravel() for a in arrays])).all() and all(
        _inside(arrays[_FIELD[name]], name) for name in ESTIMATE_BOUNDS
    ):
        return
    for name, value in zip(Estimate._fields, arrays):
        if not np.isfinite(value).all():
            raise ValueError(f"estimator {source!r} returned a non-finite {name}: {value!r}")
        if name in ESTIMATE_BOUNDS and not _inside(value, name):
            low, high, rule = ESTIMATE_BOUNDS[name]
            outside = ~(((value > low) if name == "mu" else (value >= low)) & (value <= high))
            raise ValueError(
                f"estimator {source!r} returned {name} {float(value[outside].flat[0])!r}: it must be {rule}"
            )


_FIELD = {name: i for i, name in enumerate(Estimate._fields)}


def _inside(value: np.ndarray, name: str) -> bool:
    """Whether every entry of field ``name`` lies inside its :data:`ESTIMATE_BOUNDS`."""
    low, high, _ = ESTIMATE_BOUNDS[name]
    return not value.size or bool((value.min() > low if name == "mu" else value.min() >= low) and value.max() <= high)


def is_number(value) -> bool:
    """A real number (Python's or numpy's), not a bool (plain types first: the ABC check is slow)."""
    return type(value) in (float, int) or (isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)))


def is_integer(value) -> bool:
    """An integer (Python's or numpy's), not a bool."""
    return type(value) is int or (isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)))


def check_step(dt) -> float:
    """An estimator's step ``dt`` [s] if finite and > 0; else ValueError naming it."""
    if not (is_number(dt) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite step > 0 [s], got {dt!r}")
    return float(dt)


@lru_cache(maxsize=8)
def _all_rows(batch_size: int) -> np.ndarray:
    return np.arange(batch_size)


def member_rows(members, batch_size: int) -> np.ndarray:
    """The rows (M,) int64 a batched step works on: all ``batch_size`` rows for None (one cached
    array per batch size, never to be written; kept writeable, as a read-only array would be a
    second type for numba to compile), else ``members`` checked to be distinct indices into the
    batch, since the compiled steps index without bounds checks (ValueError naming them)."""
    if members is None:
        return _all_rows(batch_size)
    given = np.asarray(members)
    if given.size and not np.issubdtype(given.dtype, np.integer):
        raise ValueError(f"members must be integer indices into the batch of {batch_size}, got {members!r}")
    rows = np.ascontiguousarray(given, dtype=np.int64)
    if (
        rows.ndim != 1
        or (len(rows) and not (0 <= rows.min() and rows.max() < batch_size))
        or len(np.unique(rows)) != len(rows)
    ):
        raise ValueError(f"members must be distinct indices into the batch of {batch_size}, got {members!r}")
    return rows


def check_controller(controller, source) -> None:
    """ValueError naming ``source`` (a name, or the object) unless ``controller`` has the
    interface of :class:`fourwis.core.types.Controller` (``reset`` and a call)."""
    if not (callable(controller) and callable(getattr(controller, "reset", None))):
        raise ValueError(
            f"controller {source!r} lacks reset() or a call, got {controller!r}: give a Controller, "
            "a name from control.CONTROLLERS or None"
        )


def check_command(command, batch: int, source) -> None:
    """ValueError naming ``source`` (a user's controller) unless ``command`` is a Command of
    finite torques (B, 4) [N m] and rear steer (B,) [rad]."""
    if not isinstance(command, Command):
        raise ValueError(f"controller {source!r} returned {type(command).__name__}, not a fourwis.Command")
    for name, shape in (("torques", (batch, 4)), ("rear_steer", (batch,))):
        value = getattr(command, name)
        if np.shape(value) != shape or np.asarray(value).dtype.kind not in "fiu" or not np.all(np.isfinite(value)):
            raise ValueError(
                f"controller {source!r} returned {name} {value!r}: expected finite real numbers of shape {shape}"
            )

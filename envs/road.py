"""Road friction maps: mu at each wheel's contact point, batched.

Typical peak friction (e.g. Rajamani, *Vehicle Dynamics and Control*, Table 13.1;
Wong, *Theory of Ground Vehicles*): dry asphalt 0.8-1.0, wet 0.5-0.7, snow 0.2-0.3,
ice 0.05-0.15.

Every built-in map is a base value plus axis-aligned rectangles ("patches") in the global
frame, later patches winning; the plant's compiled kernel evaluates that table at every
integration step. :class:`CallableMap` wraps any ``mu(x, y)`` function; the plant evaluates
it in Python once per :func:`envs.vehicle.step` call.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from fourwis.core.checks import is_number
from fourwis.envs.layout import MU_MAX, S_PSI, S_X, S_Y


def check_mu(name: str, value: float) -> float:
    """``value`` as a float if it is a friction coefficient in (0, MU_MAX] (any real number type,
    not a bool); else ValueError naming ``name``."""
    if not (
        isinstance(value, numbers.Real)
        and not isinstance(value, (bool, np.bool_))
        and math.isfinite(value)
        and 0.0 < value <= MU_MAX
    ):
        raise ValueError(f"{name} must be a friction coefficient in (0, {MU_MAX}], got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Patch:
    """Rectangle ``x0 <= X < x1, y0 <= Y < y1`` [m] of friction ``mu`` in the global frame."""

    x0: float
    x1: float
    y0: float
    y1: float
    mu: float

    def __post_init__(self) -> None:
        check_mu("Patch.mu", self.mu)
        for name in ("x0", "x1", "y0", "y1"):
            value = getattr(self, name)
            if not is_number(value) or math.isnan(value):
                raise ValueError(f"Patch.{name} must be a number [m] (+-inf for no edge), got {value!r}")
        if not (self.x0 < self.x1 and self.y0 < self.y1):
            raise ValueError(f"Patch needs x0 < x1 and y0 < y1, got x {self.x0}..{self.x1}, y {self.y0}..{self.y1}")


class FrictionMap:
    """Base class: ``mu_at(x, y)`` evaluates friction at global positions (any equal shapes)."""

    def mu_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def table(self) -> tuple[float, np.ndarray] | None:
        """(base mu, patches (K, 5) rows x0, x1, y0, y1, mu) for the kernel, or None."""
        return None


@dataclass(frozen=True)
class PatchMap(FrictionMap):
    """Uniform ``base`` friction with rectangular patches (later patches win)."""

    base: float
    patches: tuple[Patch, ...] = ()

    def __post_init__(self) -> None:
        check_mu("base mu", self.base)
        object.__setattr__(self, "patches", tuple(self.patches))
        for patch in self.patches:
            if not isinstance(patch, Patch):
                raise ValueError(f"patches must be Patch instances, got {patch!r}")

    def table(self) -> tuple[float, np.ndarray]:
        rows = np.array([[p.x0, p.x1, p.y0, p.y1, p.mu] for p in self.patches], dtype=np.float64)
        return self.base, rows.reshape(-1, 5)

    def mu_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        mu = np.full(x.shape, self.base)
        for p in self.patches:
            mu = np.where((x >= p.x0) & (x < p.x1) & (y >= p.y0) & (y < p.y1), p.mu, mu)
        return mu


def uniform(mu: float) -> PatchMap:
    """The same friction everywhere."""
    return PatchMap(check_mu("mu", mu))


def split(mu_left: float, mu_right: float, y_split: float = 0.0) -> PatchMap:
    """Left/right split: ``mu_left`` for Y >= ``y_split`` [m], ``mu_right`` below (ISO: +Y is left)."""
    return PatchMap(
        check_mu("mu_right", mu_right), (Patch(-math.inf, math.inf, y_split, math.inf, check_mu("mu_left", mu_left)),)
    )


def step_change(mu_before: float, mu_after: float, x_step: float) -> PatchMap:
    """Longitudinal step: ``mu_before`` for X < ``x_step`` [m], ``mu_after`` from there on."""
    return PatchMap(
        check_mu("mu_before", mu_before),
        (Patch(x_step, math.inf, -math.inf, math.inf, check_mu("mu_after", mu_after)),),
    )


def patch(
    mu_base: float, mu_patch: float, x0: float, x1: float, y0: float = -math.inf, y1: float = math.inf
) -> PatchMap:
    """A single patch, e.g. ice ``patch(0.9, 0.1, 50, 80)`` across the whole road for 30 m."""
    return PatchMap(check_mu("mu_base", mu_base), (Patch(x0, x1, y0, y1, mu_patch),))


@dataclass(frozen=True)
class CallableMap(FrictionMap):
    """Any user function ``fn(x, y) -> mu`` on arrays [m] -> [-]; values checked at every use."""

    fn: Callable[[np.ndarray, np.ndarray], np.ndarray]

    def mu_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        mu = np.asarray(self.fn(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)), dtype=np.float64)
        shape = np.broadcast(x, y).shape
        try:
            mu = np.broadcast_to(mu, shape)
        except ValueError:
            raise ValueError(
                f"friction map returned shape {mu.shape} for positions of shape {shape}: give one mu "
                "per position (or a scalar)"
            ) from None
        bad = ~((mu > 0.0) & (mu <= MU_MAX))
        if np.any(bad):
            raise ValueError(f"friction map returned mu {mu[bad].flat[0]!r} outside (0, {MU_MAX}]")
        return mu


def as_friction_map(road: FrictionMap | float | Callable) -> FrictionMap:
    """Accept a map, a number (uniform) or a callable ``mu(x, y)``."""
    if isinstance(road, FrictionMap):
        return road
    if isinstance(road, numbers.Real) and not isinstance(road, (bool, np.bool_)):
        return uniform(float(road))
    if callable(road):
        return CallableMap(road)
    raise ValueError(f"road must be a FrictionMap, a friction coefficient or a callable mu(x, y), got {road!r}")


def contact_points(state: np.ndarray, params) -> tuple[np.ndarray, np.ndarray]:
    """Global (X, Y) [m] of the four contact points, each (B, 4), from plant states (B, NX) of a
    car with vehicle parameters ``params`` (their ``wheel_positions``)."""
    pos = params.wheel_positions
    c, s = np.cos(state[:, S_PSI])[:, None], np.sin(state[:, S_PSI])[:, None]
    gx = state[:, S_X][:, None] + c * pos[:, 0] - s * pos[:, 1]
    gy = state[:, S_Y][:, None] + s * pos[:, 0] + c * pos[:, 1]
    return gx, gy


class RoadTables(NamedTuple):
    """Kernel form of the roads of a batch of B vehicles.

    base_mu (B,), rects (B, K, 5) rows x0, x1, y0, y1, mu (rows with mu = 0 are padding),
    mu_given (B, 4) friction per wheel used when ``use_map`` is False (callable maps).
    """

    base_mu: np.ndarray
    rects: np.ndarray
    mu_given: np.ndarray
    use_map: bool

    @classmethod
    def from_roads(cls, road, batch: int) -> RoadTables:
        """Tables for table maps (one map, or a sequence of ``batch`` maps); ValueError for callables."""
        roads = _per_vehicle(road, batch)
        tables = [r.table() for r in roads]
        if any(t is None for t in tables):
            raise ValueError("a callable friction map has no table; pass the map itself to envs.vehicle.step")
        k = max(t[1].shape[0] for t in tables)
        rects = np.zeros((batch, k, 5))
        for b, (_, rows) in enumerate(tables):
            rects[b, : rows.shape[0]] = rows
        base = np.array([t[0] for t in tables])
        return cls(base, rects, np.ones((batch, 4)), True)


def _per_vehicle(road, batch: int) -> list[FrictionMap]:
    roads = (
        [as_friction_map(r) for r in road]
        if isinstance(road, Sequence) and not isinstance(road, str)
        else [as_friction_map(road)] * batch
    )
    if len(roads) != batch:
        raise ValueError(f"got {len(roads)} roads for a batch of {batch}")
    return roads


def road_tables(road, state: np.ndarray, params) -> RoadTables:
    """Kernel arguments for a batch of plant states (B, NX): maps evaluated where they must be.

    With any callable map in the batch, friction is evaluated here at every vehicle's contact
    points and held over the plant call.
    """
    batch = state.shape[0]
    roads = _per_vehicle(road, batch)
    if all(r.table() is not None for r in roads):
        return RoadTables.from_roads(roads, batch)
    gx, gy = contact_points(state, params)
    mu = np.stack([r.mu_at(gx[b], gy[b]) for b, r in enumerate(roads)])
    return RoadTables(np.ones(batch), np.zeros((batch, 0, 5)), np.ascontiguousarray(mu), False)

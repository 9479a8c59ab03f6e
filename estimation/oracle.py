"""The oracle: passes the truth through. The reference every estimator is judged against.

:class:`PartialOracle` hands over only part of the truth, to attribute a closed-loop loss to
the estimate of one quantity (``make_estimator("joint+true-mu", ...)``: the joint estimator's
state with the road's true friction)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from fourwis.core.types import Estimate

#: what a PartialOracle can take from the truth (the name after ``+true-``) and the Estimate
#: fields each replaces; a replaced standard deviation becomes zero, as the oracle's
TRUTH_GROUPS = {
    "u": ("u",),
    "beta": ("v", "beta", "beta_std"),
    "r": ("r",),
    "accel": ("ax", "ay"),
    "mu": ("mu", "mu_std"),
    "fz": ("fz",),
}
TRUE_SUFFIX = "+true-"  #: ``<estimator>+true-<group>[-<group>...]``, e.g. ``joint+true-mu-fz``


class TruthKernel(NamedTuple):
    """The oracle as the compiled closed loop takes it: the estimate is the truth (no data)."""


class Oracle:
    """Reports the true state (the simulator hands it over: ``needs_truth``)."""

    needs_truth = True

    def kernel(self) -> TruthKernel:
        """This estimator as the compiled closed loop takes it."""
        return TruthKernel()

    def reset(self, reading, initial_speed=None, mask=None) -> None:
        """Nothing to initialise."""

    def step(self, reading, truth: Estimate | None = None, members=None) -> Estimate:
        """The truth (already restricted to ``members`` by the caller)."""
        if truth is None:
            raise ValueError("the oracle estimator needs the truth; run it through envs.simulate")
        return truth


def parse_truth_groups(text: str) -> tuple[str, ...]:
    """The groups of ``"mu-fz"`` (ValueError naming an unknown or repeated one)."""
    groups = tuple(text.split("-"))
    unknown = [g for g in groups if g not in TRUTH_GROUPS]
    repeated = sorted({g for g in groups if groups.count(g) > 1})
    if unknown or repeated:
        raise ValueError(
            f"'+true-{text}': {'unknown' if unknown else 'repeated'} truth group(s) {unknown or repeated}; "
            f"known: {list(TRUTH_GROUPS)}, each at most once"
        )
    return groups


class PartialOracle:
    """``estimator`` with the fields of ``groups`` (see :data:`TRUTH_GROUPS`) replaced by the
    truth. The wrapped estimator runs exactly as on its own: it never sees the truth (unless it
    is itself an oracle), so its other outputs are unchanged."""

    needs_truth = True

    def __init__(self, estimator, groups: Sequence[str]) -> None:
        self.estimator = estimator
        self.groups = parse_truth_groups("-".join(groups))
        self._fields = [f for g in self.groups for f in TRUTH_GROUPS[g]]

    @property
    def dt(self) -> float | None:
        """The wrapped estimator's step [s] (None if it has none)."""
        return getattr(self.estimator, "dt", None)

    def reset(self, reading, initial_speed=None, mask=None) -> None:
        self.estimator.reset(reading, initial_speed, mask)

    def step(self, reading, truth: Estimate | None = None, members=None) -> Estimate:
        if truth is None:
            raise ValueError("a partial oracle needs the truth; run it through envs.simulate")
        estimate = self.estimator.step(
            reading, truth if getattr(self.estimator, "needs_truth", False) else None, members
        )
        return estimate._replace(
            **{
                f: np.zeros_like(getattr(estimate, f)) if f.endswith("_std") else getattr(truth, f)
                for f in self._fields
            }
        )

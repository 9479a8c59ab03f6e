"""The oracle: passes the truth through. The reference every estimator is judged against."""

from __future__ import annotations

from estimation.types import Estimate


class Oracle:
    """Reports the true state (the simulator hands it over: ``needs_truth``)."""

    needs_truth = True

    def reset(self, reading, initial_speed=None, mask=None) -> None:
        """Nothing to initialise."""

    def step(self, reading, truth: Estimate | None = None, members=None) -> Estimate:
        """The truth (already restricted to ``members`` by the caller)."""
        if truth is None:
            raise ValueError("the oracle estimator needs the truth; run it through envs.simulate")
        return truth

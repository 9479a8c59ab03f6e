"""Per-run results of a run matrix: means over seeds and the runs CSV (compare, estimate)."""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Hashable, Sequence
from pathlib import Path

import numpy as np

from fourwis.training.io import atomic_write_text


def require_distinct(kind: str, names: Sequence[str]) -> None:
    """ValueError naming the repeated entries of a matrix axis (they would run twice and
    report as one row each, identically)."""
    repeated = sorted({name for name in names if list(names).count(name) > 1})
    if repeated:
        raise ValueError(f"{kind} must be distinct, got {repeated} more than once")


def mean_over_seeds(
    results: Sequence[tuple[object, dict[str, float]]], key: Callable[[object], Hashable]
) -> dict[Hashable, dict[str, float]]:
    """Mean of every metric of the runs grouped by ``key(spec)`` (NaN stays NaN)."""
    groups: dict[Hashable, list[dict]] = {}
    for spec, metrics in results:
        groups.setdefault(key(spec), []).append(metrics)
    return {k: {m: float(np.mean([r[m] for r in runs])) for m in runs[0]} for k, runs in groups.items()}


def write_runs_csv(
    results: Sequence[tuple[object, dict[str, float]]],
    columns: Sequence[str],
    row: Callable[[object], list],
    metrics: Sequence[str],
    path: Path,
) -> Path:
    """One row per run: ``row(spec)`` under ``columns``, then ``metrics`` (blank where a run lacks
    one) with 6 significant digits; written atomically."""
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow([*columns, *metrics])
    for spec, values in results:
        writer.writerow([*row(spec), *(f"{values[m]:.6g}" if m in values else "" for m in metrics)])
    return atomic_write_text(path, buffer.getvalue())

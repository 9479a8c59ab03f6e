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


#: the runs CSVs' one convention for a value a run does not have (a metric that does not apply
#: to its scenario, or NaN: undefined): an empty field, which csv readers, pandas and numpy take
#: as missing
MISSING = ""


def csv_number(value: float) -> str:
    """``value`` as a CSV field: 6 significant digits, :data:`MISSING` for NaN (inf stays inf)."""
    return MISSING if value != value else f"{value:.6g}"


def with_unit(name: str, units: dict[str, str]) -> str:
    """A CSV column header ``name [unit]`` (KeyError for a metric without a documented unit)."""
    return f"{name} [{units[name]}]"


def write_runs_csv(
    results: Sequence[tuple[object, dict[str, float]]],
    columns: Sequence[str],
    row: Callable[[object, dict[str, float]], list],
    metrics: Sequence[str],
    units: dict[str, str],
    path: Path,
) -> Path:
    """One row per run: ``row(spec, metrics)`` under ``columns``, then ``metrics`` with 6
    significant digits, each headed ``name [unit]`` from ``units`` ("-" dimensionless, "0/1"
    a flag, "count"); a metric a run lacks, or NaN, is :data:`MISSING`. Written atomically."""
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow([*columns, *(with_unit(m, units) for m in metrics)])
    for spec, values in results:
        writer.writerow([*row(spec, values), *(csv_number(values[m]) if m in values else MISSING for m in metrics)])
    return atomic_write_text(path, buffer.getvalue())

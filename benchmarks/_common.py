"""Shared output of the benchmark scripts: a labelled table on stdout plus the machine."""

from __future__ import annotations

import json
import platform


def report(results: dict, decimals: int = 0) -> dict:
    """Adds the machine to ``results``, prints them as a table and as JSON, returns them."""
    results["machine"] = f"{platform.processor() or platform.machine()}, {platform.python_version()}"
    for key, value in results.items():
        print(f"{key:55s} {value:,.{decimals}f}" if isinstance(value, float) else f"{key:55s} {value}")
    print(json.dumps(results, indent=1))
    return results

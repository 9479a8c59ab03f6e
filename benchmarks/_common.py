"""Shared output of the benchmark scripts: a Markdown table on stdout, then the same numbers as
JSON (read by benchmarks/side_by_side.py and docs/generate.py)."""

from __future__ import annotations

import json
import platform


def report(results: dict, decimals: int = 0) -> dict:
    """Adds the machine to ``results``, prints them as a Markdown table and as JSON, returns them."""
    results["machine"] = f"{platform.processor() or platform.machine()}, {platform.python_version()}"
    print("| measurement | value |")
    print("|---|---:|")
    for key, value in results.items():
        print(f"| {key} | {value:,.{decimals}f} |" if isinstance(value, float) else f"| {key} | {value} |")
    print(json.dumps(results, indent=1))
    return results

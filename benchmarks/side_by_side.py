"""Benchmarks of two versions of fourwis side by side, in one run on one machine.

    .venv/bin/python benchmarks/side_by_side.py --before REF [--only plant env ...] [--repeats 2]

Each version runs its own ``benchmarks/bench_<name>.py`` scripts: the checkout this script is in
(installed in the venv) and ``REF`` (a git commit, branch or tag of this repository), built into
a wheel and unpacked into a temporary folder that goes first on its PYTHONPATH, whatever its
layout. Each script runs once per version untimed (numba compiles and caches its kernels), then
``--repeats`` times per version, the versions alternating, so that a busy host slows both alike.
A script's numbers are read from the JSON object it prints (benchmarks/_common.report) or from
its Markdown table rows (``| label | number ... |``); the table gives each measurement's best
value per version (highest: the scripts report rates or ratios where higher is better, unless the
label names a time) and their ratio. Writes the table to ``--out`` (Markdown) if given.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
NUMBER = re.compile(r"^-?[\d,]*\.?\d+(?:e[-+]?\d+)?")
#: labels whose values are times or costs (lower is better); the others are rates (higher is better)
LOWER_IS_BETTER = re.compile(r"\b(us|ms|seconds?|time|wall|cost|per step|per vehicle-step|\[s\])\b", re.IGNORECASE)


def build(ref: str, into: Path) -> tuple[Path, Path]:
    """(the source tree, the unpacked wheel) of ``ref`` under ``into``."""
    tree = into / "tree"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "--force", str(tree), ref], check=True,
                   capture_output=True)  # fmt: skip
    wheels = into / "wheels"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--quiet", "-w", str(wheels),
         str(tree)],
        check=True, capture_output=True,
    )  # fmt: skip
    site = into / "site"
    for wheel in wheels.glob("*.whl"):
        zipfile.ZipFile(wheel).extractall(site)
    return tree, site


def run(script: Path, site: Path | None) -> str:
    """The stdout of ``script`` (with ``site`` first on its path, if given)."""
    env = dict(os.environ)
    if site is not None:
        env["PYTHONPATH"] = str(site)
    result = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True,
                            cwd=tempfile.gettempdir())  # fmt: skip
    if result.returncode:
        raise RuntimeError(f"{script} failed:\n{result.stderr[-2000:]}")
    return result.stdout


def measurements(output: str) -> dict[str, float]:
    """The numbers a benchmark printed: its JSON object's numeric entries, or its Markdown table
    rows' first numeric cell, keyed by the row's label."""
    found: dict[str, float] = {}
    start = output.rfind("\n{")
    if start >= 0:
        try:
            data = json.loads(output[start:])
            found.update({k: float(v) for k, v in data.items() if isinstance(v, int | float)})
        except json.JSONDecodeError:
            pass
    for line in output.splitlines():
        cells = [c.strip().strip("*") for c in line.strip().strip("|").split("|")] if line.startswith("|") else []
        for cell in cells[1:]:
            match = NUMBER.match(cell.replace(" ", ""))
            if match and cells[0] and not set(cells[0]) <= set("-:"):
                found.setdefault(cells[0], float(match.group(0).replace(",", "")))
                break
    return found


def best(values: list[float], label: str) -> float:
    return min(values) if LOWER_IS_BETTER.search(label) else max(values)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="git commit, branch or tag to compare with")
    parser.add_argument("--only", nargs="*", help="benchmark names (default: every bench_*.py both versions have)")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs per version (alternating)")
    parser.add_argument("--out", type=Path, help="also write the table here (Markdown)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="fourwis-before-") as tmp:
        tree, site = build(args.before, Path(tmp))
        try:
            names = args.only or sorted(
                p.stem.removeprefix("bench_")
                for p in HERE.glob("bench_*.py")
                if (tree / "benchmarks" / p.name).exists() and p.stem != "bench_cluster"
            )
            rows = []
            for name in names:
                scripts = {
                    "before": (tree / "benchmarks" / f"bench_{name}.py", site),
                    "after": (HERE / f"bench_{name}.py", None),
                }
                for script, path in scripts.values():  # untimed: compile and cache
                    run(script, path)
                seen: dict[str, dict[str, list[float]]] = {"before": {}, "after": {}}
                for _ in range(args.repeats):
                    for version, (script, path) in scripts.items():
                        for label, value in measurements(run(script, path)).items():
                            seen[version].setdefault(label, []).append(value)
                for label in seen["after"]:
                    if label in seen["before"]:
                        b, a = best(seen["before"][label], label), best(seen["after"][label], label)
                        rows.append((name, label, b, a))
                print(f"{name}: done", file=sys.stderr)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], capture_output=True)
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    lines = [
        f"Command: `{' '.join(['.venv/bin/python', 'benchmarks/side_by_side.py', *(argv or sys.argv[1:])])}`  ",
        f"Before: `{args.before}`; after: `{commit.stdout.strip()}` (this checkout). "
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
        f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC; load average {os.getloadavg()[0]:.1f}.",
        "",
        "| benchmark | measurement | before | after | after / before |",
        "|---|---|---:|---:|---:|",
        *(f"| {n} | {label} | {b:,.4g} | {a:,.4g} | {a / b:.2f} |" for n, label, b, a in rows if b),
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

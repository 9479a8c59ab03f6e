"""Benchmarks of two versions of fourwis side by side, in one run on one machine.

    .venv/bin/python benchmarks/side_by_side.py --before REF [--after REF] [--only plant env ...]
        [--scripts this] [--script-args 'env=--envs vector256 oracle256' ...]

Each version runs its own ``benchmarks/bench_<name>.py`` scripts: ``--before REF`` and ``--after
REF`` (git commits, branches or tags of this repository), each built into a wheel and unpacked into
a temporary folder that goes first on its PYTHONPATH, whatever its layout; without ``--after``, the
checkout this script is in, as installed in the venv. Each script runs once per version untimed
(numba compiles and caches its kernels), then ``--repeats`` times per version, the versions
alternating, so that a busy host slows both alike. A script's numbers are read from the JSON object
it prints (benchmarks/_common.report) or from its Markdown table rows (``| label | number ... |``);
``--scripts this`` runs this checkout's scripts against both versions' packages instead (the
same measurements where the older scripts lack them; the scripts then use only what both
versions have), ``--script-args NAME=ARGS`` hands ARGS to ``bench_NAME.py``;
the table gives each measurement's best value per version (highest: the scripts report rates or
ratios where higher is better, unless the label names a time) and their ratio. Writes the table to
``--out`` if given (a Markdown page: docs/results/side-by-side.md).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from fourwis.training.io import atomic_write_text
from fourwis.training.provenance import cpu_model

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
NUMBER = re.compile(r"^-?[\d,]*\.?\d+(?:e[-+]?\d+)?")
#: labels whose values are times or costs (lower is better); the others are rates (higher is better)
UNIT = re.compile(r"[A-Za-z][A-Za-z/%-]*")  #: a unit after a number in a value's cell ("us", "steps/s")
LOWER_IS_BETTER = re.compile(r"\b(us|ms|seconds?|time|wall|cost|per step|per vehicle-step|\[s\])\b", re.IGNORECASE)


def better(label: str) -> str:
    """ "higher" or "lower": a unit in brackets that is a rate ("[steps/s]") says higher, else
    :data:`LOWER_IS_BETTER` decides."""
    unit = re.search(r"\[([^\]]*)\]\s*$", label)
    if unit and unit.group(1).endswith("/s"):
        return "higher"
    return "lower" if LOWER_IS_BETTER.search(label) else "higher"


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


def run(script: Path, site: Path | None, args: list[str] = ()) -> str:
    """The stdout of ``script`` with ``args`` (with ``site`` first on its path, if given)."""
    env = dict(os.environ)
    if site is not None:
        env["PYTHONPATH"] = str(site)
    result = subprocess.run([sys.executable, str(script), *args], env=env, capture_output=True, text=True,
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
                # (a unit in the value's cell, "40.1 us", goes into the label where it has none)
                unit = cell.replace(" ", "")[match.end() :]
                label = cells[0] if not UNIT.fullmatch(unit) or cells[0].endswith("]") else f"{cells[0]} [{unit}]"
                found.setdefault(label, float(match.group(0).replace(",", "")))
                break
    return found


def best(values: list[float], label: str) -> float:
    return min(values) if better(label) == "lower" else max(values)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="git commit, branch or tag to compare with")
    parser.add_argument("--after", help="git commit, branch or tag to measure (default: this checkout as it is)")
    parser.add_argument("--only", nargs="*", help="benchmark names (default: every bench_*.py both versions have)")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs per version (alternating)")
    parser.add_argument("--out", type=Path, help="also write the table here (Markdown)")
    parser.add_argument("--scripts", choices=("own", "this"), default="own",
                        help="each version's own benchmark scripts, or this checkout's for both")  # fmt: skip
    parser.add_argument("--script-args", action="append", default=[], metavar="NAME=ARGS",
                        help="arguments for bench_NAME.py (repeatable)")  # fmt: skip
    args = parser.parse_args(argv)
    script_args = {name: shlex.split(rest) for name, _, rest in (a.partition("=") for a in args.script_args)}
    load = os.getloadavg()[0]
    refs = {"before": args.before, "after": args.after}
    with tempfile.TemporaryDirectory(prefix="fourwis-side-by-side-") as tmp:
        versions = {v: build(ref, Path(tmp) / v) if ref else (ROOT, None) for v, ref in refs.items()}
        try:
            scripts_of = {
                v: (HERE if args.scripts == "this" else tree / "benchmarks") for v, (tree, _) in versions.items()
            }
            common = sorted(
                p.stem.removeprefix("bench_")
                for p in HERE.glob("bench_*.py")
                if all((folder / p.name).exists() for folder in scripts_of.values())
            )
            names = args.only or [name for name in common if name != "cluster"]
            if set(names) - set(common):
                raise SystemExit(f"benchmarks not in both versions: {sorted(set(names) - set(common))}; both: {common}")
            rows = []
            for name in names:
                scripts = {v: (scripts_of[v] / f"bench_{name}.py", site) for v, (_, site) in versions.items()}
                extra = script_args.get(name, [])
                for script, path in scripts.values():  # untimed: compile and cache
                    run(script, path, extra)
                seen: dict[str, dict[str, list[float]]] = {"before": {}, "after": {}}
                for _ in range(args.repeats):
                    for version, (script, path) in scripts.items():
                        for label, value in measurements(run(script, path, extra)).items():
                            seen[version].setdefault(label, []).append(value)
                for label in seen["after"]:
                    if label in seen["before"]:
                        b, a = best(seen["before"][label], label), best(seen["after"][label], label)
                        rows.append((name, label, b, a))
                print(f"{name}: done", file=sys.stderr)
        finally:
            for tree, _ in versions.values():
                if tree != ROOT:
                    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)],
                                   capture_output=True)  # fmt: skip
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    after = f"`{args.after}`" if args.after else f"`{head.stdout.strip()}` (this checkout)"
    command = " ".join([".venv/bin/python", "benchmarks/side_by_side.py", *(argv or sys.argv[1:])])
    lines = [
        "# Two versions side by side",
        "",
        "*Written by the command below (`make side-by-side BEFORE=REF`); to re-measure, rerun it, do not "
        "edit this page.*",
        "",
        f"- command: `{command}`",
        f"- commit: before `{args.before}`; after {after}",
        f"- date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC; load average before {load:.1f}",
        f"- machine: {cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}",
        f"- each value: the best of {args.repeats} runs per version, the versions alternating",
        "",
        "| benchmark | measurement | better | before | after | after / before |",
        "|---|---|---|---:|---:|---:|",
        *(f"| {n} | {label} | {better(label)} | {b:,.4g} | {a:,.4g} | {a / b:.2f} |" for n, label, b, a in rows if b),
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        atomic_write_text(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

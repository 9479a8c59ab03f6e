"""Where an estimator's step spends its time, by compiled function, with Linux perf.

perf samples numba's compiled code as anonymous memory without names. This script writes the
map perf reads for a JIT's symbols (``/tmp/perf-<pid>.map``: start, size, name per line) from
numba's engine after the first step, then steps estimator ``--kind`` for ``--batch`` vehicles
(benchmarks/bench_estimator.py's ``_started``: a repeated reading, each step of the nominal dt)
for ``--seconds``. numba gives no sizes: a function's extends to the next one's start. With
``--summary PERF_DATA`` it instead reads ``perf report`` of a recorded run and prints each
function's share of the samples, numba's mangled names shortened to ``module.function`` and the
specialisations of one function summed. A function inlined into another counts as its caller.

    FOURWIS_THREADS=1 perf record -F 4000 -o /tmp/perf.data \\
        .venv/bin/python benchmarks/profile_estimator.py --kind joint --batch 256 --seconds 20
    .venv/bin/python benchmarks/profile_estimator.py --summary /tmp/perf.data

(The first seconds, the imports and the kernels' loading from numba's cache, are in the samples
too; start perf later with ``-D MILLISECONDS`` to leave them out.) Record 0052 gives a run.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import subprocess
import time

from bench_estimator import _started

MANGLED = re.compile(r"_ZN((?:\d+\w+?)+?)B\d+v\d+")


def write_perf_map(path: str) -> int:
    """Every function numba's engine has loaded, as a perf map at ``path``; returns their count."""
    from numba.core.registry import cpu_target

    engine = cpu_target.target_context.codegen()._engine
    starts = sorted(
        (address, name) for name in engine._defined_symbols if (address := engine._ee.get_function_address(name))
    )
    ends = [start for start, _ in starts[1:]] + [starts[-1][0] + 65536]
    with open(path, "w") as out:
        for (start, name), end in zip(starts, ends):
            out.write(f"{start:x} {min(end - start, 1 << 20):x} {name}\n")
    return len(starts)


def short_name(symbol: str) -> str:
    """``module.function`` of a numba symbol (``_ZN7fourwis10estimation5model16_add_wheel_lanesB5v...``
    -> ``model._add_wheel_lanes``); other symbols as they are."""
    match = MANGLED.search(symbol)
    if not match:
        return symbol
    parts, text = [], match.group(1)
    while (length := re.match(r"\d+", text)) is not None:
        start, end = length.end(), length.end() + int(length.group())
        parts.append(text[start:end])
        text = text[end:]
    return ".".join(parts[-2:]) if parts and not text else symbol


def summary(perf_data: str, rows: int = 30) -> None:
    """Each function's share [%] of the samples of ``perf_data``, largest first."""
    report = subprocess.run(
        ["perf", "report", "-i", perf_data, "--sort", "sym", "--stdio"], capture_output=True, text=True, check=True
    ).stdout
    shares: collections.Counter[str] = collections.Counter()
    for line in report.splitlines():
        if line.startswith("#") or "%" not in line or "[.]" not in line:
            continue
        shares[short_name(line.split("[.]", 1)[1].strip())] += float(line.split("%", 1)[0])
    print("| function | share of samples [%] |\n|---|---:|")
    for name, share in shares.most_common(rows):
        print(f"| {name} | {share:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kind", default="joint", help="estimator kind (make_estimator's name)")
    parser.add_argument("--batch", type=int, default=256, help="vehicles stepped together")
    parser.add_argument("--seconds", type=float, default=20.0, help="how long to step [s]")
    parser.add_argument("--summary", metavar="PERF_DATA", help="summarise a recorded run instead")
    args = parser.parse_args()
    if args.summary:
        summary(args.summary)
        return
    estimator, reading = _started(args.kind, args.batch)
    estimator.step(reading)  # (numba loads or compiles the kernels)
    count = write_perf_map(f"/tmp/perf-{os.getpid()}.map")
    print(f"perf map of {count} compiled functions written; stepping {args.kind} x{args.batch} for {args.seconds} s")
    start = time.perf_counter()
    while time.perf_counter() - start < args.seconds:
        estimator.step(reading)


if __name__ == "__main__":
    main()

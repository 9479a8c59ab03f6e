"""The ``fourwis`` command line: one console script, one subcommand per job."""

from __future__ import annotations

import argparse
import runpy
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def _bench(args: argparse.Namespace) -> int:
    if not BENCHMARKS.is_dir():
        raise SystemExit(f"benchmarks need the source tree: {BENCHMARKS} not found (install with pip install -e .)")
    names = args.only or sorted(p.stem.removeprefix("bench_") for p in BENCHMARKS.glob("bench_*.py"))
    for name in names:
        path = BENCHMARKS / f"bench_{name}.py"
        if not path.exists():
            raise SystemExit(f"unknown benchmark {name!r}; available: "
                             f"{sorted(p.stem.removeprefix('bench_') for p in BENCHMARKS.glob('bench_*.py'))}")
        print(f"== {name}")
        runpy.run_path(str(path), run_name="__main__")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fourwis", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    bench = sub.add_parser("bench", help="run the performance benchmarks in benchmarks/")
    bench.add_argument("--only", nargs="*", help="benchmark names (default: all)")
    bench.set_defaults(func=_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())

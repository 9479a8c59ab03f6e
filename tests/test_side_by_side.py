"""benchmarks/side_by_side.py reads which way a benchmark's value is better from its label."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from side_by_side import better  # noqa: E402


def test_a_rate_in_brackets_is_better_higher_even_when_the_label_names_a_time():
    assert better("single, one call per 2 ms step [steps/s]") == "higher"
    assert better("batch 1024 [vehicle-steps/s]") == "higher"


def test_times_and_costs_are_better_lower():
    assert better("compiled allocator, batch 1 [us per vehicle-step]") == "lower"
    assert better("joint estimator, one vehicle, per step") == "lower"
    assert better("compare (small matrix) wall [s], threads=1") == "lower"

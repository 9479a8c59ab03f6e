"""benchmarks/side_by_side.py reads which way a benchmark's value is better from its label."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from side_by_side import better, measurements  # noqa: E402


def test_a_rate_in_brackets_is_better_higher_even_when_the_label_names_a_time():
    assert better("single, one call per 2 ms step [steps/s]") == "higher"
    assert better("batch 1024 [vehicle-steps/s]") == "higher"


def test_times_and_costs_are_better_lower():
    assert better("compiled allocator, batch 1 [us per vehicle-step]") == "lower"
    assert better("joint estimator, one vehicle, per step") == "lower"
    assert better("compare (small matrix) wall [s], threads=1") == "lower"


def test_a_unit_in_the_value_cell_joins_the_label_and_decides():
    """A table row whose value carries its unit ("40.1 us") is keyed with it, so that the row
    reads lower-is-better; a rate in the cell reads higher; a label with its own unit keeps it."""
    table = "\n".join(
        [
            "| what | value |",
            "|---|---:|",
            "| ckf estimator step, one vehicle | 40.1 us |",
            "| env rate | 1,445 steps/s |",
            "| plant step [us] | 16.0 us |",
            "| CKF speed-up over filterpy | 12.4x |",
        ]
    )
    found = measurements(table)
    assert found == {
        "ckf estimator step, one vehicle [us]": 40.1,
        "env rate [steps/s]": 1445.0,
        "plant step [us]": 16.0,
        "CKF speed-up over filterpy [x]": 12.4,
    }
    assert better("ckf estimator step, one vehicle [us]") == "lower"
    assert better("env rate [steps/s]") == "higher"
    assert better("CKF speed-up over filterpy [x]") == "higher"

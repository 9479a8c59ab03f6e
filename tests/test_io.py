"""Reports and checkpoints are written atomically: a write that fails leaves the previous file
whole and no temporary behind."""

import os

import pytest

from fourwis.training.io import atomic_write, atomic_write_json, atomic_write_text


def test_a_failed_write_keeps_the_previous_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "runs.csv"
    atomic_write_text(target, "previous\n")

    def half_written(tmp):
        tmp.write_text("partial")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(target, half_written)
    assert target.read_text() == "previous\n"
    assert [p.name for p in tmp_path.iterdir()] == ["runs.csv"]
    with pytest.raises(KeyboardInterrupt):  # an interrupt mid-write too
        atomic_write(target, lambda tmp: (_ for _ in ()).throw(KeyboardInterrupt()))
    assert target.read_text() == "previous\n" and len(list(tmp_path.iterdir())) == 1


def test_a_finished_write_replaces_the_file_with_the_usual_permissions(tmp_path):
    target = tmp_path / "sub" / "report.json"  # a missing parent is created
    assert atomic_write_json(target, {"a": 1}) == '{\n  "a": 1\n}\n'
    assert target.read_text() == '{\n  "a": 1\n}\n'
    mask = os.umask(0)
    os.umask(mask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~mask  # not mkstemp's 0600

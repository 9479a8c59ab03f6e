"""A command's folder of outputs is whole as a set: an interrupt (Ctrl-C) during the runs, after
them or during the swap leaves the old set or the new one, never a mix; the output folder is
proved writable by creating it and a file in it before any work."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from fourwis.training.io import MANIFEST, STAGING_PREFIX, check_writable, staged_output

OLD = ["paper_sine:duration=0.6"]
NEW = ["paper_sine:duration=0.6", "paper_step:duration=0.6"]  # one plot more, other rows in runs.csv

#: the child process: ``fourwis compare`` of NEW into OUT, paused at MOMENT (it prints the moment's
#: name and waits for the file GO), so that the test can interrupt it there
CHILD = r"""
import os, sys, time
from pathlib import Path
moment, out, go = sys.argv[1], sys.argv[2], Path(sys.argv[3])
from fourwis.training import compare
from fourwis.training.cli import main
from fourwis.training.io import STAGING_PREFIX

def pause():
    print(moment, flush=True)
    deadline = time.monotonic() + 120
    while not go.exists():
        if time.monotonic() > deadline:
            os._exit(99)  # never interrupted: the test fails on this code
        time.sleep(0.01)

def wrap(name):
    real = getattr(compare, name)
    def paused(*args, **kwargs):
        pause()
        return real(*args, **kwargs)
    setattr(compare, name, paused)

if moment == "runs":  # after the first run, while the second is to come
    real_map = compare.parallel_map
    def stalled(*args, **kwargs):
        for i, result in enumerate(real_map(*args, **kwargs)):
            yield result
            if i == 0:
                pause()
    compare.parallel_map = stalled
elif moment == "after-runs":  # the progress bar at 100%, nothing written yet
    wrap("provenance")
elif moment == "staged":  # runs.csv and the plots written into the staging folder, report.md next
    wrap("markdown_report")
elif moment == "swap":  # the first file of the new set moved into the folder, the others not yet
    real_replace = os.replace
    def replace(src, dst, *args, **kwargs):
        real_replace(src, dst, *args, **kwargs)
        if STAGING_PREFIX in str(src) and STAGING_PREFIX not in str(dst) and not go.exists():
            pause()
    os.replace = replace
sys.exit(main(["compare", "--scenarios", *sys.argv[4:], "--estimators", "oracle", "--controllers", "none",
               "--seeds", "1", "--jobs", "1", "--out", out]))
"""


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def _interrupted(moment, out, tmp_path):
    """Run the child to ``moment``, send Ctrl-C to its process group (as a terminal does: the
    workers get it too), let it finish; its exit code."""
    go = tmp_path / f"go-{moment}"
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, moment, str(out), str(go), *NEW],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        line = child.stdout.readline().strip()
        assert line == moment, (line, child.stderr.read())
        os.killpg(child.pid, signal.SIGINT)
        if moment == "swap":  # interrupts are held back there: let it go on once the signal is in
            time.sleep(0.5)
            go.touch()
        _, err = child.communicate(timeout=300)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
    return child.returncode, err


@pytest.mark.parametrize("moment", ["runs", "after-runs", "staged", "swap"])
def test_ctrl_c_leaves_the_old_set_or_the_new_one_never_a_mix(moment, tmp_path):
    from fourwis.training.compare import compare

    out = tmp_path / "compare"
    compare(out, OLD, ["oracle"], ["none"], 1, 1)
    (out / "notes.txt").write_text("mine")  # a file no set wrote
    old = _snapshot(out)
    assert "paper_step_duration_0.6.png" not in old and json.loads(old[MANIFEST])["files"]
    code, err = _interrupted(moment, out, tmp_path)
    assert code == 130 and "fourwis compare: interrupted" in err, err
    now = _snapshot(out)
    assert not [name for name in now if name.startswith(STAGING_PREFIX)]  # no staging folder left
    if moment != "swap":  # interrupted before the swap: the old set, byte for byte
        assert now == old
        return
    # held back during the swap: the new set whole, then the interrupt
    assert now["notes.txt"] == b"mine"
    assert set(json.loads(now[MANIFEST])["files"]) == set(now) - {MANIFEST, "notes.txt"}
    assert "paper_step_duration_0.6.png" in now
    report, runs = now["report.md"].decode(), now["runs.csv"].decode()
    assert all(entry in report and entry in runs for entry in NEW)
    assert now["report.md"] != old["report.md"] and now["runs.csv"] != old["runs.csv"]


def test_a_set_replaces_the_previous_set_and_keeps_what_no_set_wrote(tmp_path):
    out = tmp_path / "out"
    with staged_output(out) as stage:
        for name in ("report.md", "a.png", "b.png"):
            (stage / name).write_text(f"old {name}")
    (out / "notes.txt").write_text("mine")
    with staged_output(out) as stage:
        assert not (stage / "report.md").exists()  # an empty folder of its own, inside out
        for name in ("report.md", "a.png"):
            (stage / name).write_text(f"new {name}")
    assert {p.name for p in out.iterdir()} == {"report.md", "a.png", "notes.txt", MANIFEST}  # b.png: the old set's
    assert (out / "report.md").read_text() == "new report.md" and (out / "notes.txt").read_text() == "mine"
    with pytest.raises(KeyboardInterrupt), staged_output(out) as stage:
        (stage / "report.md").write_text("half")
        raise KeyboardInterrupt
    assert (out / "report.md").read_text() == "new report.md"
    assert {p.name for p in out.iterdir()} == {"report.md", "a.png", "notes.txt", MANIFEST}
    (out / MANIFEST).write_text('{"files": ["../escape", "notes.txt", 3]}')  # a damaged manifest
    (tmp_path / "escape").write_text("outside")
    with staged_output(out) as stage:
        (stage / "report.md").write_text("third")
    assert (tmp_path / "escape").exists() and not (out / "notes.txt").exists()  # only plain names in out


@pytest.mark.skipif(os.geteuid() != 0, reason="/proc refuses new files to root, whom os.access lets write anywhere")
def test_an_unwritable_output_is_refused_before_any_work_even_for_root(tmp_path, monkeypatch):
    from fourwis.envs import simulation as envs_simulation
    from fourwis.training import tune as training_tune
    from fourwis.training.cli import main

    monkeypatch.setattr(envs_simulation.ClosedLoop, "__init__", lambda *a, **k: pytest.fail("a run started"))
    monkeypatch.setattr(training_tune, "calibration_run", lambda **kwargs: pytest.fail("tuning started"))
    for command in (["compare"], ["estimate"], ["simulate", "paper_step"], ["swd", "--A", "20"], ["train"]):
        with pytest.raises(SystemExit, match=f"fourwis {command[0]}: --out /proc/fourwis cannot be written"):
            main([*command, "--out", "/proc/fourwis"])
    with pytest.raises(SystemExit, match="fourwis tune: --out /proc/x.json cannot be written"):
        main(["tune", "--out", "/proc/x.json"])


def test_the_output_folder_is_created_with_a_probe_file_before_any_work(tmp_path):
    out = check_writable(tmp_path / "new" / "folder")
    assert out.is_dir() and not any(out.iterdir())  # created, the probe gone
    assert check_writable(tmp_path / "other" / "t.json", "file").parent.is_dir()
    long_name = tmp_path / ("x" * 300)  # a writable parent (os.access says yes), a name no file system takes
    with pytest.raises(ValueError, match=r"--out .* cannot be written: File name too long"):
        check_writable(long_name)
    assert long_name.name not in os.listdir(tmp_path)

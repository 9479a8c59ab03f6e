"""The progress bars keep their clock running and name the first run's compilation."""

import io
import time

import numba

from fourwis.core.progress import COMPILING, cache_is_cold, progress


def test_a_cache_without_a_compiled_closed_loop_is_cold(tmp_path, monkeypatch):
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "cache"))
    assert cache_is_cold()
    (tmp_path / "cache" / "envs_x").mkdir(parents=True)
    assert cache_is_cold()  # (a folder numba made, nothing compiled in it)
    (tmp_path / "cache" / "envs_x" / "vehicle.step-10.py311.nbi").write_bytes(b"")
    assert cache_is_cold()  # (a small kernel compiled at import: the loop still to compile)
    (tmp_path / "cache" / "envs_x" / "loop.run_cars-470.py311.nbi").write_bytes(b"")
    assert not cache_is_cold()


def test_the_loop_kernel_is_cached_under_the_name_the_check_looks_for():
    """(Where the suite has run a closed loop, the real cache is warm by that name.)"""
    from fourwis.envs.scenarios import make_scenario
    from fourwis.envs.simulation import simulate

    simulate(make_scenario("paper_dlc", duration=0.05))
    assert not cache_is_cold()


def test_the_bar_names_the_compilation_until_its_first_item_and_keeps_ticking(tmp_path, monkeypatch):
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "empty"))
    out = io.StringIO()
    with progress(3, "runs", "run", file=out) as bar:
        assert COMPILING in bar.desc
        time.sleep(2.3)  # no item done: the bar is redrawn anyway, its clock at 00:01, 00:02
        assert "00:02" in out.getvalue()
        bar.update()
        time.sleep(1.2)
        assert bar.desc == "runs"
        bar.update(2)
    assert bar.desc == "runs"

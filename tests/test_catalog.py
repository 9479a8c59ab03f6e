"""`fourwis list`: every scenario, estimator and controller by name, one line each with what it
is and its defaults (read from the code that builds it), and the recorded logs it ships."""

import pytest

from fourwis.control import CONTROLLERS, make_controller
from fourwis.envs.scenarios import SCENARIOS
from fourwis.envs.vehicle import VehicleParams
from fourwis.estimation import ESTIMATORS
from fourwis.training.cli import main


def _listed(capsys, *section) -> dict[str, str]:
    """``fourwis list [section]``'s entries: name -> the rest of its line."""
    assert main(["list", *section]) == 0
    lines = capsys.readouterr().out.splitlines()
    entries = {}
    for line in lines:
        if line.startswith("  ") and not line.startswith("  name ") and not line.startswith("  ("):
            name, _, rest = line.strip().partition(" ")
            assert name not in entries, f"{name} listed twice"
            entries[name] = " ".join(rest.split())
    return entries


def test_list_scenarios_gives_each_one_with_what_it_is_and_its_defaults(capsys):
    entries = _listed(capsys, "scenarios")
    assert set(entries) == set(SCENARIOS) | {"swd_wet"}
    for name, scenario in SCENARIOS.items():
        line = entries[name]
        assert f"{scenario.duration:.1f} s" in line, line
        if name != "random":  # (its speed is drawn)
            assert f"{scenario.speed_kph:g} km/h" in line, line
    assert "40 km/h, mu 0.3, 10.0 s; angle=1" in entries["paper_step"]
    assert "mu 0.5 left / 0.3 right" in entries["paper_split_dlc"]
    assert "mu_patch=0.3" in entries["mu_jump"] and "speed drawn in 30-110 km/h" in entries["random"]
    assert "mu 0.5, 5.5A" in entries["swd_wet"]


def test_list_estimators_and_controllers_give_each_name_its_line(capsys):
    estimators = _listed(capsys, "estimators")
    assert set(estimators) == set(ESTIMATORS)
    assert "mu fixed at 0.8, hand-set noise" in estimators["ckf"] and "mu estimated from 0.8" in estimators["joint"]
    assert "Huber c 3" in estimators["alo-fkf"] and "Huber" not in estimators["fkf"]
    controllers = _listed(capsys, "controllers")
    assert set(controllers) == set(CONTROLLERS) | {"rl:training/policies/ppo_joint"}
    assert "entry 0.07 rad/s" in controllers["esc"]
    for name in (c for c in CONTROLLERS[1:] if c != "esc"):
        built = make_controller(name, VehicleParams())
        assert f"law {built.law}, rear steer {'on' if built.rear_steer else 'off'}" in controllers[name]
        assert f"mu_margin {built.mu_margin:g} sigma" in controllers[name]
    assert "estimator joint" in controllers["rl:training/policies/ppo_joint"]


def test_list_logs_names_the_shipped_log_and_a_bare_list_shows_every_section(capsys):
    assert main(["list", "logs"]) == 0
    text = capsys.readouterr().out
    assert "revs " in text and "Ferrari 250 LM" in text and "550 s at 100 Hz, vehicle vehicle.toml" in text
    assert main(["list"]) == 0
    text = capsys.readouterr().out
    assert all(f"\n{section}:\n" in f"\n{text}" for section in ("scenarios", "estimators", "controllers", "logs"))
    with pytest.raises(SystemExit) as exit_:
        main(["list", "tyres"])
    assert exit_.value.code == 2 and "invalid choice: 'tyres'" in capsys.readouterr().err

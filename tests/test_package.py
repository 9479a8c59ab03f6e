"""The distribution: one top-level import package, its layers' import contracts, and fourwis
beside python-control (which installs the top-level package ``control``)."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """fourwis's wheel, built from a copy of this checkout's sources (setuptools writes build/
    beside them; no network: the build backend of the venv)."""
    source, out = tmp_path_factory.mktemp("source"), tmp_path_factory.mktemp("wheel")
    for name in ("pyproject.toml", "README.md", "fourwis", "envs", "estimation", "control", "training"):
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(path, source / name)
    build = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--quiet", "-w", str(out)]
    subprocess.run([*build, str(source)], check=True, capture_output=True)
    (path,) = out.glob("fourwis-*.whl")
    return path


def test_the_wheel_holds_one_top_level_package_with_its_data(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {name.split("/")[0] for name in names}
    assert {top for top in tops if not top.endswith(".dist-info")} == {"fourwis"}
    for layer in ("core", "envs", "estimation", "control", "training"):
        assert f"fourwis/{layer}/__init__.py" in names
    for data in ("estimation/data/tuned_noise.json", "estimation/data/dugoff_fit.json", "control/data/phase_plane.json",
                 "training/policies/ppo_joint/model.zip"):  # fmt: skip
        assert f"fourwis/{data}" in names
    entry_points = next(name for name in names if name.endswith("entry_points.txt"))
    assert "fourwis = fourwis.training.cli:main" in zipfile.ZipFile(wheel).read(entry_points).decode()


def test_the_layers_import_contracts_hold(wheel, tmp_path):
    """import-linter's contracts (pyproject.toml) on the installed layout: the core imports no
    layer, estimation and control only the core and not each other, envs not training, and no
    two modules of a package import each other (not even inside a function)."""
    zipfile.ZipFile(wheel).extractall(tmp_path / "site")
    lint = Path(sys.executable).parent / "lint-imports"
    result = subprocess.run(
        [str(lint), str(ROOT / "pyproject.toml"), "--no-cache"],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(tmp_path / "site")},
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Contracts: 2 kept, 0 broken." in result.stdout


PYTHON_CONTROL = """
import gymnasium as gym
import numpy as np
import control  # python-control, the Python Control Systems Library
assert hasattr(control, "tf") and "fourwis" not in control.__file__, control.__file__
env = gym.make("fourwis:FourWIS/YawStability-v0")
obs, _ = env.reset(seed=0)
obs, *_ = env.step(np.zeros(2, dtype=np.float32))
assert np.all(np.isfinite(obs))
import fourwis
assert gym.make("FourWIS/YawStability-v0") is not None
trajectory = fourwis.simulate(fourwis.make_scenario("paper_step", duration=0.5), "dyc-lqr", "joint")
assert np.all(np.isfinite(trajectory.estimate.beta))
print(control.tf([1.0], [1.0, 1.0]))
"""


def test_fourwis_runs_beside_python_control(tmp_path):
    """In an interpreter away from the checkout (a user's), python-control's ``control`` and
    fourwis live side by side: gym.make, a closed-loop simulate, and control.tf."""
    result = subprocess.run(
        [sys.executable, "-c", PYTHON_CONTROL], cwd=tmp_path, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "s + 1" in result.stdout  # (python-control's transfer function printed)

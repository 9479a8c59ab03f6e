"""Every compiled kernel is also valid Python: with NUMBA_DISABLE_JIT=1 (for debuggers and
coverage tools) the closed loop runs as plain Python and gives the compiled result."""

import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from fourwis.control import make_controller
from fourwis.envs.layout import A_USAGE
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.envs.vehicle import VehicleParams

# 2.5 s of the mu jump with DYC-LQR on the joint estimator: the plant's tyres, the estimator's
# friction update (the car reaches the 0.3 patch at ~1.5 s and saturates its tyres), the
# allocation and the controller all run
RUN = """
import sys, warnings
import numpy as np
warnings.simplefilter("ignore", RuntimeWarning)  # numpy scalars warn where compiled code gives inf quietly
from fourwis.control import make_controller
from fourwis.envs.scenarios import make_scenario
from fourwis.envs.simulation import simulate
from fourwis.envs.vehicle import VehicleParams
traj = simulate(make_scenario("mu_jump", duration=2.5), make_controller("dyc-lqr", VehicleParams()), "joint", seed=3)
np.savez(sys.argv[1], state=traj.state, controls=traj.controls, mu=traj.estimate.mu, v=traj.estimate.v)
"""


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="the reference run must be the compiled one")
def test_with_numba_disabled_the_closed_loop_runs_as_python_and_matches_the_compiled_one(tmp_path):
    out = tmp_path / "python.npz"
    subprocess.run(
        [sys.executable, "-c", RUN, str(out)],
        check=True,
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parent.parent,
        env={**os.environ, "NUMBA_DISABLE_JIT": "1"},
    )
    python = np.load(out)
    compiled = simulate(
        make_scenario("mu_jump", duration=2.5), make_controller("dyc-lqr", VehicleParams()), "joint", seed=3
    )
    assert compiled.aux[:, A_USAGE : A_USAGE + 4].max() > 0.9  # the friction is being learnt
    assert compiled.estimate.mu[-1].mean() < 0.5  # ... and has dropped towards the patch's 0.3
    # the same arithmetic up to the compiler's operation order (measured: 3e-12 in the states)
    np.testing.assert_allclose(python["state"], compiled.state, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(python["controls"], compiled.controls, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(python["mu"], compiled.estimate.mu, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(python["v"], compiled.estimate.v, rtol=1e-9, atol=1e-12)


# five control steps of the single env, whose substeps run in the compiled loop (fourwis.envs.loop)
ENV_RUN = """
import sys, warnings
import gymnasium as gym
import numpy as np
warnings.simplefilter("ignore")
from fourwis.envs.loop import PythonStage
from fourwis.envs.simulation import kernel_parts
env = gym.make("fourwis:FourWIS/YawStability-v0")
env.reset(seed=4)
assert not any(isinstance(part, PythonStage) for part in kernel_parts(env.unwrapped._core.loop))
np.save(sys.argv[1], np.array([env.step(np.array([0.5, -0.3], np.float32))[0] for _ in range(5)]))
"""


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="the reference run must be the compiled one")
def test_with_numba_disabled_the_compiled_env_loop_runs_as_python(tmp_path):
    runs = {}
    for name, disable in (("python", "1"), ("compiled", "0")):
        runs[name] = tmp_path / f"{name}.npy"
        subprocess.run(
            [sys.executable, "-c", ENV_RUN, str(runs[name])],
            check=True,
            capture_output=True,
            text=True,
            cwd=Path(__file__).resolve().parent.parent,
            env={**os.environ, "NUMBA_DISABLE_JIT": disable},
        )
    np.testing.assert_allclose(np.load(runs["python"]), np.load(runs["compiled"]), rtol=1e-5, atol=1e-6)

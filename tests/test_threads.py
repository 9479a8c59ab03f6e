"""The parallel kernels (plant, estimator) on two threads give exactly the results of
the one-car serial kernels: no shared scratch, no race, no order dependence. The rest of the
suite runs one numba thread per pytest-xdist worker (tests/conftest.py), so this is where the
threads meet."""

import numpy as np
import pytest

from fourwis.core.kernels import kernel_threads, max_threads, set_threads, share_cores
from fourwis.envs.layout import NU
from fourwis.envs.road import uniform
from fourwis.envs.sensors import SensorModel, SensorParams
from fourwis.envs.simulation import truth_of
from fourwis.envs.vehicle import VehicleParams, initial_state, step
from fourwis.estimation import make_estimator

P = VehicleParams()


@pytest.fixture
def two_threads():
    if max_threads() < 2:
        pytest.skip("a single core here")
    before = kernel_threads()
    set_threads(2)
    yield
    set_threads(before)


def test_parallel_plant_and_estimator_on_two_threads_equal_the_serial_kernels(two_threads):
    rng = np.random.default_rng(5)
    n = 64  # the plant's parallel threshold (envs.vehicle.PARALLEL_MIN_BATCH)
    state = initial_state(P, rng.uniform(10.0, 30.0, n), n)
    controls = np.zeros((n, NU))
    controls[:, :4] = rng.uniform(-300, 300, (n, 4))
    controls[:, 4] = rng.uniform(-0.1, 0.1, n)
    roads = [uniform(m) for m in rng.uniform(0.3, 1.0, n)]
    batch = step(state, controls, P, roads, 0.002, 100)
    for b in (0, 17, 63):
        single = step(state[b : b + 1], controls[b : b + 1], P, roads[b], 0.002, 100)
        np.testing.assert_array_equal(batch.state[b], single.state[0])

    # the joint estimator on 8 cars (parallel kernel) against each car alone (serial kernel)
    cars = [0, 5, 9, 20, 33, 41, 50, 62]
    sensors = SensorModel(SensorParams(), (), len(cars), [np.random.default_rng(s) for s in cars])
    readings, x = [], state[cars]
    for k in range(150):
        x, aux = step(x, controls[cars], P, [roads[c] for c in cars], 0.002)
        readings.append(sensors.measure(truth_of(x, aux)[0], k * 0.002))
    batched = make_estimator("joint", P)
    batched.reset(readings[0], x[:, 3])
    singles = [make_estimator("joint", P) for _ in cars]
    for i, est in enumerate(singles):
        est.reset(_row(readings[0], i), x[i : i + 1, 3])
    for reading in readings:
        together = batched.step(reading)
        for i, est in enumerate(singles):
            alone = est.step(_row(reading, i))
            for field in ("u", "v", "r", "mu"):
                np.testing.assert_array_equal(getattr(together, field)[i], getattr(alone, field)[0])


def _row(reading, i):
    return type(reading)(*(np.ascontiguousarray(f[i : i + 1]) for f in reading))


def test_compiled_closed_loop_on_two_threads_equals_one_thread(two_threads):
    """The compiled loop shares a batch's cars among the kernel thread count of Python threads."""
    from fourwis.envs.gym_env import YawStabilityVectorEnv

    def run() -> list:
        env = YawStabilityVectorEnv(num_envs=5, max_episode_steps=40)
        obs, _ = env.reset(seed=2)
        rng = np.random.default_rng(0)
        seen = [obs]
        for _ in range(60):
            seen += list(env.step(rng.uniform(-1, 1, (5, 2)).astype(np.float32))[:4])
        return seen

    threaded = run()
    set_threads(1)
    for a, b in zip(threaded, run()):
        np.testing.assert_array_equal(a, b)


def test_the_thread_count_is_checked_and_read_from_the_environment(monkeypatch):
    monkeypatch.setattr("fourwis.core.kernels._threads", None)
    monkeypatch.setenv("FOURWIS_THREADS", "1")
    assert kernel_threads() == 1
    monkeypatch.setenv("FOURWIS_THREADS", "many")
    with pytest.raises(ValueError, match="FOURWIS_THREADS must be an integer from 1 to .*'many'"):
        kernel_threads()
    set_threads(1)  # the setting wins over the environment
    assert kernel_threads() == 1
    for bad in (0, max_threads() + 1, 1.5, "2"):
        with pytest.raises(ValueError, match="threads must be an integer from 1"):
            set_threads(bad)


def test_worker_processes_share_the_cores_unless_a_count_was_set(monkeypatch):
    """A pool's worker takes cores // workers threads (at least 1); a set count or
    FOURWIS_THREADS is kept."""
    monkeypatch.setattr("fourwis.core.kernels._threads", None)
    monkeypatch.delenv("FOURWIS_THREADS", raising=False)
    share_cores(2)
    assert kernel_threads() == max(1, max_threads() // 2)
    monkeypatch.setattr("fourwis.core.kernels._threads", None)
    share_cores(max_threads() + 3)
    assert kernel_threads() == 1
    monkeypatch.setattr("fourwis.core.kernels._threads", None)
    share_cores(1)
    assert kernel_threads() == max_threads()
    set_threads(1)
    share_cores(1)
    assert kernel_threads() == 1
    monkeypatch.setattr("fourwis.core.kernels._threads", None)
    monkeypatch.setenv("FOURWIS_THREADS", "1")
    share_cores(1)
    assert kernel_threads() == 1
    set_threads(1)

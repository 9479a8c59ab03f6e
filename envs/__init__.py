"""Truth plant, road, sensors, scenarios and Gymnasium environments of fourwis.

Exports are loaded lazily, so ``import envs`` stays cheap (gymnasium imports it for registration).
"""

from importlib import import_module

_EXPORTS = {
    "PAPER_SCENARIOS": "envs.scenarios", "SCENARIOS": "envs.scenarios", "Scenario": "envs.scenarios",
    "make_scenario": "envs.scenarios", "Trajectory": "envs.simulation", "simulate": "envs.simulation",
    "VehicleParams": "envs.vehicle",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'envs' has no attribute {name!r}")


#: gymnasium's TimeLimit for gym.make: 30 s at the default 20 ms control step, beyond every
#: scenario's default duration (the longest, paper_split_dlc, runs 27.4 s); episodes end at
#: their scenario's end (tests/test_gym_env.py checks the durations)
MAX_EPISODE_STEPS = 1500


def _register() -> None:
    """Register the Gymnasium environment once (idempotent: spawn/forkserver workers re-import)."""
    import gymnasium

    if "FourWIS/YawStability-v0" not in gymnasium.registry:
        gymnasium.register(id="FourWIS/YawStability-v0", entry_point="envs.gym_env:YawStabilityEnv",
                           vector_entry_point="envs.gym_env:YawStabilityVectorEnv",
                           max_episode_steps=MAX_EPISODE_STEPS)


_register()

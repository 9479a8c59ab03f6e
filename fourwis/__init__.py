"""fourwis: a four-wheel independent drive and steering electric car on roads whose friction
varies per wheel, its state and road-friction estimators, and the stability controllers that
use the estimate, judged in closed loop.

``import fourwis`` registers the Gymnasium environment ``FourWIS/YawStability-v0`` (also
reachable as ``gym.make("fourwis:FourWIS/YawStability-v0")`` from a fresh interpreter) and
exposes the public API below; each name is imported on first use, so ``import fourwis`` stays
cheap.
"""

from importlib import import_module

__version__ = "0.2.0"

#: the public names, by the module that defines them
_EXPORTS = {
    "fourwis.core.types": ("CHANNELS", "Command", "Controller", "Estimate", "Estimator", "SensorReading"),
    "fourwis.core.constants": ("GRAVITY",),
    "fourwis.core.kernels": ("set_threads",),
    "fourwis.envs.scenarios": ("PAPER_SCENARIOS", "SCENARIOS", "Scenario", "make_scenario"),
    "fourwis.envs.simulation": ("ClosedLoop", "Trajectory", "simulate"),
    "fourwis.envs.vehicle": ("VehicleParams",),
    "fourwis.envs.tyre": ("TyreParams",),
    "fourwis.envs.sensors": ("Fault", "SensorParams"),
    "fourwis.envs.gym_env": ("YawStabilityEnv", "YawStabilityVectorEnv"),
    "fourwis.estimation": ("ESTIMATORS", "NoiseParams", "StateEstimator", "make_estimator"),
    "fourwis.control": ("CONTROLLERS", "StabilityController", "make_controller"),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)

#: the Gymnasium id of the yaw-stability task (episode steps: fourwis.envs.MAX_EPISODE_STEPS)
ENV_ID = "FourWIS/YawStability-v0"


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'fourwis' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])


def _register() -> None:
    """Register the Gymnasium environment once (idempotent: spawn/forkserver workers re-import)."""
    import gymnasium

    from fourwis.envs import MAX_EPISODE_STEPS

    if ENV_ID not in gymnasium.registry:
        gymnasium.register(
            id=ENV_ID,
            entry_point="fourwis.envs.gym_env:YawStabilityEnv",
            vector_entry_point="fourwis.envs.gym_env:YawStabilityVectorEnv",
            max_episode_steps=MAX_EPISODE_STEPS,
        )


_register()

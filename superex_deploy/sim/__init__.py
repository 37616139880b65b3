"""The simulator's side: the world that owns the ground truth, the episode loop joining it to the onboard explorer,
and (with the ``gym`` extra) the Gymnasium environment ``SuperEx/Explore-v0``.
"""

from superex_deploy.sim.world import World, WorldConfig

__all__ = ["World", "WorldConfig"]


def _register_gym_env() -> None:
    """Register ``SuperEx/Explore-v0`` when Gymnasium is installed (the ``gym`` extra)."""
    try:
        import gymnasium
    except ImportError:
        return
    if "SuperEx/Explore-v0" not in gymnasium.registry:
        gymnasium.register(id="SuperEx/Explore-v0", entry_point="superex_deploy.gym_env:ExplorationEnv")


_register_gym_env()

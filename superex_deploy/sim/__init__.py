"""The simulator's side: the world that owns the ground truth and the episode loop joining it to the onboard
explorer (the Gymnasium environment, ``SuperEx/Explore-v0``, is :mod:`superex_deploy.gym_env`, registered there).
"""

from superex_deploy.sim.world import World, WorldConfig

__all__ = ["World", "WorldConfig"]

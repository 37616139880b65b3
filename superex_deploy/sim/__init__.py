"""The simulator's side: the world that owns the ground truth (its sensors, noise and motion) and what an
exploration runs with (:class:`~superex_deploy.sim.exploration.ExplorationConfig`). The episode loop that joins the
world to the onboard explorer and scores it is the evaluation's (:mod:`superex_deploy.evaluation.episodes`); the
Gymnasium environment, ``SuperEx/Explore-v0``, is :mod:`superex_deploy.gym_env`, registered there.
"""

from superex_deploy.sim.world import World, WorldConfig

__all__ = ["World", "WorldConfig"]

"""A Gymnasium environment for learning where to explore: ``SuperEx/Explore-v0`` (needs the ``gym`` extra).

The agent picks a goal among the current frontier regions; the simulated robot drives there with the onboard
explorer (one simulator step per ``MotionConfig.step_m`` of path) until the goal is reached, the explorer asks for a new goal
or ``steps_per_action`` steps have passed. The reward is the area newly known (square metres, carved cells
included). The observation is the explorer's map cropped around the robot, one-hot per cell state, plus the predicted
wall probability when a predictor is given; the agent sees only what the robot knows.

>>> import gymnasium, superex_deploy.gym_env  # importing it registers SuperEx/Explore-v0 (ENV_ID)
>>> env = gymnasium.make("SuperEx/Explore-v0", map="50052750")
"""

from __future__ import annotations

from typing import Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from superex_deploy.onboard.planning.motion import planning_map
from superex_deploy.onboard.planning.planners import NearestFrontier
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, Planner, PlanningContext
from superex_deploy.maps import load_map, random_start
from superex_deploy.messages import MapFrame
from superex_deploy.pipeline import build_explorer
from superex_deploy.evaluation.episodes import make_world_and_explorer

__all__ = ["ExplorationEnv", "ENV_ID"]

ENV_ID = "SuperEx/Explore-v0"
"""The id :class:`ExplorationEnv` is registered under when this module is imported."""


class _AgentGoal(Planner):
    """The agent's choice as a planner: the target cell when it is reachable, else the nearest frontier."""

    name = "agent"

    def __init__(self) -> None:
        self.target: Optional[tuple[int, int]] = None
        self._fallback = NearestFrontier()

    def choose_goal(self, ctx: PlanningContext) -> Optional[tuple[int, int]]:
        target, self.target = self.target, None
        if target is not None and np.isfinite(ctx.travel_cost[target]):
            return target
        return self._fallback.choose_goal(ctx)


def _crop(array: np.ndarray, centre: tuple[int, int], size: int, fill) -> np.ndarray:
    out = np.full((size, size), fill, array.dtype)
    top, left = centre[0] - size // 2, centre[1] - size // 2
    r0, c0 = max(top, 0), max(left, 0)
    r1, c1 = min(top + size, array.shape[0]), min(left + size, array.shape[1])
    if r1 > r0 and c1 > c0:
        out[r0 - top:r1 - top, c0 - left:c1 - left] = array[r0:r1, c0:c1]
    return out


class ExplorationEnv(gym.Env):
    """Frontier-choice exploration on a bundled KTH map.

    Args:
        map: bundled map name (or an image / ROS YAML path).
        predictor: None, or a predictor name of :func:`superex_deploy.onboard.prediction.registry.make_onboard_predictor`
            (adds a channel with its wall probability; ``oracle`` is refused: the agent must not see the truth).
        crop_cells: side of the square observation around the robot (cells).
        max_frontiers: size of the Discrete action space; frontier regions beyond it (farthest first) are dropped.
        steps_per_action: simulator steps per action at most.
        max_steps: simulator steps per episode (truncation).
        profile: the pipeline's profile (:data:`superex_deploy.pipeline.PROFILES`; None: the default pipeline's,
            ``PIPELINES[DEFAULT_PIPELINE].profile``: :data:`~superex_deploy.pipeline.DEFAULT_PROFILE`), on the
            simulated clock (reproducible for a seed).

    Spaces:
        observation: float32 ``[C, crop, crop]`` in [0, 1]: free, occupied, unknown (+ predicted wall probability).
        action: ``Discrete(max_frontiers)``; ``info["action_mask"]`` (int8 ``[max_frontiers]``) marks the frontier
            regions the robot can reach, nearest first, that it has not reached before; a masked-out action drives
            to the nearest frontier (``info["masked_action"]``).
        info: also ``steps``, ``coverage``, ``known_m2`` and the explorer's last ``status`` and ``reason``
            (:attr:`~superex_deploy.messages.Command.status`).

    Episodes follow Gymnasium's contract: :meth:`step` raises ``RuntimeError`` before the first :meth:`reset`,
    after an episode ended (``terminated`` or ``truncated``) until the next :meth:`reset`, and after
    :meth:`close` (a :meth:`reset` then starts afresh).
    """

    metadata = {"render_modes": []}

    def __init__(self, map: str = "50052750", predictor: Optional[str] = None, crop_cells: int = 64,
                 max_frontiers: int = 16, steps_per_action: int = 40, max_steps: int = 500,
                 profile: Optional[str] = None):
        from superex_deploy.onboard.prediction.registry import kind_of
        from superex_deploy.pipeline import DEFAULT_PIPELINE, PIPELINES, PREDICTORS, check_profile, make_predictor

        if kind_of(predictor).reads_truth:
            raise ValueError(f"the {predictor} predictor shows the agent the ground truth; choose another")
        if kind_of(predictor).reads_evidence:
            usable = [name for name, kind in PREDICTORS.items() if not kind.reads_evidence and not kind.reads_truth]
            raise ValueError(f"predictor {predictor!r} reads SPAD evidence, which this environment does not simulate; "
                             f"choose {' or '.join(usable)}")
        for name, value in (("crop_cells", crop_cells), ("max_frontiers", max_frontiers),
                            ("steps_per_action", steps_per_action), ("max_steps", max_steps)):
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        self.profile = PIPELINES[DEFAULT_PIPELINE].profile if profile is None else profile
        chosen = check_profile(self.profile, _AgentGoal(), predictor or "observed")
        self.grid = load_map(map)
        self._predictor = make_predictor(predictor, profile=chosen) if predictor is not None else None
        self.crop_cells, self.max_frontiers = int(crop_cells), int(max_frontiers)
        self.steps_per_action, self.max_steps = int(steps_per_action), int(max_steps)
        channels = 3 + (self._predictor is not None)
        self.observation_space = spaces.Box(0.0, 1.0, (channels, self.crop_cells, self.crop_cells), np.float32)
        self.action_space = spaces.Discrete(self.max_frontiers)
        self._cfg = chosen.episode_config()
        self._world = self._explorer = None
        self._goals: list[tuple[int, int]] = []
        self._ended: Optional[str] = "reset() has not been called yet"  # why step() is refused, or None

    def close(self) -> None:
        if self._explorer is not None:
            self._explorer.close()
        self._ended = "the environment is closed"

    def _observation(self) -> np.ndarray:
        observed = self._explorer.observed
        pose = self._world.pose_rc
        crop = _crop(observed, pose, self.crop_cells, UNKNOWN)
        planes = [crop == FREE, crop == OCCUPIED, crop == UNKNOWN]
        if self._predictor is not None:
            planes.append(_crop(self._explorer.predict().mean, pose, self.crop_cells, np.float32(0.5)))
        return np.stack(planes).astype(np.float32)

    def _action_mask(self) -> np.ndarray:
        blocks = self._explorer.planning_grid  # the explorer plans (and its agent chooses) on these
        plan = planning_map(self._explorer.planning_observed, blocks.block(self._world.pose_rc), blocks.block_m,
                            self._cfg.explorer.motion)
        # The explorer's own rules: a region already reached (in sight within the tolerance) or whose goal cell was
        # visited before would be dropped at once, wasting the action.
        regions = self._explorer.frontier_candidates(self._world.pose_rc)
        reachable = [(plan.travel_cost[f.cell_rc], f.cell_rc) for f in regions if np.isfinite(plan.travel_cost[f.cell_rc])]
        reachable.sort()
        self._goals = [cell for _, cell in reachable[:self.max_frontiers]]
        mask = np.zeros(self.max_frontiers, np.int8)
        mask[:len(self._goals)] = 1
        return mask

    def _known_m2(self) -> float:
        return float(self._explorer.mapper.known().sum()) * self.grid.resolution_m ** 2

    def _info(self) -> dict:
        return {"action_mask": self._action_mask(), "steps": self._world.steps,
                "coverage": self._world.coverage(self._explorer.mapper.known()), "known_m2": self._known_m2(),
                "status": self._command.status, "reason": self._command.reason}

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        self.close()
        start = random_start(self.grid, self.np_random, 0.4)
        self._agent = _AgentGoal()
        explorer = build_explorer(MapFrame(self.grid.shape, self.grid.resolution_m), self._agent,
                                  self._predictor or ObservedAsPrediction(), profile=self.profile,
                                  seed=int(self.np_random.integers(2 ** 31)), cfg=self._cfg.explorer)
        self._world, self._explorer = make_world_and_explorer(self.grid, start, cfg=self._cfg, explorer=explorer)
        self._command = self._explorer.step(self._world.observe())
        self._ended = None
        return self._observation(), self._info()

    def step(self, action):
        if self._ended is not None:
            raise RuntimeError(f"step() needs a running episode: {self._ended}; call reset() to start one")
        if not self.action_space.contains(action):
            raise ValueError(f"action must be an integer in [0, {self.max_frontiers}), got {action!r}")
        # A masked-out action (an agent that ignores info["action_mask"], or the environment checker's random one)
        # drives to the nearest frontier instead, and info["masked_action"] says so.
        masked = int(action) >= len(self._goals)
        before = self._known_m2()
        self._agent.target = None if masked else self._goals[int(action)]
        self._explorer.drop_goal()  # choose again, now
        command = self._command
        for inner in range(self.steps_per_action):
            if self._world.steps >= self.max_steps:
                break
            if inner > 0:  # the first inner step re-scans where the robot stands and takes the new target
                self._world.apply(command)
            command = self._explorer.step(self._world.observe())
            if command.finished or (inner > 0 and command.new_goal):
                break
        self._command = command
        reward = self._known_m2() - before
        terminated = bool(command.finished)
        truncated = not terminated and self._world.steps >= self.max_steps
        info = self._info()
        info["masked_action"] = masked
        if not terminated and not info["action_mask"].any():
            terminated = True  # nothing reachable is left to choose
        if terminated or truncated:
            self._ended = f"the episode has {'terminated' if terminated else 'been truncated'}"
        return self._observation(), float(reward), terminated, truncated, info


if ENV_ID not in gym.registry:  # registered beside its class, once per process
    gym.register(id=ENV_ID, entry_point=f"{__name__}:ExplorationEnv")

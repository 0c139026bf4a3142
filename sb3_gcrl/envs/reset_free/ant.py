"""Reset-free Ant in an open square arena (thesis Section 3.7.1 "Ant", Figure 3.1; adapted by the thesis from
PEG's AntMaze by making the maze a square).

Built on gymnasium-robotics' ``AntMaze`` v5 (Gymnasium's Ant in a MuJoCo maze) with an open 2 x 2-cell map at
AntMaze's fixed cell size of 4: the ant moves in the square [-4, 4]^2, bounded by walls.

- ``observation`` (27,): the Ant's qpos without x, y (13) and qvel (14) - the thesis's 29-dim state minus the
  goal-space coordinates; contact forces are excluded (``include_cfrc_ext_in_observation=False``).
- ``achieved_goal`` / ``desired_goal`` (2,): torso xy. Action Box(-1, 1, (8,)) joint torques.
- Reward (AntMaze): 1 if ``||achieved - desired|| <= 0.45`` else 0; ``info["is_success"]`` the same test.
  Never terminates (a flipped ant is not detected; hard resets recover it).
- rho_0: the centre (0, 0) plus U(-0.1, 0.1)^2 noise. rho_g*: U(2, 3)^2, the corner region the thesis uses
  (it calls it the top-left corner; in MuJoCo's frame it is the +x, +y corner).
- Evaluation horizon 500 steps; hard reset every 2e5 steps (thesis).

Departures: PEG's own AntMaze (mrl codebase) has other arena/threshold constants that the thesis does not
state; the arena size [-4, 4]^2 and the 0.45 success radius are gymnasium-robotics' AntMaze values.
AntMaze writes the maze XML to a temporary file; we delete it once MuJoCo has loaded it.
"""

from __future__ import annotations

import contextlib
import os
from typing import Any, ClassVar

import numpy as np
from gymnasium.utils import EzPickle
from gymnasium_robotics.envs.maze.ant_maze_v5 import AntMazeEnv
from gymnasium_robotics.envs.maze.maze_v4 import MazeEnv

from sb3_gcrl.envs.reset_free.reset_options import commanded_goal

#: Success radius on torso xy (AntMaze).
SUCCESS_THRESHOLD = 0.45
#: Open square arena: 2 x 2 free cells of size 4 inside a wall border, i.e. the free square [-4, 4]^2.
ARENA_MAP = [
    [1, 1, 1, 1],
    [1, 0, 0, 1],
    [1, 0, 0, 1],
    [1, 1, 1, 1],
]
ARENA_HALF_SIZE = 4.0
#: Goal-space box (torso xy), for binning visited goals and heatmaps.
GOAL_LOW, GOAL_HIGH = (-ARENA_HALF_SIZE, -ARENA_HALF_SIZE), (ARENA_HALF_SIZE, ARENA_HALF_SIZE)
#: rho_0: start at the centre with uniform noise of this half-width (thesis: U(-0.1, 0.1)).
START_NOISE = 0.1
#: rho_g*: uniform over [low, high]^2 (thesis: U(2, 3) for both x and y).
GOAL_REGION = (2.0, 3.0)


class AntArenaEnv(AntMazeEnv):
    """``GCRL/AntArena-v0``: Ant starting at the centre of an open square arena, goals in one corner.

    :param render_mode: as Gymnasium's Ant (``"human"``, ``"rgb_array"``, ...).
    :param reward_type: ``"sparse"`` (default, 1 within 0.45) or ``"dense"`` (``exp(-distance)``), as AntMaze.
    :param kwargs: forwarded to Gymnasium's ``Ant-v5`` (``include_cfrc_ext_in_observation`` defaults to False).
    """

    #: success radius in goal space (the name gymnasium-robotics' goal envs use)
    distance_threshold: ClassVar[float] = SUCCESS_THRESHOLD

    def __init__(self, render_mode: str | None = None, reward_type: str = "sparse", **kwargs: Any) -> None:
        if reward_type not in ("sparse", "dense"):
            raise ValueError(f"reward_type must be 'sparse' or 'dense', got {reward_type!r}")
        kwargs.setdefault("include_cfrc_ext_in_observation", False)
        super().__init__(
            render_mode=render_mode,
            maze_map=ARENA_MAP,
            reward_type=reward_type,
            continuing_task=True,
            reset_target=False,
            **kwargs,
        )
        # The compiled model lives in memory; the XML AntMaze wrote into the temp dir is no longer needed.
        with contextlib.suppress(OSError):
            os.remove(self.tmp_xml_file_path)
        EzPickle.__init__(self, render_mode=render_mode, reward_type=reward_type, **kwargs)

    def sample_initial_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_0: the arena centre plus U(-0.1, 0.1)^2 noise (torso xy)."""
        return rng.uniform(-START_NOISE, START_NOISE, size=2)

    def sample_evaluation_goal(self, rng: np.random.Generator) -> np.ndarray:
        """rho_g*: uniform over the corner region [2, 3]^2."""
        return rng.uniform(*GOAL_REGION, size=2)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        # Replaces MazeEnv's cell-based start/goal sampling with rho_0 / rho_g*; the rest is AntMaze's reset.
        super(MazeEnv, self).reset(seed=seed)  # GoalEnv.reset: seeds self.np_random, checks the spaces
        goal = commanded_goal(options, self.observation_space["desired_goal"], "AntArena")
        self.goal = self.sample_evaluation_goal(self.np_random) if goal is None else goal
        self.reset_pos = self.sample_initial_goal(self.np_random)
        self.update_target_site_pos()
        self.ant_env.init_qpos[:2] = self.reset_pos
        ant_obs, info = self.ant_env.reset(seed=seed)
        obs = self._get_obs(ant_obs)
        info["success"] = info["is_success"] = self._is_success(obs["achieved_goal"])
        return obs, info

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        info["is_success"] = info["success"]
        return obs, reward, terminated, truncated, info

    def _is_success(self, achieved_goal: np.ndarray) -> bool:
        return bool(np.linalg.norm(achieved_goal - self.goal) <= SUCCESS_THRESHOLD)

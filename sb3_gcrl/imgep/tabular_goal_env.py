"""A tabular env seen as a goal env with the one-hot goal reward of thesis Eq. 6.6.

:class:`TabularGoalEnv` turns an env with a ``Discrete`` observation (e.g. ``GCRL/FourRoomsTabular-v0``)
into a gymnasium-robotics style goal env whose goals are discrete too: ``achieved_goal = goal_of_state[s]``,
reward ``R_g(s, a, s') = 1[goal(s') = g]`` (Eq. 6.6), ``info["is_success"]``. For the MiniGrid tabular tasks
the goal space is the agent's cell ``(x, y)`` (``state // 4``, direction dropped) and the reachable goals are
found by a breadth-first search over the grid (lava and walls excluded) and the env's own task is the goal tile's
cell (:attr:`TabularGoalEnv.task_goal`); for any other Discrete env goals are states, every state counts as
reachable unless ``reachable_goals`` is given, and the task goal is unknown unless ``task_goal`` is given.
"""

from __future__ import annotations

from collections import deque
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import unwrap_wrapper

from sb3_gcrl.envs.minigrid_tabular import N_DIRECTIONS, TabularMiniGridObservation
from sb3_gcrl.wrappers.goal_env import record_constructor_args


def minigrid_reachable_cells(env: gym.Env) -> np.ndarray:
    """Cells ``y * width + x`` reachable from the agent's start cell without entering walls or lava.

    The env is reset once (the tabular tasks have a fixed layout per ``layout_seed``).

    :param env: a MiniGrid env (possibly wrapped).
    :return: sorted int64 array of cell indices.
    """
    env.reset()
    base = env.unwrapped
    width, height = int(base.width), int(base.height)
    start = (int(base.agent_pos[0]), int(base.agent_pos[1]))
    seen = {start}
    queue = deque([start])
    while queue:
        x, y = queue.popleft()
        for nx, ny in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
            if not (0 <= nx < width and 0 <= ny < height) or (nx, ny) in seen:
                continue
            cell = base.grid.get(nx, ny)
            if cell is not None and (not cell.can_overlap() or cell.type == "lava"):
                continue
            seen.add((nx, ny))
            queue.append((nx, ny))
    return np.array(sorted(y * width + x for x, y in seen), dtype=np.int64)


def minigrid_task_goal(env: gym.Env) -> int | None:
    """Cell ``y * width + x`` of the grid's goal tile (the env's own task), or None when there is not exactly one.

    The env is reset once (the tabular tasks have a fixed layout per ``layout_seed``).

    :param env: a MiniGrid env (possibly wrapped).
    :return: the goal tile's cell index, or None.
    """
    env.reset()
    base = env.unwrapped
    width, height = int(base.width), int(base.height)
    cells = [
        y * width + x
        for y in range(height)
        for x in range(width)
        if getattr(base.grid.get(x, y), "type", None) == "goal"
    ]
    return cells[0] if len(cells) == 1 else None


class TabularGoalEnv(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Goal env over a Discrete-observation env, with one-hot goal reward (thesis Eq. 6.6).

    Observation: ``Dict(observation=Discrete(n_states), achieved_goal=Discrete(n_goals),
    desired_goal=Discrete(n_goals))``. The goal of an episode is ``reset(options={"goal": g})``; without it a
    goal is drawn uniformly from :attr:`reachable_goals`. The env's own reward is replaced by Eq. 6.6.

    :param env: env with a Discrete observation space.
    :param goal_of_state: lookup table state -> goal index (``None``: MiniGrid tabular tasks use the cell
        ``state // 4``; any other env uses the state itself).
    :param n_goals: size of the goal space (inferred with ``goal_of_state``'s default).
    :param reachable_goals: goals to evaluate on and to draw default goals from (MiniGrid: BFS over the grid;
        otherwise all goals).
    :param terminate_at_goal: end the episode (``terminated``) when the goal is reached. True for evaluation;
        :class:`~sb3_gcrl.imgep.TabularIMGEP` sets it False and decides itself (post-exploration).
    :param task_goal: the goal that solves the wrapped env's own task, commanded when an agent is given a bare
        state of the env (``TabularIMGEP.predict``, ``evaluate_policy`` or ``EvalCallback`` on the plain env).
        ``None``: MiniGrid tabular tasks use the goal tile's cell; for any other env it stays unknown.
    """

    def __init__(
        self,
        env: gym.Env,
        goal_of_state: np.ndarray | None = None,
        n_goals: int | None = None,
        reachable_goals: np.ndarray | None = None,
        terminate_at_goal: bool = True,
        task_goal: int | None = None,
    ) -> None:
        if not isinstance(env.observation_space, spaces.Discrete):
            raise TypeError(
                f"TabularGoalEnv needs a Discrete observation space (a tabular env such as "
                f"GCRL/FourRoomsTabular-v0), got {env.observation_space}"
            )
        if not isinstance(env.action_space, spaces.Discrete):
            raise TypeError(f"TabularGoalEnv needs a Discrete action space, got {env.action_space}")
        record_constructor_args(self, locals())
        gym.Wrapper.__init__(self, env)
        n_states = int(env.observation_space.n)
        minigrid = unwrap_wrapper(env, TabularMiniGridObservation)
        if goal_of_state is None:
            if minigrid is not None:
                goal_of_state = np.arange(n_states, dtype=np.int64) // N_DIRECTIONS
                n_goals = n_states // N_DIRECTIONS
            else:
                goal_of_state = np.arange(n_states, dtype=np.int64)
                n_goals = n_states
        goal_of_state = np.asarray(goal_of_state, dtype=np.int64)
        if goal_of_state.shape != (n_states,):
            raise ValueError(f"goal_of_state needs one goal per state ({n_states}), got shape {goal_of_state.shape}")
        n_goals = int(goal_of_state.max()) + 1 if n_goals is None else int(n_goals)
        if goal_of_state.min() < 0 or goal_of_state.max() >= n_goals:
            raise ValueError(f"goal_of_state values must lie in [0, n_goals={n_goals})")
        self.goal_of_state = goal_of_state
        self.n_goals = n_goals
        if reachable_goals is None:
            reachable_goals = minigrid_reachable_cells(env) if minigrid is not None else np.arange(n_goals)
        self.reachable_goals = np.unique(np.asarray(reachable_goals, dtype=np.int64))
        if self.reachable_goals.size == 0 or self.reachable_goals.max() >= n_goals or self.reachable_goals.min() < 0:
            raise ValueError(f"reachable_goals must be a non-empty set of goal indices in [0, {n_goals})")
        self.terminate_at_goal = bool(terminate_at_goal)
        if task_goal is None and minigrid is not None:
            task_goal = minigrid_task_goal(env)
        if task_goal is not None and not 0 <= int(task_goal) < n_goals:
            raise ValueError(f"task_goal must be a goal index in [0, {n_goals}), got {task_goal}")
        #: goal of the wrapped env's own task (None: unknown)
        self.task_goal = None if task_goal is None else int(task_goal)
        self.observation_space = spaces.Dict(
            {
                "observation": spaces.Discrete(n_states),
                "achieved_goal": spaces.Discrete(n_goals),
                "desired_goal": spaces.Discrete(n_goals),
            }
        )
        self.goal = int(self.reachable_goals[0])

    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray | float:
        """One-hot goal reward, Eq. 6.6 (vectorised)."""
        reward = (np.asarray(achieved_goal) == np.asarray(desired_goal)).astype(np.float64)
        return float(reward) if reward.ndim == 0 else reward

    def _obs(self, state: Any) -> dict[str, np.int64]:
        state = np.int64(state)
        return {
            "observation": state,
            "achieved_goal": np.int64(self.goal_of_state[state]),
            "desired_goal": np.int64(self.goal),
        }

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        options = dict(options or {})
        goal = options.pop("goal", None)
        state, info = self.env.reset(seed=seed, options=options or None)
        if goal is None:
            goal = self.np_random.choice(self.reachable_goals)
        if not 0 <= int(goal) < self.n_goals:
            raise ValueError(f"goal {goal} is outside the goal space [0, {self.n_goals})")
        self.goal = int(goal)
        info["is_success"] = False
        return self._obs(state), info

    def step(self, action: Any) -> tuple[dict, SupportsFloat, bool, bool, dict]:
        state, _, terminated, truncated, info = self.env.step(action)
        obs = self._obs(state)
        success = bool(obs["achieved_goal"] == self.goal)
        info["is_success"] = success
        return obs, float(success), bool(terminated or (success and self.terminate_at_goal)), truncated, info

"""Small synthetic envs shared by the tests of the episodic-control, 2M, tabular and IMGEP agents."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class ChainEnv(gym.Env):
    """States ``0 .. n - 1`` on a line, start 0. Action 1 moves right; action 0 moves left (or stays, with
    ``stay_on_zero``). Every step gives ``step_reward``, reaching the last state also ``goal_reward``; the episode
    terminates there if ``terminal_goal`` and is truncated after ``horizon`` steps (``None``: never). The executed
    actions are recorded in ``executed``; ``info["is_success"]`` marks reaching the last state.

    :param n: number of states.
    :param horizon: time limit in steps (``None``: none).
    :param stay_on_zero: action 0 stays instead of moving left.
    :param step_reward: reward of every step.
    :param goal_reward: extra reward for reaching the last state.
    :param terminal_goal: the last state is terminal.
    """

    def __init__(
        self,
        n: int = 5,
        horizon: int | None = None,
        stay_on_zero: bool = False,
        step_reward: float = 0.0,
        goal_reward: float = 1.0,
        terminal_goal: bool = True,
    ) -> None:
        self.observation_space = spaces.Discrete(n)
        self.action_space = spaces.Discrete(2)
        self.n, self.horizon, self.stay_on_zero = n, horizon, stay_on_zero
        self.step_reward, self.goal_reward, self.terminal_goal = step_reward, goal_reward, terminal_goal
        self.executed: list[int] = []
        self.state, self.t = 0, 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.int64, dict]:
        super().reset(seed=seed)
        self.state, self.t = 0, 0
        return np.int64(0), {}

    def step(self, action: int) -> tuple[np.int64, float, bool, bool, dict]:
        self.executed.append(int(action))
        move = 1 if action == 1 else (0 if self.stay_on_zero else -1)
        self.state = int(np.clip(self.state + move, 0, self.n - 1))
        self.t += 1
        at_goal = self.state == self.n - 1
        reward = self.step_reward + (self.goal_reward if at_goal else 0.0)
        truncated = self.horizon is not None and self.t >= self.horizon
        return np.int64(self.state), reward, at_goal and self.terminal_goal, truncated, {"is_success": at_goal}


#: the smallest MoReFree networks (world model, actors, critics, ensemble) used by the tests: a few ms per update
MOREFREE_TINY_NET: dict[str, Any] = {
    "deter": 16,
    "stoch": 4,
    "rssm_hidden": 16,
    "model_hidden": 16,
    "model_layers": 1,
    "head_hidden": 16,
    "head_layers": 1,
    "ensemble_size": 2,
}

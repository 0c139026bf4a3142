"""Sparse MountainCarContinuous (thesis Ch. 4, Sec. 4.5.1, Fig. 4.4).

Registered as ``GCRL/SparseMountainCarContinuous-v0``.

gymnasium's ``MountainCarContinuous-v0`` with its reward replaced: +100 on the step that reaches the flag
(position >= 0.45 and velocity >= 0, which terminates), 0 otherwise. The dense action cost
``-0.1 * action**2`` of the original is removed, as in the thesis ("the agent only gets a final reward
(+100) once it brings the car successfully to the flag").

- Observation: ``Box([-1.2, -0.07], [0.6, 0.07], float32)`` (position, velocity); start position
  ~ U(-0.6, -0.4), velocity 0.
- Action: ``Box(-1, 1, (1,), float32)``, the engine force.
- Horizon: 999 steps (as gymnasium registers the original).
- ``info["is_success"]`` is True on the flag step.

No departure from the thesis's task that we know of (the authors' code gives +100 at the flag, 0 else).
"""

from __future__ import annotations

import numpy as np
from gymnasium.envs.classic_control.continuous_mountain_car import Continuous_MountainCarEnv

FLAG_REWARD = 100.0


class SparseMountainCarContinuousEnv(Continuous_MountainCarEnv):
    """``MountainCarContinuous`` with reward +100 at the flag and 0 otherwise.

    :param flag_reward: reward on reaching the flag.
    :param render_mode: as gymnasium's ``MountainCarContinuous``.
    :param goal_velocity: as gymnasium's ``MountainCarContinuous``.
    """

    def __init__(self, flag_reward: float = FLAG_REWARD, render_mode: str | None = None, goal_velocity: float = 0):
        super().__init__(render_mode=render_mode, goal_velocity=goal_velocity)
        self.flag_reward = float(flag_reward)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, _, terminated, truncated, info = super().step(action)
        info["is_success"] = terminated
        return obs, self.flag_reward if terminated else 0.0, terminated, truncated, info

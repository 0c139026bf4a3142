"""safety-gymnasium's own Goal tasks in the thesis's reading: ``GCRL/SafetyPointGoal0-v0``, ``GCRL/SafetyCarGoal0-v0``.

The real robots and the real task (safety-gymnasium 1.0.0's ``SafetyPointGoal0-v0`` / ``SafetyCarGoal0-v0``:
robot and goal drawn anywhere in [-1, 1]^2 with keep-outs, uniform heading, 16-bin goal lidar, 1000 steps),
with the reward and episode end of our rebuilds (:mod:`sb3_gcrl.envs.safety_nav`): reward 1 when the robot
enters the goal zone (radius 0.3), which ends the episode and sets ``info["is_success"]``; 0 otherwise (no dense
progress reward, no new goal). ``info["cost"]`` passes safety-gymnasium's cost on (always 0: Goal0 has no hazards).

The observation is a ``Box`` of float32 with safety-gymnasium's sensors and lidar flattened in Safety-Gym's order
(keys sorted: accelerometer, [ballangvel_rear, ballquat_rear], goal_lidar, gyro, magnetometer, velocimeter), the
layout of our ``GCRL/PointGoal-v0`` / ``GCRL/CarGoal-v0`` with 16 lidar bins (28 / 40 dims), so any agent that
runs on those runs here. The ids are registered only where safety-gymnasium is installed
(``pip install --no-deps safety-gymnasium==1.0.0 xmltodict``; :mod:`sb3_gcrl.envs.safety_gymnasium_compat` makes
it import on our stack). Several times slower per step than our rebuilds (docs/envs.md): safety-gymnasium
recompiles its scene at every reset and runs three ``mj_forward`` per step.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_gcrl.envs.safety_gymnasium_compat import make_builder

_ROBOTS = {"point": "Point", "car": "Car"}


class SafetyGymnasiumGoalEnv(gym.Env):
    """safety-gymnasium's Goal0 task with its Point or Car robot; sparse reward 1 in the goal zone, which ends the
    episode.

    :param robot: ``"point"`` (28-dim observation) or ``"car"`` (40-dim).
    :raises ModuleNotFoundError: where safety-gymnasium is not installed (the message names the install command).
    """

    metadata = {"render_modes": []}

    def __init__(self, robot: str = "point") -> None:
        if robot not in _ROBOTS:
            raise ValueError(f"robot must be one of {sorted(_ROBOTS)}, got {robot!r}.")
        self.robot = robot
        agent = _ROBOTS[robot]
        self.builder = make_builder(agent, f"Safety{agent}Goal0-v0", {"observation_flatten": False})
        self.builder.task.mechanism_conf.continue_goal = False  # the goal ends the episode
        space_dict = self.builder.obs_space_dict
        self._keys = sorted(space_dict)  # Safety-Gym flattens its keys in sorted order
        low = np.concatenate([np.ravel(space_dict[key].low) for key in self._keys]).astype(np.float32)
        high = np.concatenate([np.ravel(space_dict[key].high) for key in self._keys]).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        # its controls' ranges, [-1, 1] for both robots: the action space; actions are clipped to them
        self._ctrl_low = self.builder.action_space.low.astype(np.float64)
        self._ctrl_high = self.builder.action_space.high.astype(np.float64)
        self.action_space = spaces.Box(self._ctrl_low.astype(np.float32), self._ctrl_high.astype(np.float32))
        self.goal_size = float(self.builder.task.goal.size)

    @property
    def goal(self) -> np.ndarray:
        """The goal's planar position."""
        return self.builder.task.goal.pos[:2].copy()

    @property
    def robot_xy(self) -> np.ndarray:
        """The robot body's planar position."""
        return self.builder.task.agent.pos[:2].copy()

    @property
    def robot_yaw(self) -> float:
        """The robot frame's yaw (rad): the angle of its x axis in the plane."""
        matrix = self.builder.task.agent.mat
        return math.atan2(matrix[1, 0], matrix[0, 0])

    def _flatten(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([np.ravel(obs[key]) for key in self._keys]).astype(np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """A new layout drawn by safety-gymnasium (from ``seed`` if given, else from its own generator).

        :param seed: seed of safety-gymnasium's layout generator.
        :param options: not supported (safety-gymnasium draws the layout).
        """
        super().reset(seed=seed)
        if options:
            raise ValueError(f"{type(self).__name__} takes no reset options, got {sorted(options)}.")
        obs, _ = self.builder.reset(seed=seed)
        return self._flatten(obs), {"is_success": False}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        values = np.asarray(action, dtype=np.float64).ravel()
        if values.shape != self.action_space.shape or not np.all(np.isfinite(values)):
            raise ValueError(f"{type(self).__name__} needs {self.action_space.shape[0]} finite action values.")
        obs, _, cost, terminated, truncated, info = self.builder.step(np.clip(values, self._ctrl_low, self._ctrl_high))
        success = bool(info.get("goal_met", False))
        info = {"is_success": success, "cost": float(cost)}
        return self._flatten(obs), float(success), success or terminated, truncated, info


__all__ = ["SafetyGymnasiumGoalEnv"]

"""``reset(options=...)`` of the reset-free goal envs: ``{"goal": g}`` commands the episode's goal."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces


def commanded_goal(options: dict[str, Any] | None, goal_space: spaces.Box, env_name: str) -> np.ndarray | None:
    """The goal given as ``options={"goal": g}`` (shape and dtype of ``goal_space``), or None when none is given.

    Like ``GCRL/GrowingTreeGoal-v0`` and the PointMaze tasks, the reset-free envs accept an explicit goal (used
    e.g. by :func:`~sb3_gcrl.post_exploration.evaluate_all_goals`); any other option is an error rather than
    silently ignored.

    :param options: the ``options`` passed to ``reset``.
    :param goal_space: the env's ``desired_goal`` space.
    :param env_name: env name for the error messages.
    :raises ValueError: on unknown options, or a goal of the wrong shape or not finite.
    """
    options = dict(options or {})
    goal = options.pop("goal", None)
    if options:
        raise ValueError(f"Unknown reset options {sorted(options)} for {env_name}; it accepts only 'goal'.")
    if goal is None:
        return None
    goal = np.asarray(goal, dtype=goal_space.dtype)
    if goal.shape != goal_space.shape or not np.all(np.isfinite(goal)):
        raise ValueError(f"{env_name} reset goal must be a finite array of shape {goal_space.shape}, got {goal!r}")
    return goal

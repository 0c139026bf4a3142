"""Helpers shared by the wrappers (goal-env checks, the record of constructor arguments), and an
``info["is_success"]`` adapter.

Goal envs follow gymnasium-robotics: a Dict observation with ``observation``,
``achieved_goal`` and ``desired_goal``, a vectorised ``compute_reward(achieved, desired, info)``, and
``info["is_success"]`` (the only key SB3/RL-Zoo read for success rates).
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import unwrap_wrapper
from stable_baselines3.common.monitor import Monitor

from sb3_gcrl.common.validation import check_float

GOAL_KEYS = ("observation", "achieved_goal", "desired_goal")


def record_constructor_args(wrapper: gym.utils.RecordConstructorArgs, arguments: dict[str, Any]) -> None:
    """Record a wrapper's constructor arguments, so that ``gym.make`` can rebuild it from an env's spec (gymnasium's
    ``RecordConstructorArgs``; in a chain of subclasses the first record, the outermost class's, is kept).

    Call it at the start of ``__init__`` with ``locals()``, before any other local exists: the arguments are then
    the constructor's parameters (``self``, ``env`` and the ``__class__`` cell of ``super()`` left out).

    :param wrapper: the wrapper being built.
    :param arguments: ``locals()`` of its ``__init__``.
    """
    recorded = {name: value for name, value in arguments.items() if name not in ("self", "env", "__class__")}
    gym.utils.RecordConstructorArgs.__init__(wrapper, **recorded)


def check_goal_env(env: gym.Env, wrapper_name: str) -> None:
    """Raise a ``TypeError`` naming the fix when ``env`` is not a gymnasium-robotics style goal env.

    :param env: the env about to be wrapped.
    :param wrapper_name: name of the wrapper, used in the message.
    """
    space = env.observation_space
    if not isinstance(space, spaces.Dict) or any(key not in space.spaces for key in GOAL_KEYS):
        raise TypeError(
            f"{wrapper_name} needs a goal env: a Dict observation space with keys {GOAL_KEYS} (gymnasium-robotics "
            f"style), got {space}. Use a goal env such as PointMaze_UMaze-v3 or a GCRL/*Goal-v0 env."
        )
    if space["achieved_goal"].shape != space["desired_goal"].shape:
        raise TypeError(
            f"{wrapper_name}: achieved_goal {space['achieved_goal'].shape} and desired_goal "
            f"{space['desired_goal'].shape} must have the same shape"
        )
    if not callable(getattr(env.unwrapped, "compute_reward", None)):
        raise TypeError(
            f"{wrapper_name} needs env.unwrapped.compute_reward(achieved_goal, desired_goal, info) (vectorised) to "
            "recompute rewards for commanded goals; add it to the env."
        )


class IsSuccessWrapper(
    gym.Wrapper[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray], np.ndarray], gym.utils.RecordConstructorArgs
):
    """Provide ``info["is_success"]`` for goal envs that report success under another key.

    gymnasium-robotics' PointMaze/AntMaze report ``info["success"]``; SB3's ``Monitor``/``EvalCallback`` and
    RL-Zoo only read ``info["is_success"]``. When ``source_key`` is missing from ``info`` the success is
    computed from the distance between achieved and desired goal.

    Placed above an SB3 ``Monitor`` (``make_vec_env`` and RL-Zoo put the Monitor directly around the env and the
    ``env_wrapper`` list above it), the wrapper also adds the key *below* the Monitor, so that a Monitor with
    ``info_keywords=("is_success",)`` (RL-Zoo's ``monitor_kwargs``) finds it at the end of an episode instead of
    raising a ``KeyError``.

    :param env: goal env.
    :param source_key: info key to copy (``"success"`` for gymnasium-robotics mazes).
    :param success_distance: fallback threshold on ``||achieved_goal - desired_goal||`` when ``source_key`` is
        absent; ``None`` raises instead.
    """

    def __init__(self, env: gym.Env, source_key: str = "success", success_distance: float | None = None) -> None:
        check_goal_env(env, type(self).__name__)
        record_constructor_args(self, locals())
        super().__init__(env)
        self.source_key = source_key
        self.success_distance = (
            None
            if success_distance is None
            else check_float("success_distance", success_distance, minimum=0.0, exclusive_minimum=True)
        )
        monitor = unwrap_wrapper(env, Monitor)
        if monitor is not None and not isinstance(monitor.env, IsSuccessWrapper):
            # the Monitor reads info_keywords from the env it wraps: provide the key there too
            monitor.env = IsSuccessWrapper(monitor.env, source_key, success_distance)

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """The env's vectorised reward (gymnasium 1.x wrappers do not forward attributes)."""
        return self.env.unwrapped.compute_reward(achieved_goal, desired_goal, info)

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if "is_success" not in info:
            if self.source_key in info:
                info["is_success"] = bool(info[self.source_key])
            elif self.success_distance is not None:
                distance = np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"])
                info["is_success"] = bool(distance <= self.success_distance)
            else:
                raise KeyError(
                    f"info has neither 'is_success' nor {self.source_key!r}: pass source_key=<the env's success key> "
                    "or success_distance=<goal threshold> to IsSuccessWrapper"
                )
        return obs, reward, terminated, truncated, info

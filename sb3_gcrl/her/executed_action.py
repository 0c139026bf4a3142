"""Replay buffers that store the action the env executed, not the ignored policy action.

Explore phases (:class:`~sb3_gcrl.wrappers.GoExploreWrapper`) and post-exploration replace the agent's action
inside the env. SB3's ``OffPolicyAlgorithm.collect_rollouts`` stores the *policy's* action (``buffer_actions``) and
passes the step's ``infos`` to ``replay_buffer.add``; these buffers read ``info["executed_action"]`` and store that
action instead. Of the three possible mechanisms (algorithm mixin overriding
``_store_transition``, buffer reading ``infos``, callback writing into ``locals``) this one works with every stock
SB3 off-policy algorithm, from an RL-Zoo YAML (``replay_buffer_class``), with HER and with ``n_envs > 1``, and
relies only on the public ``add(..., infos)`` signature.

For ``Box`` action spaces SB3 stores actions rescaled to [-1, 1] (``policy.scale_action``); the executed action
(in env units) is rescaled the same way here.
"""

from __future__ import annotations

from numbers import Real
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.her.goal_selection_strategy import GoalSelectionStrategy
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sb3_gcrl.wrappers.go_explore import EXECUTED_ACTION_KEY


def check_n_sampled_goal(n_sampled_goal: Any, minimum: int = 0, why: str = "") -> int:
    """Check HER's ``n_sampled_goal`` before a HER buffer divides by ``n_sampled_goal + 1``.

    HER relabels ``n_sampled_goal / (n_sampled_goal + 1)`` of each batch: 0 relabels nothing, -1 divides by zero
    and below -1 asks for more relabeled transitions than the batch has.

    :param n_sampled_goal: relabeled goals per real transition.
    :param minimum: the smallest value that makes sense where it is used (0, or 1 where relabeling is needed).
    :param why: why ``minimum`` is above 0 (appended to the message).
    :return: ``n_sampled_goal`` as an int.
    :raises ValueError: naming the valid range, for a value that is not an integer >= ``minimum``.
    """
    if (
        isinstance(n_sampled_goal, bool)
        or not isinstance(n_sampled_goal, Real)
        or n_sampled_goal != int(n_sampled_goal)
    ):
        raise ValueError(f"n_sampled_goal must be an integer >= {minimum}, got {n_sampled_goal!r}")
    if n_sampled_goal < minimum:
        raise ValueError(
            f"n_sampled_goal must be an integer >= {minimum} (relabeled goals per real transition: HER relabels "
            f"n_sampled_goal / (n_sampled_goal + 1) of each batch, 0 none), got {n_sampled_goal}{why}"
        )
    return int(n_sampled_goal)


class ExecutedActionMixin:
    """Mixin for SB3 replay buffers: replace stored actions by ``info["executed_action"]`` when present."""

    action_space: spaces.Space

    def _to_buffer_action(self, action: Any) -> np.ndarray:
        """Env-unit action -> the representation SB3 stores (rescaled to [-1, 1] for ``Box``)."""
        action = np.asarray(action)
        if isinstance(self.action_space, spaces.Box):
            low, high = self.action_space.low, self.action_space.high
            return np.clip(2.0 * (action - low) / (high - low) - 1.0, -1.0, 1.0)
        return action

    def executed_actions(self, action: np.ndarray, infos: list[dict[str, Any]]) -> np.ndarray:
        """Return ``action`` (shape ``(n_envs, ...)``) with rows replaced by the executed actions found in ``infos``.

        :param action: actions SB3 is about to store (policy actions, buffer representation).
        :param infos: one info dict per env of the step.
        :return: the actions to store (``action`` itself when no env replaced its action).
        """
        out = None
        for env_idx, info in enumerate(infos):
            executed = info.get(EXECUTED_ACTION_KEY)
            if executed is not None:
                if out is None:
                    out = np.array(action, copy=True)
                out[env_idx] = self._to_buffer_action(executed).reshape(out[env_idx].shape)
        return action if out is None else out


class ExecutedActionReplayBuffer(ExecutedActionMixin, ReplayBuffer):
    """:class:`~stable_baselines3.common.buffers.ReplayBuffer` storing executed actions (Box observations)."""

    def add(self, obs, next_obs, action, reward, done, infos) -> None:  # type: ignore[no-untyped-def]
        super().add(obs, next_obs, self.executed_actions(action, infos), reward, done, infos)


class ExecutedActionDictReplayBuffer(ExecutedActionMixin, DictReplayBuffer):
    """:class:`~stable_baselines3.common.buffers.DictReplayBuffer` storing executed actions."""

    def add(self, obs, next_obs, action, reward, done, infos) -> None:  # type: ignore[no-untyped-def]
        super().add(obs, next_obs, self.executed_actions(action, infos), reward, done, infos)


class ExecutedActionHerReplayBuffer(ExecutedActionMixin, HerReplayBuffer):
    """:class:`~stable_baselines3.HerReplayBuffer` storing executed actions (same constructor, ``n_sampled_goal``
    checked).

    :param buffer_size: max number of transitions.
    :param observation_space: the goal env's Dict observation space.
    :param action_space: action space.
    :param env: the training VecEnv (serves ``compute_reward``).
    :param device: PyTorch device.
    :param n_envs: number of parallel envs.
    :param optimize_memory_usage: unsupported by HER (SB3 refuses it).
    :param handle_timeout_termination: treat timeouts as non-terminal (SB3's default).
    :param n_sampled_goal: relabeled goals per real transition, an integer >= 0 (:func:`check_n_sampled_goal`).
    :param goal_selection_strategy: ``"future"``, ``"final"`` or ``"episode"``.
    :param copy_info_dict: keep the info dicts for ``compute_reward``.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        env: VecEnv,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_sampled_goal: int = 4,
        goal_selection_strategy: GoalSelectionStrategy | str = "future",
        copy_info_dict: bool = False,
    ) -> None:
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            env,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
            n_sampled_goal=check_n_sampled_goal(n_sampled_goal),
            goal_selection_strategy=goal_selection_strategy,
            copy_info_dict=copy_info_dict,
        )

    def add(self, obs, next_obs, action, reward, done, infos) -> None:  # type: ignore[no-untyped-def]
        super().add(obs, next_obs, self.executed_actions(action, infos), reward, done, infos)

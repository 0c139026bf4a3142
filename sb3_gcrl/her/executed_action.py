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

from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sb3_gcrl.common.validation import check_n_sampled_goal
from sb3_gcrl.wrappers.go_explore import EXECUTED_ACTION_KEY


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
    """:class:`~stable_baselines3.HerReplayBuffer` storing executed actions, with ``n_sampled_goal`` checked.

    :param args: :class:`~stable_baselines3.HerReplayBuffer`'s arguments (``buffer_size``, ``observation_space``,
        ``action_space``, ``env``, ...).
    :param n_sampled_goal: relabeled goals per real transition, an integer >= 0
        (:func:`~sb3_gcrl.common.validation.check_n_sampled_goal`: -1, which SB3 would divide by zero with, is a
        ``ValueError`` naming the valid range).
    :param kwargs: the other :class:`~stable_baselines3.HerReplayBuffer` arguments (``goal_selection_strategy``,
        ``copy_info_dict``, ...).
    """

    def __init__(self, *args: Any, n_sampled_goal: int = 4, **kwargs: Any) -> None:
        super().__init__(*args, n_sampled_goal=check_n_sampled_goal(n_sampled_goal), **kwargs)

    def add(self, obs, next_obs, action, reward, done, infos) -> None:  # type: ignore[no-untyped-def]
        super().add(obs, next_obs, self.executed_actions(action, infos), reward, done, infos)

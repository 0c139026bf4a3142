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

#: the ``replay_buffer_class`` line of an RL-Zoo YAML that stores executed actions
EXECUTED_ACTION_BUFFER_YAML = "\"__import__('sb3_gcrl.her').her.ExecutedActionHerReplayBuffer\""


def check_stores_executed_actions(model: Any, caller: str, replacer: str) -> None:
    """Raise unless ``model`` stores the actions the env executed (``info["executed_action"]``).

    A wrapper that replaces the agent's action (an Explore phase of
    :class:`~sb3_gcrl.wrappers.GoExploreWrapper`, post-exploration) reports the executed action in ``info``; SB3's
    own replay buffers ignore it and store the policy's action, which the env never ran. The buffers of this module,
    and agents that store executed actions themselves (``stores_executed_actions = True``, e.g.
    :class:`~sb3_gcrl.morefree.MoReFree`), pass.

    :param model: the algorithm being trained.
    :param caller: who checks (named in the error).
    :param replacer: what replaces the actions (named in the error).
    :raises TypeError: the model would store actions the env did not execute.
    """
    buffer = getattr(model, "replay_buffer", None)
    if getattr(model, "stores_executed_actions", False) or getattr(buffer, "stores_executed_actions", False):
        return
    raise TypeError(
        f"{caller}: {replacer} replaces the agent's actions, and the replay buffer "
        f"({type(buffer).__name__}) would store the agent's actions, not the ones the env executed; use "
        "replay_buffer_class=sb3_gcrl.her.ExecutedActionHerReplayBuffer (or TaskRelevantHerReplayBuffer; YAML: "
        f"replay_buffer_class: {EXECUTED_ACTION_BUFFER_YAML})"
    )


class ExecutedActionMixin:
    """Mixin for SB3 replay buffers: replace stored actions by ``info["executed_action"]`` when present."""

    action_space: spaces.Space
    #: read by :func:`check_stores_executed_actions`
    stores_executed_actions = True

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

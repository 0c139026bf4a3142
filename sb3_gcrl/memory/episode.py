"""Running episodes of each env and their Monte-Carlo returns: the one episode layer of every episodic memory.

Episodic control learns once an episode is over, from the discounted return of each of its steps (thesis
Algorithm 1, UPDATE; Eq. 5.2 for the tabular memory; Algorithm 2 for the episodic half of 2M): CEC and MFEC, the 2M
agents, tabular episodic control and EMAC's memory all take their episodes from here.

* :class:`EpisodeBuffers` holds the running episode of every env in preallocated, growable arrays;
  :func:`discounted_returns` computes the returns of a finished one.
* An algorithm that collects through SB3's ``collect_rollouts`` records every env step with
  :meth:`EpisodeRecorder.record` and gets back the episodes that ended (:class:`FinishedEpisode`);
  :meth:`FinishedEpisode.updates_memory` says whether one may update the memory: a time-limit cut
  (:func:`truncated_ends`) does only when the algorithm's ``update_truncated`` setting allows it (the thesis's update
  runs on every finished episode). :class:`EpisodeRecordingMixin` keeps such a record in an SB3 algorithm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import lfilter


def discounted_returns(rewards: np.ndarray, gamma: float) -> np.ndarray:
    """Monte-Carlo returns ``G_t = r_t + gamma * G_{t+1}`` of one finished episode (thesis Algorithm 1, UPDATE).

    :param rewards: ``(T,)`` rewards in time order.
    :param gamma: discount factor.
    :return: ``(T,)`` float64 returns.
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    if rewards.size == 0:
        return rewards.copy()
    # G_t = r_t + gamma * G_{t+1} is a first-order IIR filter run backwards in time
    return lfilter([1.0], [1.0, -gamma], rewards[::-1])[::-1].copy()


class EpisodeBuffers:
    """Growable preallocated buffers of the running episode of each of ``n_envs`` envs.

    :meth:`add` appends one step for every env at once (one vectorised write, no per-step Python lists);
    :meth:`pop` returns a finished env's episode and empties its buffer. What is recorded per step (the
    "key") is a memory key, an observation or a state index, as the memory needs.

    :param n_envs: number of envs.
    :param key_shape: shape of what is recorded per step (an int ``d`` means ``(d,)``; ``()`` for a state index).
    :param action_shape: shape of one action (``()`` for discrete actions).
    :param action_dtype: dtype of actions.
    :param key_dtype: dtype of the recorded keys.
    :param initial_length: initial per-env length (doubled when exceeded).
    """

    def __init__(
        self,
        n_envs: int,
        key_shape: int | tuple[int, ...],
        action_shape: tuple[int, ...],
        action_dtype: np.dtype | type = np.float32,
        key_dtype: np.dtype | type = np.float32,
        initial_length: int = 256,
    ) -> None:
        key_shape = (key_shape,) if isinstance(key_shape, (int, np.integer)) else tuple(key_shape)
        self.n_envs = n_envs
        self.keys = np.zeros((n_envs, initial_length, *key_shape), dtype=key_dtype)
        self.actions = np.zeros((n_envs, initial_length, *action_shape), dtype=action_dtype)
        self.rewards = np.zeros((n_envs, initial_length), dtype=np.float64)
        self.lengths = np.zeros(n_envs, dtype=np.int64)
        self._env_indices = np.arange(n_envs)

    def _grow(self) -> None:
        self.keys = np.concatenate([self.keys, np.zeros_like(self.keys)], axis=1)
        self.actions = np.concatenate([self.actions, np.zeros_like(self.actions)], axis=1)
        self.rewards = np.concatenate([self.rewards, np.zeros_like(self.rewards)], axis=1)

    def add(self, keys: np.ndarray, actions: np.ndarray, rewards: np.ndarray) -> None:
        """Append one step for every env (leading dimension ``n_envs`` on all three arguments)."""
        if self.lengths.max() >= self.keys.shape[1]:
            self._grow()
        envs = self._env_indices
        self.keys[envs, self.lengths] = keys
        self.actions[envs, self.lengths] = actions
        self.rewards[envs, self.lengths] = rewards
        self.lengths += 1

    def pop(self, env_idx: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Episode of env ``env_idx`` as ``(keys, actions, rewards)`` copies; the buffer is emptied."""
        n = self.lengths[env_idx]
        out = self.keys[env_idx, :n].copy(), self.actions[env_idx, :n].copy(), self.rewards[env_idx, :n].copy()
        self.lengths[env_idx] = 0
        return out

    def reset(self) -> None:
        """Drop every running episode (e.g. after the envs were reset)."""
        self.lengths[:] = 0


def truncated_ends(dones: np.ndarray, infos: list[dict[str, Any]]) -> np.ndarray:
    """Which episode ends of a step are time-limit truncations (SB3's ``TimeLimit.truncated``).

    :param dones: episode ends of one step, shape (n_envs,).
    :param infos: the step's infos, one per env.
    :return: boolean array, shape (n_envs,).
    """
    return np.array([bool(done) and info.get("TimeLimit.truncated", False) for done, info in zip(dones, infos)])


@dataclass(frozen=True)
class FinishedEpisode:
    """One finished episode of one env, as recorded step by step.

    :param env_index: the env that ran it.
    :param keys: what was recorded per step (a memory key, an observation or a state index), shape (T, ...).
    :param actions: the executed actions, shape (T, ...).
    :param rewards: the rewards, shape (T,).
    :param truncated: whether a time limit cut it.
    """

    env_index: int
    keys: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    truncated: bool

    def updates_memory(self, update_truncated: bool) -> bool:
        """Whether this episode may update an episodic memory: always unless cut by a time limit, then only with
        ``update_truncated``.

        :param update_truncated: the algorithm's setting (``ec_update_truncated`` and the like).
        """
        return update_truncated or not self.truncated

    @property
    def episode_return(self) -> float:
        """Undiscounted return (what the 2M score windows of Eq. 5.6 average)."""
        return float(self.rewards.sum())

    def returns(self, gamma: float) -> np.ndarray:
        """Monte-Carlo return of every step, ``G_t = r_t + gamma * G_{t+1}``.

        :param gamma: discount factor.
        :return: shape (T,), float64.
        """
        return discounted_returns(self.rewards, gamma)


class EpisodeRecorder:
    """The running episode of every env, in preallocated per-env arrays (:class:`EpisodeBuffers`,
    allocated on the first step with its shapes and dtypes).

    :param initial_length: initial per-env length of the arrays (doubled when exceeded).
    """

    def __init__(self, initial_length: int = 256) -> None:
        self.initial_length = initial_length
        self.buffers: EpisodeBuffers | None = None

    def reset(self) -> None:
        """Forget every running episode (the envs were reset)."""
        self.buffers = None

    def record(
        self,
        keys: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> list[FinishedEpisode]:
        """Append one step of every env and hand over the episodes that ended with it.

        :param keys: what to record per env, shape (n_envs, ...).
        :param actions: executed actions, shape (n_envs, ...).
        :param rewards: rewards, shape (n_envs,).
        :param dones: episode ends (termination or truncation), shape (n_envs,).
        :param infos: the step's infos (``TimeLimit.truncated`` marks a cut).
        :return: the finished episodes, in env order.
        """
        keys, actions = np.asarray(keys), np.asarray(actions)
        if self.buffers is None or self.buffers.n_envs != len(keys):
            self.buffers = EpisodeBuffers(
                len(keys), keys.shape[1:], actions.shape[1:], actions.dtype, keys.dtype, self.initial_length
            )
        self.buffers.add(keys, actions, rewards)
        truncated = truncated_ends(dones, infos)
        return [
            FinishedEpisode(int(env_index), *self.buffers.pop(int(env_index)), bool(truncated[env_index]))
            for env_index in np.flatnonzero(dones)
        ]


class EpisodeRecordingMixin:
    """Mix in before an SB3 algorithm that records the running episodes of its training envs in ``_episodes`` (an
    :class:`EpisodeRecorder`, made by the algorithm's constructor or set-up).

    ``learn`` forgets them when it resets the envs (their running episodes are gone), and ``save`` leaves them out (a
    loaded model starts on reset envs).
    """

    _episodes: EpisodeRecorder

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        previous_obs = self._last_obs  # type: ignore[attr-defined]
        result = super()._setup_learn(*args, **kwargs)  # type: ignore[misc]
        if self._last_obs is not previous_obs:  # type: ignore[attr-defined]  (SB3 reset the envs)
            self._episodes.reset()
        return result

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_episodes"]  # type: ignore[misc]

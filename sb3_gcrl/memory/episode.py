"""Running episodes of each env and their Monte-Carlo returns: the one episode layer of every episodic memory.

CEC and MFEC (thesis Algorithm 1), the 2M agents (Algorithm 2) and tabular episodic control (Eq. 5.2) all learn
once an episode is over, from the discounted return of each of its steps.
"""

from __future__ import annotations

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

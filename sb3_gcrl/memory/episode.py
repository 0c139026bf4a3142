"""Per-env buffers of the running episode (keys, actions, rewards) and discounted returns."""

from __future__ import annotations

import numpy as np


def discounted_returns(rewards: np.ndarray, gamma: float, bootstrap: float = 0.0) -> np.ndarray:
    """Monte-Carlo returns ``G_t = r_t + gamma * G_{t+1}`` of one episode (thesis Algorithm 1, UPDATE).

    :param rewards: ``(T,)`` rewards in time order.
    :param gamma: discount factor.
    :param bootstrap: value after the last step (0 for a finished episode).
    :return: ``(T,)`` float64 returns.
    """
    returns = np.empty(len(rewards), dtype=np.float64)
    running = float(bootstrap)
    for t in range(len(rewards) - 1, -1, -1):
        running = float(rewards[t]) + gamma * running
        returns[t] = running
    return returns


class EpisodeBuffers:
    """Growable preallocated buffers of the running episode of each of ``n_envs`` envs.

    :meth:`add` appends one step for every env at once (no per-step Python lists); :meth:`pop`
    returns a finished env's episode and empties its buffer.

    :param n_envs: number of envs.
    :param key_dim: dimension of a memory key.
    :param action_shape: shape of one action (``()`` for discrete actions).
    :param action_dtype: dtype of actions.
    :param initial_length: initial per-env length (doubled when exceeded).
    """

    def __init__(
        self,
        n_envs: int,
        key_dim: int,
        action_shape: tuple[int, ...],
        action_dtype: np.dtype | type = np.float32,
        initial_length: int = 1024,
    ) -> None:
        self.n_envs = n_envs
        self.keys = np.zeros((n_envs, initial_length, key_dim), dtype=np.float32)
        self.actions = np.zeros((n_envs, initial_length, *action_shape), dtype=action_dtype)
        self.rewards = np.zeros((n_envs, initial_length), dtype=np.float64)
        self.lengths = np.zeros(n_envs, dtype=np.int64)
        self._env_indices = np.arange(n_envs)

    def _grow(self) -> None:
        self.keys = np.concatenate([self.keys, np.zeros_like(self.keys)], axis=1)
        self.actions = np.concatenate([self.actions, np.zeros_like(self.actions)], axis=1)
        self.rewards = np.concatenate([self.rewards, np.zeros_like(self.rewards)], axis=1)

    def add(self, keys: np.ndarray, actions: np.ndarray, rewards: np.ndarray) -> None:
        """Append one step for every env (``keys`` ``(n_envs, key_dim)``, ``actions``, ``rewards`` ``(n_envs,)``)."""
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

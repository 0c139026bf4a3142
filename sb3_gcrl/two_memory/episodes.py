"""Per-env buffers of the running episode, for memories that learn once an episode is over (Eq. 5.2, Eq. 4.3).

Arrays are preallocated per env and doubled when an episode outgrows them, so recording a step is a single
vectorised write for all envs (no per-step Python lists).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def discounted_returns(rewards: np.ndarray, gamma: float) -> np.ndarray:
    """``G_t = sum_k gamma^(k-t) r_k`` for every step of one episode (the returns MFEC/CEC store).

    :param rewards: rewards of one episode, shape (T,).
    :param gamma: discount factor.
    :return: returns, shape (T,), float64.
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    if rewards.size == 0:
        return rewards
    # G_t = r_t + gamma * G_{t+1} is a first-order IIR filter run backwards in time.
    return lfilter([1.0], [1.0, -gamma], rewards[::-1])[::-1].copy()


class EpisodeRecorder:
    """Observations, actions and rewards of each env's running episode.

    :param n_envs: number of envs.
    :param obs_shape: shape of one observation.
    :param obs_dtype: observation dtype.
    :param action_shape: shape of one action (``()`` for Discrete).
    :param action_dtype: action dtype.
    :param capacity: initial steps per env (grows by doubling).
    """

    def __init__(
        self,
        n_envs: int,
        obs_shape: tuple[int, ...],
        obs_dtype: np.dtype,
        action_shape: tuple[int, ...],
        action_dtype: np.dtype,
        capacity: int = 256,
    ) -> None:
        self.n_envs = n_envs
        self.observations = np.zeros((n_envs, capacity, *obs_shape), dtype=obs_dtype)
        self.actions = np.zeros((n_envs, capacity, *action_shape), dtype=action_dtype)
        self.rewards = np.zeros((n_envs, capacity), dtype=np.float64)
        self.lengths = np.zeros(n_envs, dtype=np.int64)
        self._env_index = np.arange(n_envs)

    @property
    def capacity(self) -> int:
        return self.rewards.shape[1]

    def _grow(self) -> None:
        def double(array: np.ndarray) -> np.ndarray:
            bigger = np.zeros((array.shape[0], 2 * array.shape[1], *array.shape[2:]), dtype=array.dtype)
            bigger[:, : array.shape[1]] = array
            return bigger

        self.observations = double(self.observations)
        self.actions = double(self.actions)
        self.rewards = double(self.rewards)

    def add(self, observations: np.ndarray, actions: np.ndarray, rewards: np.ndarray) -> None:
        """Append one step for every env (batched: leading dimension ``n_envs``)."""
        if self.lengths.max() >= self.capacity:
            self._grow()
        self.observations[self._env_index, self.lengths] = observations
        self.actions[self._env_index, self.lengths] = actions
        self.rewards[self._env_index, self.lengths] = rewards
        self.lengths += 1

    def pop(self, env_index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (observations, actions, rewards) of env ``env_index``'s episode (copies) and clear it."""
        length = self.lengths[env_index]
        episode = (
            self.observations[env_index, :length].copy(),
            self.actions[env_index, :length].copy(),
            self.rewards[env_index, :length].copy(),
        )
        self.lengths[env_index] = 0
        return episode

    def clear(self) -> None:
        """Forget all running episodes (after an env reset)."""
        self.lengths[:] = 0

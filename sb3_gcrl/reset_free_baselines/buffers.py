"""Replay buffers of the forward and backward policies (one per policy, as in MEDAL's official code).

:class:`PhaseReplayBuffer` is SB3's ``DictReplayBuffer`` plus one flag per row: whether the row is a demonstration
(MEDAL puts the demonstrations into both buffers) or a transition the policy collected. The backward policy's reward
model trains on the collected rows only (:meth:`PhaseReplayBuffer.sample_visited_states`: MEDAL's discriminator
negatives, R3L's RND states). :class:`RelabeledRewards` gives SB3's ``SAC.train`` the backward buffer with the
rewards replaced, at sampling time, by the reward model's value of the next state (as MEDAL's code does).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.type_aliases import DictReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize


class PhaseReplayBuffer(DictReplayBuffer):
    """``DictReplayBuffer`` that marks demonstration rows (see the module docstring); same arguments."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.optimize_memory_usage:
            raise ValueError("PhaseReplayBuffer does not support optimize_memory_usage (rows of several envs mix)")
        #: True where the row holds a demonstration transition
        self.is_demo = np.zeros((self.buffer_size, self.n_envs), dtype=bool)

    def add(self, *args: Any, **kwargs: Any) -> None:
        """Add a collected transition (SB3's ``add`` arguments)."""
        self.is_demo[self.pos] = False
        super().add(*args, **kwargs)

    def add_demo(self, *args: Any, **kwargs: Any) -> None:
        """Add a demonstration transition (SB3's ``add`` arguments)."""
        super().add(*args, **kwargs)
        self.is_demo[(self.pos - 1) % self.buffer_size] = True

    def n_visited(self) -> int:
        """Number of collected (non-demonstration) rows."""
        upper = self.buffer_size if self.full else self.pos
        return int((~self.is_demo[:upper]).sum())

    def sample_visited_states(self, n: int, key: str, rng: np.random.Generator | None = None) -> np.ndarray | None:
        """Next states of ``n`` collected rows drawn uniformly (with replacement), or None when there is none.

        :param n: number of states.
        :param key: observation key of the state.
        :param rng: generator of the draws (the algorithm's); None: a generator of fresh entropy.
        :return: ``(n, state_dim)`` float32 array, or None.
        """
        rng = np.random.default_rng() if rng is None else rng
        upper = self.buffer_size if self.full else self.pos
        flags = self.is_demo[:upper]
        if flags.any():
            rows, envs = np.nonzero(~flags)
            if len(rows) == 0:
                return None
            pick = rng.integers(0, len(rows), size=n)
            rows, envs = rows[pick], envs[pick]
        else:
            if upper == 0:
                return None
            rows = rng.integers(0, upper, size=n)
            envs = rng.integers(0, self.n_envs, size=n)
        return self.next_observations[key][rows, envs].reshape(n, -1).astype(np.float32)


class RelabeledRewards:
    """A view of a :class:`PhaseReplayBuffer` whose samples carry ``reward_fn(next_observations)`` as rewards.

    Only ``sample`` (what ``SAC.train`` calls) is offered.

    :param buffer: the backward policy's buffer.
    :param reward_fn: maps the sampled next observations (dict of tensors) to rewards ``(batch, 1)``.
    """

    def __init__(self, buffer: PhaseReplayBuffer, reward_fn: Callable[[dict[str, th.Tensor]], th.Tensor]) -> None:
        self.buffer = buffer
        self.reward_fn = reward_fn

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> DictReplayBufferSamples:
        """The buffer's sample with the rewards replaced."""
        samples = self.buffer.sample(batch_size, env=env)
        return samples._replace(rewards=self.reward_fn(samples.next_observations).reshape(-1, 1))

    def size(self) -> int:
        return self.buffer.size()

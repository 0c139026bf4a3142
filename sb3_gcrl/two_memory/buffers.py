"""Replay buffer that remembers which memory collected each transition (thesis Sec. 5.4.3, data sharing)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_gcrl.common.seeding import draw_seed
from sb3_gcrl.two_memory.schedules import EPISODIC, PARAMETRIC


class SourceTaggedReplayBuffer(ReplayBuffer):
    """A :class:`~stable_baselines3.common.buffers.ReplayBuffer` that tags each transition with its source memory.

    With data sharing (the thesis default) every transition is sampled, whoever collected it. Without it
    (ablation 2Mw/oDS) ``sampled_sources=(PARAMETRIC,)`` and the RL memory trains only on its own episodes; the
    other transitions stay in the buffer (SB3 stores all envs of a step in one row) but are never sampled.
    The tags also give the fraction of EC data in the buffer, which the thesis discusses in Sec. 5.5.3.

    Before :meth:`add`, the algorithm sets :attr:`next_sources` (one tag per env).

    A filtering buffer samples with its own generator, seeded from the action space's generator (which SB3 seeds with
    the model's seed before it builds the buffer) and saved with the buffer; without filtering, :meth:`sample` is
    SB3's own.

    :param sampled_sources: sources that :meth:`sample` draws from.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: Any = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        sampled_sources: tuple[int, ...] = (EPISODIC, PARAMETRIC),
    ) -> None:
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
        )
        sampled_sources = tuple(int(s) for s in sampled_sources)
        if not sampled_sources or not set(sampled_sources) <= {EPISODIC, PARAMETRIC}:
            raise ValueError(f"sampled_sources must be a non-empty subset of (0: EC, 1: RL), got {sampled_sources}")
        if optimize_memory_usage and len(sampled_sources) < 2:
            raise ValueError("optimize_memory_usage=True cannot be combined with source filtering; set it to False")
        self.sampled_sources = sampled_sources
        self.sources = np.full((self.buffer_size, self.n_envs), PARAMETRIC, dtype=np.int8)
        #: source of the transitions passed to the next :meth:`add`, one per env
        self.next_sources = np.full(self.n_envs, PARAMETRIC, dtype=np.int8)
        #: generator of the filtered sampling (None without filtering)
        self.rng = np.random.default_rng(draw_seed(action_space)) if self.filters_sources else None

    @property
    def filters_sources(self) -> bool:
        return len(self.sampled_sources) < 2

    def add(self, *args: Any, **kwargs: Any) -> None:
        self.sources[self.pos] = self.next_sources
        super().add(*args, **kwargs)

    def _sampleable_mask(self) -> np.ndarray:
        upper = self.buffer_size if self.full else self.pos
        return np.isin(self.sources[:upper], self.sampled_sources)

    def n_sampleable(self) -> int:
        """Number of stored transitions that :meth:`sample` may return."""
        if not self.filters_sources:
            return self.size() * self.n_envs
        return int(self._sampleable_mask().sum())

    def source_fraction(self, source: int) -> float:
        """Fraction of stored transitions collected by ``source`` (0.0 when empty)."""
        upper = self.buffer_size if self.full else self.pos
        return float((self.sources[:upper] == source).mean()) if upper > 0 else 0.0

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        if not self.filters_sources:
            return super().sample(batch_size, env=env)
        flat = np.flatnonzero(self._sampleable_mask())
        if flat.size == 0:
            raise RuntimeError(
                f"No transition from sources {self.sampled_sources} in the replay buffer yet; "
                "check n_sampleable() > 0 before sampling"
            )
        assert self.rng is not None
        chosen = flat[self.rng.integers(0, flat.size, size=batch_size)]
        batch_inds, env_indices = np.divmod(chosen, self.n_envs)
        data = (
            self._normalize_obs(self.observations[batch_inds, env_indices, :], env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(self.next_observations[batch_inds, env_indices, :], env),
            (self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])).reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))

"""Sequence replay for the world model: one continuous stream of states per env, sampled as fixed-length chunks.

Reset-free training shows SB3 segments (truncated, never terminal) whose next ``reset()`` returns the *same*
state; the stream therefore continues across segment ends and restarts (``is_first``) only at physical resets
(``reset_infos[i]["physical_reset"]``, True when absent). Row ``t`` of an env's stream holds the state vector
``x_t`` (``observation`` then ``achieved_goal``), the action executed *before* it (scaled to [-1, 1]; zero at a
start) and ``is_first_t``. The env's reward is not stored: MoReFree never trains on it.
"""

from __future__ import annotations

import numpy as np


class SequenceReplayBuffer:
    """Preallocated per-env ring buffers of (state, previous action, is_first).

    :param capacity: rows in total (split evenly between envs).
    :param n_envs: number of envs.
    :param state_dim: size of the flat state vector.
    :param action_dim: action size.
    :param goal_dim: size of the ``achieved_goal`` part, the last entries of the state vector.
    """

    def __init__(self, capacity: int, n_envs: int, state_dim: int, action_dim: int, goal_dim: int) -> None:
        if capacity < n_envs * 2:
            raise ValueError(f"buffer_size must be >= 2 * n_envs, got {capacity} for {n_envs} envs")
        if not 0 < goal_dim <= state_dim:
            raise ValueError(f"goal_dim must be in [1, state_dim={state_dim}], got {goal_dim}")
        self.goal_dim = goal_dim
        self.rows = capacity // n_envs
        self.n_envs = n_envs
        self.states = np.zeros((n_envs, self.rows, state_dim), dtype=np.float32)
        self.actions = np.zeros((n_envs, self.rows, action_dim), dtype=np.float32)
        self.is_first = np.zeros((n_envs, self.rows), dtype=bool)
        #: index of the physical segment (between two physical resets) each row belongs to
        self.segment = np.zeros((n_envs, self.rows), dtype=np.int64)
        self._segments = np.zeros(n_envs, dtype=np.int64)
        self.pos = np.zeros(n_envs, dtype=np.int64)
        self.full = np.zeros(n_envs, dtype=bool)

    def stored(self) -> np.ndarray:
        """Rows stored per env ``(n_envs,)``: the ring's size once full, else its write position."""
        return np.where(self.full, self.rows, self.pos)

    def size(self) -> int:
        """Rows stored over all envs."""
        return int(self.stored().sum())

    def add(self, env: int, state: np.ndarray, prev_action: np.ndarray | None) -> None:
        """Append one row to env ``env``'s stream (``prev_action=None`` marks a start, ``is_first``)."""
        p = self.pos[env]
        self.states[env, p] = state
        if prev_action is None:
            self.actions[env, p] = 0.0
            self.is_first[env, p] = True
            self._segments[env] += 1
        else:
            self.actions[env, p] = prev_action
            self.is_first[env, p] = False
        self.segment[env, p] = self._segments[env]
        self.pos[env] = (p + 1) % self.rows
        if self.pos[env] == 0:
            self.full[env] = True

    def can_sample(self, length: int) -> bool:
        """Whether a chunk of ``length`` rows exists."""
        return bool((self.stored() >= length).any())

    def sample(self, batch: int, length: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``batch`` chunks of ``length`` consecutive rows, uniform over valid starts; time-major arrays.

        The first row of every chunk is marked ``is_first`` (the world model starts each chunk from the zero state).

        :return: states ``(L, B, state_dim)``, previous actions ``(L, B, action_dim)``, is_first ``(L, B)``.
        """
        stored = self.stored()
        valid = np.flatnonzero(stored >= length)
        if not valid.size:
            raise RuntimeError(f"no chunk of {length} steps stored yet")
        # starts per env: a full ring may not cross its write position
        counts = stored[valid] - length + 1
        envs = rng.choice(valid, size=batch, p=counts / counts.sum())
        starts = np.empty(batch, dtype=np.int64)
        for k, env in enumerate(envs):
            offset = rng.integers(0, stored[env] - length + 1)
            # in a full ring the oldest row sits at the write position
            starts[k] = (self.pos[env] + offset) % self.rows if self.full[env] else offset
        index = (starts[:, None] + np.arange(length)[None, :]) % self.rows
        states = self.states[envs[:, None], index]
        actions = self.actions[envs[:, None], index]
        is_first = self.is_first[envs[:, None], index].copy()
        is_first[:, 0] = True
        return states.swapaxes(0, 1), actions.swapaxes(0, 1), is_first.swapaxes(0, 1)

    def achieved_goals(self) -> np.ndarray:
        """Every stored ``achieved_goal`` in storage order (env by env, oldest first): what training visited.

        :return: array ``(size(), goal_dim)``.
        """
        streams = []
        for env in range(self.n_envs):
            order = (self.pos[env] + np.arange(self.rows)) % self.rows if self.full[env] else np.arange(self.pos[env])
            streams.append(self.states[env, order, -self.goal_dim :])
        return np.concatenate(streams)

    def sample_pairs(
        self, n: int, max_gap: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``n`` pairs of stored achieved goals of one stream, ``gap ~ U{0..max_gap}`` steps apart.

        :return: earlier goals ``(n, goal_dim)``, later goals ``(n, goal_dim)``, gaps ``(n,)`` and a validity mask
            ``(n,)``: False where the stream is shorter than the gap or a physical reset lies between the two.
        """
        sizes = self.stored()
        if sizes.sum() == 0:
            raise RuntimeError("the replay buffer is empty")
        envs = rng.choice(self.n_envs, size=n, p=sizes / sizes.sum())
        gaps = rng.integers(0, max_gap + 1, size=n)
        available = sizes[envs] - gaps
        offsets = (rng.random(n) * np.maximum(available, 1)).astype(np.int64)
        # in a full ring the oldest row sits at the write position
        starts = np.where(self.full[envs], (self.pos[envs] + offsets) % self.rows, offsets)
        ends = (starts + gaps) % self.rows
        valid = (available > 0) & (self.segment[envs, starts] == self.segment[envs, ends])
        goal = slice(-self.goal_dim, None)
        return self.states[envs, starts, goal], self.states[envs, ends, goal], gaps, valid

    def sample_states(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` stored state vectors, uniform over the whole buffer (the replay-state goals of Sec. 3.4.2)."""
        sizes = self.stored()
        if sizes.sum() == 0:
            raise RuntimeError("the replay buffer is empty")
        flat = rng.integers(0, sizes.sum(), size=n)
        envs = np.searchsorted(np.cumsum(sizes), flat, side="right")
        rows = flat - np.concatenate([[0], np.cumsum(sizes)[:-1]])[envs]
        return self.states[envs, rows].copy()

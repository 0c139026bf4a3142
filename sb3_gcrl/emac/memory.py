"""EMAC's episodic memory: random-projection keys of (state, action) pairs with their Monte-Carlo returns.

Kuznetsov & Filchenkov (IJCAI 2021), "Memory Module": every step of a finished episode is written as one row, the
key a fixed Gaussian random projection of the concatenated (flattened observation, action), the value the step's
discounted Monte-Carlo return. The estimate ``Q_M(s, a)`` of a query is the weighted average of the values of its
``k`` nearest keys (Euclidean). Rows are never merged or updated; when the memory is full the oldest row is
overwritten (first in, first out; the authors size the memory to the whole training budget, so they never evict).

The key table and its exact kNN search are the package's :class:`~sb3_gcrl.memory.KNNIndex`, the projection is
:class:`~sb3_gcrl.memory.KeyEmbedding` (thesis Sec. 4.4, the same random projection as CEC/MFEC), and the eviction
order is :class:`~sb3_gcrl.memory.RecencyOrder` (rows are touched once, when written, so least recently updated is
oldest).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from gymnasium import spaces

from sb3_gcrl.common.validation import check_choice, check_finite_returns
from sb3_gcrl.memory.embedding import KeyEmbedding
from sb3_gcrl.memory.knn import KNNBackend
from sb3_gcrl.memory.value_table import KNNValueTable

NeighbourWeighting = Literal["softmin", "uniform"]
NEIGHBOUR_WEIGHTINGS: tuple[str, ...] = ("softmin", "uniform")


class StateActionEmbedding:
    """(observation, action) -> memory key: the flattened observation (Dict observations: ``observation_keys``
    concatenated, see :class:`~sb3_gcrl.memory.KeyEmbedding`) concatenated with the flattened action, multiplied by a
    fixed ``(input_dim, projection_dim)`` matrix with N(0, 1) entries drawn from ``numpy.random.default_rng(seed)``.

    :param observation_space: observation space (Box, Discrete, MultiBinary or a Dict of those).
    :param action_space: Box action space.
    :param projection_dim: key dimension after projection (authors: 4); ``None``: no projection.
    :param seed: seed of the projection matrix.
    :param observation_keys: Dict observation keys in the key, in order (default: observation + desired_goal).
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Box,
        projection_dim: int | None = 4,
        seed: int | None = None,
        observation_keys: Sequence[str] | None = None,
    ) -> None:
        self.observations = KeyEmbedding(observation_space, projection_dim=None, observation_keys=observation_keys)
        self.action_dim = int(np.prod(action_space.shape))
        joint = spaces.Box(-np.inf, np.inf, (self.observations.input_dim + self.action_dim,), np.float32)
        self.joint = KeyEmbedding(joint, projection_dim=projection_dim, seed=seed)

    @property
    def key_dim(self) -> int:
        """Dimension of the keys."""
        return self.joint.key_dim

    def __call__(self, observations: np.ndarray | dict[str, np.ndarray], actions: np.ndarray) -> np.ndarray:
        """Keys ``(n, key_dim)`` float32 of a batch of observations and the actions taken in them.

        :raises ValueError: if the batch sizes differ, or an observation or action is NaN or inf.
        """
        features = self.observations.features(observations)
        actions = np.asarray(actions, dtype=np.float32).reshape(len(actions), -1)
        if len(actions) != len(features):
            raise ValueError(f"{len(features)} observations but {len(actions)} actions")
        return self.joint(np.concatenate([features, actions], axis=1))

    def get_state(self) -> dict[str, np.ndarray]:
        """The projection matrix (see :meth:`KeyEmbedding.get_state`)."""
        return self.joint.get_state()

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore what :meth:`get_state` returned."""
        self.joint.set_state(state)


class EMACMemory(KNNValueTable):
    """Rows (key, Monte-Carlo return), first in first out, with a kNN estimate ``Q_M``.

    :param key_dim: key dimension.
    :param capacity: maximum number of rows (the oldest is overwritten when full).
    :param n_neighbors: ``k`` of the estimate (authors: 2).
    :param neighbour_weighting: ``"softmin"``: the ``k`` values weighted by ``softmax(-distance)`` (authors' code);
        ``"uniform"``: their plain mean.
    :param knn_backend: see :class:`~sb3_gcrl.memory.KNNIndex`.
    :param rebuild_threshold: see :class:`~sb3_gcrl.memory.KNNIndex`.
    """

    capacity_name = "memory_capacity"

    def __init__(
        self,
        key_dim: int,
        capacity: int,
        n_neighbors: int = 2,
        neighbour_weighting: NeighbourWeighting = "softmin",
        knn_backend: KNNBackend = "auto",
        rebuild_threshold: int | None = None,
    ) -> None:
        super().__init__(key_dim, capacity, n_neighbors, knn_backend, rebuild_threshold)
        self.neighbour_weighting: NeighbourWeighting = check_choice(
            "neighbour_weighting", neighbour_weighting, NEIGHBOUR_WEIGHTINGS
        )

    def add_episode(self, keys: np.ndarray, returns: np.ndarray) -> int:
        """Write every step of a finished episode, in time order (one row each).

        :param keys: ``(T, key_dim)`` keys of the episode's (state, action) pairs.
        :param returns: ``(T,)`` their discounted Monte-Carlo returns.
        :return: number of rows that overwrote an older row.
        :raises ValueError: if the lengths differ or a return is NaN or infinite (nothing is written then).
        """
        keys = np.ascontiguousarray(keys, dtype=np.float32).reshape(len(keys), self.key_dim)
        returns = np.asarray(returns, dtype=np.float64).reshape(-1)
        if len(keys) != len(returns):
            raise ValueError(f"keys and returns lengths differ: {len(keys)}, {len(returns)}")
        check_finite_returns(returns)
        evicted = 0
        for key, value in zip(keys, returns):
            evicted += self.write(key, value)[1] >= 0
        return evicted

    def estimate(self, keys: np.ndarray) -> np.ndarray:
        """``Q_M`` of a batch of keys: the weighted mean value of the ``k`` nearest rows (fewer while the memory
        holds fewer than ``k`` rows).

        :param keys: ``(n, key_dim)`` float32 keys.
        :return: ``(n,)`` float64 estimates.
        :raises RuntimeError: if the memory is empty.
        """
        if len(self) == 0:
            raise RuntimeError("EMACMemory is empty: write an episode (add_episode) before estimating")
        distances, rows = self.index.search(np.ascontiguousarray(keys, dtype=np.float32), self.n_neighbors)
        valid = rows >= 0  # only missing when the memory holds fewer than k rows
        if self.neighbour_weighting == "softmin":
            logits = np.where(valid, -distances, -np.inf)
            logits = logits - logits[:, :1]  # the nearest row is always valid: a stable softmax
            weights = np.exp(logits)
        else:
            weights = valid.astype(np.float64)
        weights /= weights.sum(axis=1, keepdims=True)
        return (self.values[np.where(valid, rows, 0)] * weights).sum(axis=1)

"""Policy of MFEC: per-action episodic value tables, greedy with epsilon-random exploration."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_gcrl.common.saving import refuse_learning_rate_schedule
from sb3_gcrl.episodic_control.policies import EpisodicControlPolicy
from sb3_gcrl.memory.actors import mfec_actions
from sb3_gcrl.memory.mfec_memory import MFECMemory


class MFECPolicy(EpisodicControlPolicy):
    """Model-free episodic control policy (thesis Section 5.2.3).

    Greedy action: ``argmax_a Q_ec(s, a)`` with the MFEC estimate (exact match, else mean of the
    ``k`` nearest rows, ``+inf`` for actions whose table holds ``<= k`` rows); ties are broken
    uniformly at random when stochastic and by lowest index when deterministic. Stochastic action:
    a uniform random action with probability ``exploration_rate`` (epsilon-greedy).

    :param observation_space: observation space.
    :param action_space: ``Discrete`` action space.
    :param capacity_per_action: rows per action table.
    :param n_neighbors: ``k`` of the kNN estimate.

    The defaults of the memory settings are those of :class:`~sb3_gcrl.mfec.MFEC`, which reads them here.

    :param kwargs: the :class:`~sb3_gcrl.episodic_control.EpisodicControlPolicy` arguments (``projection_dim``,
        ``observation_keys``, ``seed``, ``knn_backend``, ``rebuild_threshold``).
    :raises TypeError: naming ``MFEC.load`` when SB3's own ``load`` (``SAC.load``) builds this policy from a MFEC
        model file (it passes a learning-rate schedule third).
    """

    action_space: spaces.Discrete

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        capacity_per_action: int = 100_000,
        n_neighbors: int = 3,
        **kwargs: Any,
    ) -> None:
        refuse_learning_rate_schedule(type(self).__name__, "capacity_per_action", capacity_per_action, "MFEC")
        super().__init__(observation_space, action_space, **kwargs)
        self.memory = MFECMemory(
            key_dim=self.embedding.key_dim,
            n_actions=int(action_space.n),
            capacity_per_action=capacity_per_action,
            n_neighbors=n_neighbors,
            knn_backend=self.knn_backend,
            rebuild_threshold=self.rebuild_threshold,
        )
        #: ``action_space.start``: env actions are ``start + a`` for the table index ``a``
        self.action_start = int(action_space.start)

    def memory_settings(self) -> dict[str, Any]:
        """The memory settings as the memory checked them, by constructor argument name."""
        return {"capacity_per_action": self.memory.capacity_per_action, "n_neighbors": self.memory.n_neighbors}

    def q_values(self, keys: np.ndarray) -> np.ndarray:
        """``Q_ec(s, .)`` for a batch of keys: ``(n, n_actions)``."""
        return self.memory.estimate(keys)

    def act(self, keys: np.ndarray, deterministic: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Actions ``(n,)`` and the mask of queries whose chosen action had a finite estimate
        (:func:`~sb3_gcrl.memory.actors.mfec_actions`)."""
        actions, known = mfec_actions(self.memory, keys, self.rng, deterministic, self.exploration_rate)
        return actions + self.action_start, known


MlpPolicy = MFECPolicy
MultiInputPolicy = MFECPolicy

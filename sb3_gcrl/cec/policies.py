"""Policy of CEC: the CEC memory plus exploration (thesis Algorithm 1, SELECT ACTION)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_gcrl.common.saving import refuse_learning_rate_schedule
from sb3_gcrl.common.validation import check_float
from sb3_gcrl.episodic_control.policies import EpisodicControlPolicy
from sb3_gcrl.memory.actors import cec_actions
from sb3_gcrl.memory.cec_memory import CECMemory


class CECPolicy(EpisodicControlPolicy):
    """Continuous episodic control policy (thesis Section 4.4).

    Stochastic action (training): sample a stored action of the ``k`` nearest rows within ``n * d``
    by ``softmax(v / tau)`` (Eq. 4.5); with probability ``exploration_rate`` (epsilon) add
    ``N(0, noise_std^2)`` noise; if no row is within ``n * d``, a uniform random action. Actions
    are clipped to the action space.
    Deterministic action (evaluation): the action of the single nearest row, no threshold; while the
    memory is empty, the centre of the action space.

    :param observation_space: observation space.
    :param action_space: bounded ``Box`` action space.
    :param capacity: memory rows.
    :param distance_threshold: ``d`` (Table 4.4).
    :param filter_factor: ``n`` (Table 4.4).
    :param n_neighbors: ``k`` (Table 4.4).
    :param temperature: ``tau`` (Table 4.4, Eq. 4.5).
    :param noise_std: ``sigma`` (Table 4.4), in action units.

    The defaults of the memory settings are those of :class:`~sb3_gcrl.cec.CEC` (the PointUMaze row of Table 4.4),
    which reads them here.

    :param kwargs: the :class:`~sb3_gcrl.episodic_control.EpisodicControlPolicy` arguments (``projection_dim``,
        ``observation_keys``, ``seed``, ``knn_backend``, ``rebuild_threshold``).
    :raises TypeError: naming ``CEC.load`` when SB3's own ``load`` (``SAC.load``) builds this policy from a CEC
        model file (it passes a learning-rate schedule third).
    """

    action_space: spaces.Box

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Box,
        capacity: int = 1_000_000,
        distance_threshold: float = 0.1,
        filter_factor: float = 1.0,
        n_neighbors: int = 5,
        temperature: float = 0.1,
        noise_std: float = 0.3,
        **kwargs: Any,
    ) -> None:
        refuse_learning_rate_schedule(type(self).__name__, "capacity", capacity, "CEC")
        super().__init__(observation_space, action_space, **kwargs)
        self.noise_std = check_float("noise_std (sigma)", noise_std, 0.0)
        self.memory = CECMemory(
            key_dim=self.embedding.key_dim,
            action_dim=int(np.prod(action_space.shape)),
            capacity=capacity,
            distance_threshold=distance_threshold,
            filter_factor=filter_factor,
            n_neighbors=n_neighbors,
            temperature=temperature,
            knn_backend=self.knn_backend,
            rebuild_threshold=self.rebuild_threshold,
        )
        self._low = action_space.low.astype(np.float32).reshape(-1)
        self._high = action_space.high.astype(np.float32).reshape(-1)

    def memory_settings(self) -> dict[str, Any]:
        """The memory settings as the memory and the policy checked them, by constructor argument name."""
        return {
            "capacity": self.memory.capacity,
            "distance_threshold": self.memory.distance_threshold,
            "filter_factor": self.memory.filter_factor,
            "n_neighbors": self.memory.n_neighbors,
            "temperature": self.memory.temperature,
            "noise_std": self.noise_std,
        }

    def act(self, keys: np.ndarray, deterministic: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Actions ``(n, *action_shape)`` for keys ``(n, key_dim)`` and the mask of memory hits
        (:func:`~sb3_gcrl.memory.actors.cec_actions`)."""
        actions, found = cec_actions(
            self.memory, keys, self._low, self._high, self.rng, deterministic, self.exploration_rate, self.noise_std
        )
        return actions.reshape(len(keys), *self.action_space.shape), found


MlpPolicy = CECPolicy
MultiInputPolicy = CECPolicy

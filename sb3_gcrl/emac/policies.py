"""EMAC policies: SB3's TD3 actor-critic plus the episodic memory of (state, action) returns.

The memory and its random projection live in the policy and go into its ``state_dict`` through ``get_extra_state``
(used rows only, as CEC and the 2M policies do), so ``model.save``/``load``, ``policy.save``/``load`` and
``set_parameters`` bring the networks and the memory back together. The memory is not used to act: the actor is.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import CombinedExtractor
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.td3.policies import TD3Policy

from sb3_gcrl.common.validation import check_int, check_optional_int
from sb3_gcrl.emac.memory import EMACMemory, NeighbourWeighting, StateActionEmbedding
from sb3_gcrl.memory.knn import KNNBackend
from sb3_gcrl.memory.serialization import load_memory_state, memory_state


class EMACPolicy(TD3Policy):
    """TD3/DDPG actor-critic with EMAC's memory module (Kuznetsov & Filchenkov, 2021).

    :param observation_space: observation space (Box, or Dict for goal envs).
    :param action_space: Box action space.
    :param lr_schedule: learning rate schedule of actor and critic.
    :param memory_capacity: memory rows (authors: the whole training budget).
    :param n_neighbors: ``k`` of the memory estimate (authors: 2).
    :param projection_dim: dimension of the random projection of (state, action) (authors: 4; ``None``: none).
    :param neighbour_weighting: ``"softmin"`` (authors' code) or ``"uniform"`` weights of the ``k`` values.
    :param observation_keys: Dict observation keys in the memory key, in order.
    :param memory_seed: seed of the projection matrix (:class:`~sb3_gcrl.EMAC` passes its ``seed``; ``None``: fresh
        entropy).
    :param knn_backend: kNN backend of the memory (see :class:`~sb3_gcrl.memory.KNNIndex`).
    :param kwargs: :class:`~stable_baselines3.td3.policies.TD3Policy` arguments (``net_arch``, ``n_critics``...).
    """

    memory_parameters = (
        "memory_capacity",
        "n_neighbors",
        "projection_dim",
        "neighbour_weighting",
        "observation_keys",
        "memory_seed",
        "knn_backend",
    )

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        memory_capacity: int = 1_000_000,
        n_neighbors: int = 2,
        projection_dim: int | None = 4,
        neighbour_weighting: NeighbourWeighting = "softmin",
        observation_keys: Sequence[str] | None = None,
        memory_seed: int | None = None,
        knn_backend: KNNBackend = "auto",
        **kwargs: Any,
    ) -> None:
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)
        if memory_seed is None:
            memory_seed = int(np.random.default_rng().integers(2**31 - 1))
        self.memory_capacity = check_int("memory_capacity", memory_capacity)
        self.n_neighbors = check_int("n_neighbors (k)", n_neighbors)
        self.projection_dim = check_optional_int("projection_dim", projection_dim)
        self.neighbour_weighting = neighbour_weighting
        self.observation_keys = None if observation_keys is None else tuple(observation_keys)
        self.memory_seed = int(memory_seed)
        self.knn_backend = knn_backend
        self.memory_embedding = StateActionEmbedding(
            observation_space,
            action_space,
            projection_dim=self.projection_dim,
            seed=self.memory_seed,
            observation_keys=self.observation_keys,
        )
        self.memory = EMACMemory(
            self.memory_embedding.key_dim,
            capacity=self.memory_capacity,
            n_neighbors=self.n_neighbors,
            neighbour_weighting=neighbour_weighting,
            knn_backend=knn_backend,
        )

    def memory_keys(self, observations: np.ndarray | dict[str, np.ndarray], actions: np.ndarray) -> np.ndarray:
        """Memory keys of observations (as the replay buffer holds them) and actions scaled to [-1, 1] (as the
        critic sees them).

        :param observations: batch of observations (a dict of batches for Dict spaces).
        :param actions: ``(n, *action_shape)`` actions in [-1, 1].
        :return: ``(n, key_dim)`` float32 keys.
        """
        return self.memory_embedding(observations, actions)

    def memory_estimate(self, observations: th.Tensor | dict[str, th.Tensor], actions: th.Tensor) -> th.Tensor | None:
        """``Q_M(s, a)`` of a replay batch as a ``(n, 1)`` tensor on the actions' device; ``None`` while the memory
        is empty.

        :param observations: replay observations (tensor, or dict of tensors).
        :param actions: replay actions (scaled to [-1, 1]).
        """
        if len(self.memory) == 0:
            return None
        if isinstance(observations, dict):
            obs: np.ndarray | dict[str, np.ndarray] = {k: v.cpu().numpy() for k, v in observations.items()}
        else:
            obs = observations.cpu().numpy()
        values = self.memory.estimate(self.memory_keys(obs, actions.cpu().numpy()))
        return th.as_tensor(values, dtype=actions.dtype, device=actions.device).reshape(-1, 1)

    def get_extra_state(self) -> dict[str, th.Tensor]:
        """Memory rows and projection matrix, as tensors, for ``state_dict``/``policy.pth``."""
        return memory_state(self.memory, self.memory_embedding)

    def set_extra_state(self, state: dict[str, th.Tensor]) -> None:
        """Restore what :meth:`get_extra_state` returned.

        :raises MemoryRestoreError: if the saved memory cannot be restored (see
            :func:`~sb3_gcrl.memory.serialization.load_memory_state`).
        """
        load_memory_state(self, self.memory, self.memory_embedding, state)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update({name: getattr(self, name) for name in self.memory_parameters})
        return data


class MultiInputEMACPolicy(EMACPolicy):
    """:class:`EMACPolicy` for Dict observations (goal envs): SB3's ``CombinedExtractor`` for the networks; the
    memory key concatenates ``observation``, ``desired_goal`` (see :class:`~sb3_gcrl.memory.KeyEmbedding`) and the
    action."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", CombinedExtractor)
        super().__init__(*args, **kwargs)


MlpPolicy = EMACPolicy
MultiInputPolicy = MultiInputEMACPolicy

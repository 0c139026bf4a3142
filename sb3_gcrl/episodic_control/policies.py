"""Base policy of the episodic-control algorithms (CEC, MFEC): the memory *is* the policy.

An episodic-control agent has no network and no gradient step. So the policy is a
:class:`~stable_baselines3.common.policies.BasePolicy` without parameters that holds the memory and a
:class:`~sb3_gcrl.memory.embedding.KeyEmbedding`, works on numpy end to end while training (no tensor round trip
per step; SB3's own ``predict`` reaches the memory through ``_predict``), and puts the memory into its
``state_dict`` through ``get_extra_state`` (:func:`~sb3_gcrl.memory.serialization.memory_state`: used rows only, as
tensors), so ``save``/``load`` restore it exactly inside the usual ``policy.pth`` of the SB3 zip.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.common.seeding import generator_state, restore_generator
from sb3_gcrl.common.validation import check_optional_int
from sb3_gcrl.memory.embedding import KeyEmbedding
from sb3_gcrl.memory.knn import KNNBackend
from sb3_gcrl.memory.serialization import load_memory_state, memory_state


class EpisodicControlPolicy(BasePolicy):
    """Base policy holding an episodic memory and the observation -> key embedding.

    Subclasses create ``self.memory`` (with ``state_dict``/``load_state_dict``/``__len__``), implement :meth:`act`
    and return their memory settings by constructor argument name from :meth:`memory_settings` (saved by
    ``policy.save``; :class:`~sb3_gcrl.episodic_control.EpisodicControlAlgorithm` keeps them as it checked them).

    :param observation_space: observation space (Box, Discrete, MultiBinary or Dict of those).
    :param action_space: action space.
    :param projection_dim: random-projection dimension of the keys, ``None`` for raw observations.
    :param observation_keys: Dict observation keys used for the key, in order (default
        ``("observation", "desired_goal")`` for goal envs).
    :param seed: seed of the projection matrix and of the policy's action-sampling generator.
    :param knn_backend: kNN backend of the memory (see :class:`~sb3_gcrl.memory.knn.KNNIndex`).
    :param rebuild_threshold: KD-tree rebuild threshold of the memory (``None``: automatic).
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        projection_dim: int | None = None,
        observation_keys: Sequence[str] | None = None,
        seed: int | None = None,
        knn_backend: KNNBackend = "auto",
        rebuild_threshold: int | None = None,
    ) -> None:
        super().__init__(observation_space, action_space)
        self.projection_dim = projection_dim
        self.observation_keys = None if observation_keys is None else tuple(observation_keys)
        self.seed = seed
        self.knn_backend = knn_backend
        self.rebuild_threshold = check_optional_int("rebuild_threshold", rebuild_threshold)
        self.embedding = KeyEmbedding(
            observation_space, projection_dim=projection_dim, seed=seed, observation_keys=self.observation_keys
        )
        self.rng = np.random.default_rng(seed)
        #: probability of exploring (epsilon), set by the algorithm's schedule during training
        self.exploration_rate = 0.0

    @abstractmethod
    def memory_settings(self) -> dict[str, Any]:
        """The memory settings as the policy uses them (checked and converted), by constructor argument name."""

    def set_seed(self, seed: int | None) -> None:
        """Reseed the action-sampling generator (the projection matrix stays as it is)."""
        self.rng = np.random.default_rng(seed)

    @abstractmethod
    def act(self, keys: np.ndarray, deterministic: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Actions for a batch of keys; returns ``(actions, hits)`` where ``hits`` marks the queries
        the memory could answer (logged as ``memory/hit_rate``)."""

    def _predict(self, observation: th.Tensor | dict[str, th.Tensor], deterministic: bool = False) -> th.Tensor:
        """The memory's actions for a batch of observations, in the action space's dtype, for SB3's ``predict``.

        SB3's :meth:`predict` prepares the observation as for any SB3 policy (channel-last images are transposed
        channel-first, as ``VecTransposeImage`` did during training, so the memory sees the keys it was trained on; a
        single observation gets a batch dimension) and gives the actions SB3's shapes (an array of shape ``()`` for
        one ``Discrete`` observation, as SB3's DQN returns).

        :param observation: the batch, as tensors.
        :param deterministic: greedy actions if True, else the training-time (exploring) actions.
        :return: the actions (the memory computes in float32; they are returned in the action space's dtype).
        """
        if isinstance(observation, dict):
            obs: np.ndarray | dict[str, np.ndarray] = {k: v.cpu().numpy() for k, v in observation.items()}
        else:
            obs = observation.cpu().numpy()
        actions, _ = self.act(self.embedding(obs), deterministic=deterministic)
        return th.as_tensor(np.asarray(actions, dtype=self.action_space.dtype))

    def forward(self, obs: th.Tensor, deterministic: bool = False) -> th.Tensor:
        return self._predict(obs, deterministic)

    def get_extra_state(self) -> dict[str, th.Tensor]:
        """Memory rows, projection matrix and the action-sampling generator's state, as tensors, for
        ``state_dict``/``policy.pth``."""
        return {**memory_state(self.memory, self.embedding), "rng": generator_state(self.rng)}

    def set_extra_state(self, state: dict[str, th.Tensor]) -> None:
        """Restore what :meth:`get_extra_state` returned (see :func:`load_memory_state`); the action-sampling
        generator continues where the saved one stopped."""
        load_memory_state(self, self.memory, self.embedding, state)
        self.rng = restore_generator(state["rng"])

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        del data["normalize_images"]  # no network, nothing to normalize: keys are built from the raw observation
        data.update(
            projection_dim=self.projection_dim,
            observation_keys=self.observation_keys,
            seed=self.seed,
            knn_backend=self.knn_backend,
            rebuild_threshold=self.rebuild_threshold,
            **self.memory_settings(),
        )
        return data

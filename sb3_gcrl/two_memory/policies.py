"""2M hybrid policies: an episodic memory (MFEC or CEC) and an SB3 network (DQN or SAC) behind one dispatch.

The dispatch (which memory acts per episode and env, score windows, evaluation memory of Eq. 5.6) comes from
:class:`~sb3_gcrl.two_memory.policy_mixin.TwoMemoryDispatchMixin`; the memories come from :mod:`sb3_gcrl.memory` and act
as in standalone CEC / MFEC (:mod:`sb3_gcrl.memory.actors`).
Everything is in the policy's ``state_dict`` (the episodic table through ``get_extra_state``, used rows only), so
``save``/``load`` restore the table, the network and the score windows exactly.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, CombinedExtractor
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.dqn.policies import DQNPolicy
from stable_baselines3.sac.policies import SACPolicy
from torch import nn

from sb3_gcrl.common.seeding import draw_seed, generator_state, restore_generator, seeded_generator
from sb3_gcrl.common.validation import check_float
from sb3_gcrl.memory import CECMemory, KeyEmbedding, MFECMemory
from sb3_gcrl.memory.actors import cec_actions, mfec_actions
from sb3_gcrl.memory.serialization import load_memory_state, memory_state
from sb3_gcrl.two_memory.dispatch import TwoMemoryDispatcher
from sb3_gcrl.two_memory.policy_mixin import TwoMemoryDispatchMixin


class MinAtarCNN(BaseFeaturesExtractor):
    """The authors' MinAtar torso: Conv(C->16, 3x3) -> ReLU -> Conv(16->32, 3x3) -> ReLU -> flatten (32*6*6 = 1152).

    With ``net_arch=[]`` the DQN head is the single Linear(1152 -> n_actions) of the authors' network (public repo
    yangzhao-666/2m). Observations are channel-last ``(10, 10, C)`` booleans, as MinAtar's gymnasium envs return them.

    :param observation_space: ``Box((H, W, C))``.
    """

    def __init__(self, observation_space: spaces.Box) -> None:
        if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 3:
            raise ValueError(
                f"MinAtarCNN needs a channel-last Box((H, W, C)) observation space, got {observation_space}"
            )
        height, width, channels = observation_space.shape
        if height < 5 or width < 5:
            raise ValueError(f"MinAtarCNN needs images of at least 5x5, got {observation_space.shape}")
        n_flatten = 32 * (height - 4) * (width - 4)
        super().__init__(observation_space, features_dim=n_flatten)
        self.cnn = nn.Sequential(
            nn.Conv2d(channels, 16, kernel_size=3),
            nn.ReLU(),
            nn.Conv2d(16, 32, kernel_size=3),
            nn.ReLU(),
            nn.Flatten(),
        )

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.cnn(observations.permute(0, 3, 1, 2))


class MinAtarDQNPolicy(DQNPolicy):
    """Plain :class:`~stable_baselines3.dqn.policies.DQNPolicy` with the authors' MinAtar network as default
    (``rl_zoo3 train --algo dqn`` with ``policy: sb3_gcrl.two_memory.policies.MinAtarDQNPolicy``: rl_zoo3 cannot
    take a features extractor class in ``policy_kwargs``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", MinAtarCNN)
        kwargs.setdefault("net_arch", [])
        super().__init__(*args, **kwargs)


class KeyedMemoryDispatchMixin(TwoMemoryDispatchMixin):
    """2M dispatch whose episodic half is a kNN memory (MFEC or CEC) keyed by a :class:`~sb3_gcrl.memory.KeyEmbedding`:
    the memory (``self.memory``), its embedding, its generator (``self.rng``) and their save/restore (the generator's
    state too, so a loaded policy continues its draws), shared by the DQN and SAC flavours."""

    memory: Any
    embedding: KeyEmbedding

    def _init_keyed_memory(self, ec_projection_dim: int | None, ec_seed: int | None, knn_backend: str) -> int:
        """Build the embedding and the generator; keep the settings as attributes.

        :param ec_projection_dim: random-projection dimension of the keys (None: no projection).
        :param ec_seed: seed of the projection and of the EC generator (None: drawn from the action space's
            generator, which SB3 seeds with the model's seed before it builds the policy).
        :param knn_backend: kNN backend of the memory.
        :return: the seed used.
        """
        if ec_seed is None:
            ec_seed = draw_seed(self.action_space)  # type: ignore[attr-defined]
        self.ec_projection_dim = ec_projection_dim
        self.ec_seed = ec_seed
        self.knn_backend = knn_backend
        self.embedding = KeyEmbedding(self.observation_space, projection_dim=ec_projection_dim, seed=ec_seed)  # type: ignore[attr-defined]
        self.rng = np.random.default_rng(ec_seed)
        return ec_seed

    def set_seed(self, seed: int | None) -> None:
        """Reseed the EC generator (tie-breaking, Eq. 4.5 sampling, exploration); the projection matrix stays.

        :param seed: seed.
        """
        self.rng = seeded_generator(seed, "episodic memory")

    def _keys(self, observation: th.Tensor | dict[str, th.Tensor]) -> np.ndarray:
        if isinstance(observation, dict):
            return self.embedding({k: v.cpu().numpy() for k, v in observation.items()})
        return self.embedding(observation.cpu().numpy())

    def _episode_features(self, observations: Any) -> np.ndarray:
        return self.embedding(observations)

    def _episodic_state(self) -> dict[str, th.Tensor]:
        return {**memory_state(self.memory, self.embedding), "ec_rng": generator_state(self.rng)}

    def _load_episodic_state(self, state: dict[str, th.Tensor]) -> None:
        state = dict(state)
        saved_rng = state.pop("ec_rng")
        load_memory_state(self, self.memory, self.embedding, state)
        self.rng = restore_generator(saved_rng)


class TwoMemoryDQNPolicy(KeyedMemoryDispatchMixin, DQNPolicy):
    """2M policy for discrete actions: an MFEC table (2M-EC) and a DQN Q-network (2M-RL), thesis Ch. 5.

    MFEC keys are a seeded Gaussian random projection of the flattened observation (8 dims in the authors' code).
    MFEC acts greedily (:func:`~sb3_gcrl.memory.actors.mfec_actions`, untried actions first, ties broken at random
    while training); epsilon-greedy exploration is drawn per env by the algorithm, on both memories.

    :param observation_space: observation space.
    :param action_space: Discrete action space.
    :param lr_schedule: learning rate schedule of the Q-network.
    :param score_window: n of Eq. 5.6.
    :param ec_projection_dim: random-projection dimension of the MFEC keys (None: no projection).
    :param ec_capacity_per_action: rows per action table (None: authors' ``1e5 / (2 * n_actions)``).
    :param ec_n_neighbors: k of the MFEC estimate (Table 5.1: 3).
    :param ec_seed: seed of the projection matrix and of the MFEC generator (None: drawn from the action space's
        generator, which SB3 seeds with the model's seed before it builds the policy).
    :param knn_backend: kNN backend of the MFEC tables (see :class:`~sb3_gcrl.memory.KNNIndex`).
    :param kwargs: :class:`~stable_baselines3.dqn.policies.DQNPolicy` arguments (net_arch, features extractor...).
    """

    ec_parameters = (  # noqa: RUF012
        *TwoMemoryDispatchMixin.ec_parameters,
        "ec_projection_dim",
        "ec_capacity_per_action",
        "ec_n_neighbors",
        "ec_seed",
        "knn_backend",
    )
    memory: MFECMemory

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        score_window: int = 50,
        ec_projection_dim: int | None = 8,
        ec_capacity_per_action: int | None = None,
        ec_n_neighbors: int = 3,
        ec_seed: int | None = None,
        knn_backend: str = "auto",
        **kwargs: Any,
    ) -> None:
        TwoMemoryDispatcher.refuse_settings(kwargs, type(self).__name__)
        DQNPolicy.__init__(self, observation_space, action_space, lr_schedule, **kwargs)
        self._init_dispatch(score_window)
        self._init_keyed_memory(ec_projection_dim=ec_projection_dim, ec_seed=ec_seed, knn_backend=knn_backend)
        n_actions = int(action_space.n)
        if ec_capacity_per_action is None:
            ec_capacity_per_action = max(100_000 // (2 * n_actions), 1)
        self.ec_capacity_per_action = ec_capacity_per_action
        self.ec_n_neighbors = ec_n_neighbors
        self.memory = MFECMemory(
            self.embedding.key_dim,
            n_actions,
            capacity_per_action=ec_capacity_per_action,
            n_neighbors=ec_n_neighbors,
            knn_backend=knn_backend,  # type: ignore[arg-type]
        )

    def _episodic_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        actions, _ = mfec_actions(self.memory, self._keys(observation), self.rng, deterministic, epsilon=0.0)
        return th.as_tensor(actions)

    def _parametric_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        return self.q_net._predict(observation, deterministic=True)

    def update_episodic_memory(self, features: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> None:
        self.memory.update_episode(features, actions, returns)


class TwoMemoryMinAtarPolicy(TwoMemoryDQNPolicy):
    """:class:`TwoMemoryDQNPolicy` with the authors' MinAtar network (:class:`MinAtarCNN` + one linear layer)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", MinAtarCNN)
        kwargs.setdefault("net_arch", [])
        super().__init__(*args, **kwargs)


class TwoMemoryMultiInputDQNPolicy(TwoMemoryDQNPolicy):
    """:class:`TwoMemoryDQNPolicy` for Dict observations (goal envs): SB3's ``CombinedExtractor`` for the Q-network;
    the MFEC key concatenates ``observation`` and ``desired_goal`` (see :class:`~sb3_gcrl.memory.KeyEmbedding`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", CombinedExtractor)
        super().__init__(*args, **kwargs)


class TwoMemorySACPolicy(KeyedMemoryDispatchMixin, SACPolicy):
    """2M policy for continuous actions: a CEC memory (2M-EC, thesis Ch. 4) and a SAC actor (2M-RL).

    Not in the thesis: 2M with CEC and SAC is this package's extension of Ch. 5 to continuous actions. CEC stores
    actions scaled to [-1, 1] (the space the SAC actor and the replay buffer use) and acts as standalone CEC does
    (:func:`~sb3_gcrl.memory.actors.cec_actions`, thesis Algorithm 1): while training, the Eq. 4.5 sample plus
    Gaussian noise of std ``ec_noise_std`` with probability ``ec_epsilon``, or a uniformly random action when no
    stored state lies within n*d; evaluation (``deterministic=True``) takes the nearest row's action, and an empty
    memory answers the middle of the action space, so deterministic predictions never draw random numbers.

    :param observation_space: observation space (Box, or Dict for goal envs: observation + desired_goal keys).
    :param action_space: Box action space.
    :param lr_schedule: learning rate schedule of SAC.
    :param score_window: n of Eq. 5.6.
    :param ec_projection_dim: random-projection dimension of the CEC keys (None: none).
    :param ec_capacity: CEC rows.
    :param ec_distance_threshold: d of Table 4.4.
    :param ec_filter_factor: n of Table 4.4.
    :param ec_n_neighbors: k of Table 4.4.
    :param ec_temperature: tau of Eq. 4.5.
    :param ec_epsilon: epsilon of Algorithm 1: probability of adding the Gaussian noise to an EC action while
        training.
    :param ec_noise_std: sigma of Algorithm 1: std of that noise (in [-1, 1] units).
    :param ec_seed: seed of the projection and of the EC sampling generator.
    :param knn_backend: kNN backend of the CEC memory.
    :param kwargs: :class:`~stable_baselines3.sac.policies.SACPolicy` arguments.
    """

    ec_parameters = (  # noqa: RUF012
        *TwoMemoryDispatchMixin.ec_parameters,
        "ec_projection_dim",
        "ec_capacity",
        "ec_distance_threshold",
        "ec_filter_factor",
        "ec_n_neighbors",
        "ec_temperature",
        "ec_epsilon",
        "ec_noise_std",
        "ec_seed",
        "knn_backend",
    )
    memory: CECMemory

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        score_window: int = 50,
        ec_projection_dim: int | None = None,
        ec_capacity: int = 100_000,
        ec_distance_threshold: float = 0.1,
        ec_filter_factor: float = 1.0,
        ec_n_neighbors: int = 5,
        ec_temperature: float = 0.1,
        ec_epsilon: float = 0.1,
        ec_noise_std: float = 0.1,
        ec_seed: int | None = None,
        knn_backend: str = "auto",
        **kwargs: Any,
    ) -> None:
        TwoMemoryDispatcher.refuse_settings(kwargs, type(self).__name__)
        SACPolicy.__init__(self, observation_space, action_space, lr_schedule, **kwargs)
        self._init_dispatch(score_window)
        self.ec_epsilon = check_float("ec_epsilon", ec_epsilon, 0.0, 1.0)
        self.ec_noise_std = check_float("ec_noise_std", ec_noise_std, 0.0)
        self._init_keyed_memory(ec_projection_dim=ec_projection_dim, ec_seed=ec_seed, knn_backend=knn_backend)
        self.memory = CECMemory(
            self.embedding.key_dim,
            int(np.prod(action_space.shape)),
            capacity=ec_capacity,
            distance_threshold=ec_distance_threshold,
            filter_factor=ec_filter_factor,
            n_neighbors=ec_n_neighbors,
            temperature=ec_temperature,
            knn_backend=knn_backend,  # type: ignore[arg-type]
        )
        self.ec_capacity = ec_capacity
        self.ec_distance_threshold = ec_distance_threshold
        self.ec_filter_factor = ec_filter_factor
        self.ec_n_neighbors = ec_n_neighbors
        self.ec_temperature = ec_temperature
        action_dim = int(np.prod(action_space.shape))
        self._unit_low = -np.ones(action_dim, dtype=np.float32)
        self._unit_high = np.ones(action_dim, dtype=np.float32)

    def _episodic_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        actions, _ = cec_actions(
            self.memory,
            self._keys(observation),
            self._unit_low,
            self._unit_high,
            self.rng,
            deterministic,
            self.ec_epsilon,
            self.ec_noise_std,
        )
        return th.as_tensor(actions.reshape((-1, *self.action_space.shape)), dtype=th.float32)

    def _parametric_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        return self.actor(observation, deterministic=deterministic)

    def update_episodic_memory(self, features: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> None:
        self.memory.update_episode(features, actions.reshape(len(actions), -1), returns)


class TwoMemoryMultiInputSACPolicy(TwoMemorySACPolicy):
    """:class:`TwoMemorySACPolicy` for Dict observations (goal envs): SB3's ``CombinedExtractor`` for the networks;
    the CEC key concatenates ``observation`` and ``desired_goal`` (see :class:`~sb3_gcrl.memory.KeyEmbedding`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", CombinedExtractor)
        super().__init__(*args, **kwargs)

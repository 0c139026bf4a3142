"""SB3 plumbing shared by the episodic-control algorithms (CEC, MFEC): policy base and learn loop.

An episodic-control agent has no network and no gradient step: the policy *is* the memory. So the
policy is a :class:`~stable_baselines3.common.policies.BasePolicy` without parameters that holds the
memory and a :class:`~sb3_gcrl.memory.embedding.KeyEmbedding`, works on numpy end to end (no
tensor round trip per step), and puts the memory into its ``state_dict`` through
``get_extra_state`` (used rows only, as tensors), so ``save``/``load`` restore it exactly inside the
usual ``policy.pth`` of the SB3 zip. The algorithm collects steps with all envs at once and updates
the memory from each finished episode's discounted returns (thesis Algorithm 1).
"""

from __future__ import annotations

import sys
import time
from abc import abstractmethod
from collections.abc import Sequence
from typing import Any, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import LinearSchedule, is_vectorized_observation, safe_mean

from sb3_gcrl.memory.embedding import KeyEmbedding
from sb3_gcrl.memory.episode import EpisodeBuffers, discounted_returns
from sb3_gcrl.memory.knn import KNNBackend

SelfEpisodicControlAlgorithm = TypeVar("SelfEpisodicControlAlgorithm", bound="EpisodicControlAlgorithm")


def _to_tensor(value: Any) -> th.Tensor:
    return th.as_tensor(np.asarray(value))


class EpisodicControlPolicy(BasePolicy):
    """Base policy holding an episodic memory and the observation -> key embedding.

    Subclasses create ``self.memory`` (with ``state_dict``/``load_state_dict``/``__len__``) and
    implement :meth:`act`.

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
        self.rebuild_threshold = rebuild_threshold
        self.embedding = KeyEmbedding(observation_space, projection_dim, seed, self.observation_keys)
        self.rng = np.random.default_rng(seed)
        #: probability of exploring (epsilon), set by the algorithm's schedule during training
        self.exploration_rate = 0.0

    def set_seed(self, seed: int | None) -> None:
        """Reseed the action-sampling generator (the projection matrix stays as it is)."""
        self.rng = np.random.default_rng(seed)

    @abstractmethod
    def act(self, keys: np.ndarray, deterministic: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Actions for a batch of keys; returns ``(actions, hits)`` where ``hits`` marks the queries
        the memory could answer (logged as ``memory/hit_rate``)."""

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3 ``predict`` on numpy: embed, query the memory, return actions (batched or single)."""
        if isinstance(observation, tuple) and len(observation) == 2 and isinstance(observation[1], dict):
            raise ValueError(
                "predict() got a tuple (obs, info): pass only the observation returned by env.reset()/step()"
            )
        vectorized = is_vectorized_observation(observation, self.observation_space)
        if isinstance(observation, dict):
            batch: np.ndarray | dict[str, np.ndarray] = {
                k: (np.asarray(v) if vectorized else np.asarray(v)[None]) for k, v in observation.items()
            }
        else:
            batch = np.asarray(observation) if vectorized else np.asarray(observation)[None]
        actions, _ = self.act(self.embedding(batch), deterministic=deterministic)
        return (actions if vectorized else actions[0]), state

    def _predict(self, observation: th.Tensor | dict[str, th.Tensor], deterministic: bool = False) -> th.Tensor:
        if isinstance(observation, dict):
            obs: np.ndarray | dict[str, np.ndarray] = {k: v.cpu().numpy() for k, v in observation.items()}
        else:
            obs = observation.cpu().numpy()
        actions, _ = self.act(self.embedding(obs), deterministic=deterministic)
        return th.as_tensor(actions)

    def forward(self, obs: th.Tensor, deterministic: bool = False) -> th.Tensor:
        return self._predict(obs, deterministic)

    def get_extra_state(self) -> dict[str, th.Tensor]:
        """Memory rows and projection matrix, as tensors, for ``state_dict``/``policy.pth``."""
        state = {f"memory/{k}": _to_tensor(v) for k, v in self.memory.state_dict().items()}
        state.update({f"embedding/{k}": _to_tensor(v) for k, v in self.embedding.get_state().items()})
        return state

    def set_extra_state(self, state: dict[str, th.Tensor]) -> None:
        """Restore what :meth:`get_extra_state` returned."""
        memory_state = {k[len("memory/") :]: v.cpu().numpy() for k, v in state.items() if k.startswith("memory/")}
        for name in memory_state:
            if name == "clock" or name.endswith("/clock"):
                memory_state[name] = int(memory_state[name])
        self.embedding.set_state(
            {k[len("embedding/") :]: v.cpu().numpy() for k, v in state.items() if k.startswith("embedding/")}
        )
        self.memory.load_state_dict(memory_state)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            projection_dim=self.projection_dim,
            observation_keys=self.observation_keys,
            seed=self.seed,
            knn_backend=self.knn_backend,
            rebuild_threshold=self.rebuild_threshold,
        )
        return data


class EpisodicControlAlgorithm(BaseAlgorithm):
    """Learn loop of episodic control: act with the memory, update it after every finished episode.

    Subclasses set ``policy_aliases`` and implement :meth:`_policy_memory_kwargs`,
    :meth:`_check_spaces` and :meth:`_update_memory`.

    :param policy: policy class or alias.
    :param env: env, VecEnv or registered env id; any number of envs.
    :param gamma: discount factor of the stored Monte-Carlo returns.
    :param exploration_initial_eps: initial exploration probability epsilon.
    :param exploration_final_eps: final epsilon.
    :param exploration_fraction: fraction of the training budget over which epsilon decays linearly.
    :param projection_dim: random-projection dimension of the keys (``None``: raw observations).
    :param observation_keys: Dict observation keys concatenated into the key, in order.
    :param knn_backend: ``"auto"``, ``"kdtree"`` or ``"flat"`` (see :class:`~sb3_gcrl.memory.knn.KNNIndex`).
    :param rebuild_threshold: KD-tree rebuild threshold (``None``: automatic).
    :param stats_window_size: episodes averaged in the rollout logs.
    :param tensorboard_log: tensorboard log folder.
    :param policy_kwargs: extra policy arguments.
    :param verbose: 0 silent, 1 info.
    :param seed: seed of everything (projection matrix, action sampling, envs).
    :param device: kept for the SB3 API; everything runs on CPU with numpy.
    :param _init_setup_model: build the policy at construction.
    """

    policy: EpisodicControlPolicy

    def __init__(
        self,
        policy: str | type[EpisodicControlPolicy],
        env: GymEnv | str,
        gamma: float = 0.99,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.05,
        exploration_fraction: float = 0.1,
        projection_dim: int | None = None,
        observation_keys: Sequence[str] | None = None,
        knn_backend: KNNBackend = "auto",
        rebuild_threshold: int | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "cpu",
        _init_setup_model: bool = True,
    ) -> None:
        if hasattr(env, "action_space") and hasattr(env, "observation_space"):
            # before SB3's own (assertion) checks, so that the error names the fix
            self._check_spaces(env.observation_space, env.action_space)
        super().__init__(
            policy,
            env,
            learning_rate=0.0,  # nothing is trained by gradient descent
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            support_multi_env=True,
            seed=seed,
        )
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must lie in [0, 1], got {gamma}")
        for name, value in (
            ("exploration_initial_eps", exploration_initial_eps),
            ("exploration_final_eps", exploration_final_eps),
            ("exploration_fraction", exploration_fraction),
        ):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {value}")
        self.gamma = gamma
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_fraction = exploration_fraction
        self.projection_dim = projection_dim
        self.observation_keys = None if observation_keys is None else list(observation_keys)
        self.knn_backend = knn_backend
        self.rebuild_threshold = rebuild_threshold
        if self.env is not None:
            self._check_spaces(self.observation_space, self.action_space)
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ to implement
    @abstractmethod
    def _check_spaces(self, observation_space: spaces.Space, action_space: spaces.Space) -> None:
        """Raise a ``ValueError`` naming the fix when the spaces are not supported."""

    @abstractmethod
    def _policy_memory_kwargs(self) -> dict[str, Any]:
        """Memory hyperparameters passed to the policy constructor (besides the kNN backend)."""

    @abstractmethod
    def _update_memory(self, keys: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> dict[str, int]:
        """Update the memory with one finished episode; return counters to log under ``memory/``."""

    # ------------------------------------------------------------------ SB3 API
    def _setup_model(self) -> None:
        if is_image_space(self.observation_space) and self.projection_dim is None:
            raise ValueError("Image observations need a key embedding: set projection_dim (e.g. 8, as in the thesis)")
        self.set_random_seed(self.seed)
        self.exploration_schedule: Schedule = LinearSchedule(
            self.exploration_initial_eps, self.exploration_final_eps, self.exploration_fraction
        )
        kwargs = dict(
            projection_dim=self.projection_dim,
            observation_keys=self.observation_keys,
            seed=self.seed,
            knn_backend=self.knn_backend,
            rebuild_threshold=self.rebuild_threshold,
            **self._policy_memory_kwargs(),
        )
        kwargs.update(self.policy_kwargs)
        self.policy = self.policy_class(self.observation_space, self.action_space, **kwargs)
        self.policy.set_seed(self.seed)
        self.exploration_rate = self.exploration_initial_eps
        self.policy.exploration_rate = self.exploration_rate
        self._episode_buffers: EpisodeBuffers | None = None
        self._reset_memory_stats()

    def set_random_seed(self, seed: int | None = None) -> None:
        """Seed python/numpy/torch, the action space, the envs and the policy's sampling generator."""
        super().set_random_seed(seed)
        if seed is not None and getattr(self, "policy", None) is not None:
            self.policy.set_seed(seed)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_episode_buffers", "exploration_schedule"]

    def _reset_memory_stats(self) -> None:
        self._n_queries = 0
        self._n_hits = 0
        self._memory_counts: dict[str, int] = {}

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        had_obs = self._last_obs is not None
        total_timesteps, callback = super()._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        assert self.env is not None
        if self._episode_buffers is None or reset_num_timesteps or not had_obs:
            # the envs were (re)set: running episodes start from scratch
            action_shape = self.action_space.shape if isinstance(self.action_space, spaces.Box) else ()
            action_dtype = np.float32 if isinstance(self.action_space, spaces.Box) else np.int64
            self._episode_buffers = EpisodeBuffers(
                self.env.num_envs, self.policy.embedding.key_dim, action_shape, action_dtype
            )
        return total_timesteps, callback

    def learn(
        self: SelfEpisodicControlAlgorithm,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 10,
        tb_log_name: str = "EpisodicControl",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfEpisodicControlAlgorithm:
        """Collect ``total_timesteps`` env steps, updating the memory after every finished episode.

        :param total_timesteps: env steps (summed over envs).
        :param callback: SB3 callback(s), called after every vectorised step.
        :param log_interval: dump the logs every ``log_interval`` finished episodes (None or <= 0: never).
        :param tb_log_name: tensorboard run name.
        :param reset_num_timesteps: start counting from 0 (and reset the envs).
        :param progress_bar: show a tqdm/rich progress bar.
        """
        total_timesteps, callback = self._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        callback.on_training_start(locals(), globals())
        assert self.env is not None and self._episode_buffers is not None and self._last_obs is not None
        n_envs = self.env.num_envs
        buffers = self._episode_buffers
        embed = self.policy.embedding

        while self.num_timesteps < total_timesteps:
            self._update_current_progress_remaining(self.num_timesteps, total_timesteps)
            self.exploration_rate = float(self.exploration_schedule(self._current_progress_remaining))
            self.policy.exploration_rate = self.exploration_rate

            keys = embed(self._last_obs)
            actions, hits = self.policy.act(keys, deterministic=False)
            new_obs, rewards, dones, infos = self.env.step(actions)
            self.num_timesteps += n_envs
            self._n_queries += n_envs
            self._n_hits += int(hits.sum())
            buffers.add(keys, actions, rewards)

            callback.update_locals(locals())
            if not callback.on_step():
                break
            self._update_info_buffer(infos, dones)
            for env_idx in np.flatnonzero(dones):
                ep_keys, ep_actions, ep_rewards = buffers.pop(int(env_idx))
                counts = self._update_memory(ep_keys, ep_actions, discounted_returns(ep_rewards, self.gamma))
                for name, count in counts.items():
                    self._memory_counts[name] = self._memory_counts.get(name, 0) + count
                self._episode_num += 1
                if log_interval and log_interval > 0 and self._episode_num % log_interval == 0:
                    self.dump_logs()
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones

        callback.on_training_end()
        return self

    def dump_logs(self) -> None:
        """Record rollout, time and memory statistics and write them."""
        assert self.ep_info_buffer is not None and self.ep_success_buffer is not None
        time_elapsed = max((time.time_ns() - self.start_time) / 1e9, sys.float_info.epsilon)
        fps = int((self.num_timesteps - self._num_timesteps_at_start) / time_elapsed)
        if len(self.ep_info_buffer) > 0 and len(self.ep_info_buffer[0]) > 0:
            self.logger.record("rollout/ep_rew_mean", safe_mean([ep_info["r"] for ep_info in self.ep_info_buffer]))
            self.logger.record("rollout/ep_len_mean", safe_mean([ep_info["l"] for ep_info in self.ep_info_buffer]))
        if len(self.ep_success_buffer) > 0:
            self.logger.record("rollout/success_rate", safe_mean(self.ep_success_buffer))
        self.logger.record("rollout/exploration_rate", self.exploration_rate)
        self.logger.record("memory/size", len(self.policy.memory))
        if self._n_queries:
            self.logger.record("memory/hit_rate", self._n_hits / self._n_queries)
        for name, count in self._memory_counts.items():
            self.logger.record(f"memory/{name}", count)
        self.logger.record("time/episodes", self._episode_num, exclude="tensorboard")
        self.logger.record("time/fps", fps)
        self.logger.record("time/time_elapsed", int(time_elapsed), exclude="tensorboard")
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(step=self.num_timesteps)
        self._reset_memory_stats()

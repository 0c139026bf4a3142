"""Learn loop of the episodic-control algorithms (CEC, MFEC): act with the memory, update it after every episode.

The algorithm collects steps with all envs at once and updates the memory of its
:class:`~sb3_gcrl.episodic_control.policies.EpisodicControlPolicy` from each finished episode's discounted returns
(thesis Algorithm 1); there is no replay buffer and no gradient step.
"""

from __future__ import annotations

import io
import pathlib
import sys
import time
import warnings
from abc import abstractmethod
from collections.abc import Sequence
from typing import Any, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import LinearSchedule, safe_mean

from sb3_gcrl.common.saving import ModelFileMixin
from sb3_gcrl.common.validation import check_choice, check_finite_rewards, check_float, check_int, check_optional_int
from sb3_gcrl.episodic_control.policies import EpisodicControlPolicy
from sb3_gcrl.memory.episode import EpisodeRecorder, EpisodeRecordingMixin
from sb3_gcrl.memory.knn import KNN_BACKENDS, KNNBackend

SelfEpisodicControlAlgorithm = TypeVar("SelfEpisodicControlAlgorithm", bound="EpisodicControlAlgorithm")


class EpisodicControlAlgorithm(EpisodeRecordingMixin, ModelFileMixin, BaseAlgorithm):
    """Learn loop of episodic control: act with the memory, update it after every finished episode.

    Subclasses set ``policy_aliases`` and implement :meth:`_check_spaces`, :meth:`_memory_kwargs` and
    :meth:`_update_memory`. The first parameters after ``env`` are the ones whose defaults differ between the
    algorithms (each states its own, the authors' values, and passes them on in order). The memory settings are the
    policy's constructor arguments (with their defaults): a subclass takes them under the same names, reads their
    defaults from the policy (:func:`~sb3_gcrl.common.arguments.constructor_defaults`), keeps each as an attribute
    of the same name before calling this constructor and hands them to the policy in :meth:`_memory_kwargs`; the
    policy checks them, and the attributes then hold them as the policy converted them
    (:meth:`~sb3_gcrl.episodic_control.EpisodicControlPolicy.memory_settings`).

    :param policy: policy class or alias.
    :param env: env, VecEnv or registered env id; any number of envs.
    :param exploration_initial_eps: initial exploration probability epsilon.
    :param exploration_final_eps: final epsilon.
    :param exploration_fraction: fraction of the training budget over which epsilon decays linearly.
    :param projection_dim: random-projection dimension of the keys (``None``: raw observations).
    :param gamma: discount factor of the stored Monte-Carlo returns.
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
    :raises ValueError: naming the parameter, for a hyperparameter out of range, or a policy class of
        another algorithm (e.g. loading an MFEC file with ``CEC.load``).
    """

    policy: EpisodicControlPolicy

    def __init__(
        self,
        policy: str | type[EpisodicControlPolicy],
        env: GymEnv | str,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.05,
        exploration_fraction: float = 0.1,
        projection_dim: int | None = None,
        gamma: float = 0.99,
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
        # first the policy (a file saved by another algorithm is loaded through here), then the spaces,
        # before SB3's own (assertion) checks, so that the errors name the fix
        self._check_policy_class(self._get_policy_from_name(policy) if isinstance(policy, str) else policy)
        if hasattr(env, "action_space") and hasattr(env, "observation_space"):
            self._check_spaces(env.observation_space, env.action_space)
        gamma = check_float("gamma", gamma, 0.0, 1.0)
        exploration_initial_eps = check_float("exploration_initial_eps", exploration_initial_eps, 0.0, 1.0)
        exploration_final_eps = check_float("exploration_final_eps", exploration_final_eps, 0.0, 1.0)
        exploration_fraction = check_float("exploration_fraction", exploration_fraction, 0.0, 1.0)
        projection_dim = check_optional_int("projection_dim", projection_dim)
        rebuild_threshold = check_optional_int("rebuild_threshold", rebuild_threshold)
        stats_window_size = check_int("stats_window_size", stats_window_size)
        check_choice("knn_backend", knn_backend, KNN_BACKENDS)
        #: seed given to :meth:`set_random_seed` while no env was attached, applied by :meth:`set_env`
        self._pending_env_seed: int | None = None
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
        self.gamma = gamma
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_fraction = exploration_fraction
        #: current epsilon (saved with the model, so a loaded model explores as the saved one did)
        self.exploration_rate = exploration_initial_eps
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
    def _memory_kwargs(self) -> dict[str, Any]:
        """The memory settings handed to the policy by ``_setup_model``, by its constructor argument names."""

    @abstractmethod
    def _update_memory(self, keys: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> dict[str, int]:
        """Update the memory with one finished episode; return counters to log under ``memory/``."""

    # ------------------------------------------------------------------ SB3 API
    def _get_policy_from_name(self, policy_name: str) -> type[BasePolicy]:
        """Policy class of an alias; the error for an unknown alias lists the valid ones.

        ``"CnnPolicy"`` is not an alias on purpose: there is no network, so nothing to make
        convolutional. Image observations work with the default policy (transposed channel-first as in
        SB3, keyed by a Gaussian random projection of the pixels, ``projection_dim``).
        """
        if policy_name in self.policy_aliases:
            return self.policy_aliases[policy_name]
        name, default = type(self).__name__, next(iter(self.policy_aliases))
        if policy_name == "CnnPolicy":
            raise ValueError(
                f"{name} has no 'CnnPolicy': it has no network, so nothing is convolutional. Use {default!r}, which "
                "handles image observations too (channel-last images are transposed as in SB3; set projection_dim "
                "to key them by a random projection of the pixels)"
            )
        raise ValueError(f"Policy {policy_name!r} unknown for {name}; use one of {sorted(self.policy_aliases)}")

    def _check_policy_class(self, policy_class: type[BasePolicy]) -> None:
        """Raise a ``ValueError`` naming the right algorithm when ``policy_class`` belongs to another one."""
        accepted = tuple(dict.fromkeys(self.policy_aliases.values()))
        if isinstance(policy_class, type) and issubclass(policy_class, accepted):
            return
        name = type(self).__name__
        owner = _episodic_algorithm_of(policy_class)
        if owner is not None:
            raise ValueError(
                f"{name} got {policy_class.__name__}, the policy class of {owner}: this is a model of {owner}, "
                f"not of {name}. Load a file saved by {owner} with {owner}.load(path); build a {name} with one of "
                f"{sorted(self.policy_aliases)}"
            )
        raise ValueError(
            f"{name} cannot use the policy {getattr(policy_class, '__name__', policy_class)!r}: it must be a subclass "
            f"of {', '.join(c.__name__ for c in accepted)}. A file saved by another algorithm must be loaded with "
            "that algorithm's load()"
        )

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
            **self._memory_kwargs(),
        )
        kwargs.update(self.policy_kwargs)
        self.policy = self.policy_class(self.observation_space, self.action_space, **kwargs)
        for name, value in self.policy.memory_settings().items():
            setattr(self, name, value)  # as the policy checked them (and ``policy_kwargs`` set them)
        self.policy.set_seed(self.seed)
        self.policy.exploration_rate = self.exploration_rate
        self._episodes = EpisodeRecorder(initial_length=1024)
        self._reset_memory_stats()

    def set_random_seed(self, seed: int | None = None) -> None:
        """Seed python/numpy/torch, the action space, the envs and the policy's sampling generator.

        With no env attached (e.g. after ``load(path)`` without ``env``), the envs are seeded by the next
        :meth:`set_env`, so ``load -> set_random_seed -> set_env -> learn`` is reproducible too.

        :param seed: the seed; ``None`` changes nothing.
        """
        super().set_random_seed(seed)
        if seed is None:
            return
        if getattr(self, "policy", None) is not None:
            self.policy.set_seed(seed)
        self._pending_env_seed = seed if self.env is None else None

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """SB3's ``set_env``; also seeds the new envs with a seed given to :meth:`set_random_seed` while no
        env was attached.

        :param env: the new env (same spaces).
        :param force_reset: reset the env at the next ``learn`` (SB3's default).
        """
        super().set_env(env, force_reset)
        if self._pending_env_seed is not None:
            assert self.env is not None
            self.env.seed(self._pending_env_seed)
            self._pending_env_seed = None

    def save_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase) -> None:
        """Episodic control has no replay buffer: the memory is saved in the model file by :meth:`save`.

        Warns and writes nothing (RL-Zoo's ``--save-replay-buffer`` calls this).

        :param path: where a replay buffer would go.
        """
        warnings.warn(
            f"{type(self).__name__} has no replay buffer: its episodic memory is saved in the model file by save() "
            f"and restored by load(); nothing was written to {path}",
            UserWarning,
            stacklevel=2,
        )

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True) -> None:
        """Episodic control has no replay buffer: the memory is restored from the model file by :meth:`load`.

        Warns and reads nothing.

        :param path: where a replay buffer would be.
        :param truncate_last_traj: unused (SB3 signature).
        """
        warnings.warn(
            f"{type(self).__name__} has no replay buffer: its episodic memory is restored from the model file by "
            f"load(); nothing was read from {path}",
            UserWarning,
            stacklevel=2,
        )

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "exploration_schedule", "_pending_env_seed"]

    def _reset_memory_stats(self) -> None:
        self._n_queries = 0
        self._n_hits = 0
        self._memory_counts: dict[str, int] = {}

    def learn(
        self: SelfEpisodicControlAlgorithm,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 10,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfEpisodicControlAlgorithm:
        """Collect ``total_timesteps`` env steps, updating the memory after every finished episode.

        :param total_timesteps: env steps (summed over envs).
        :param callback: SB3 callback(s), called after every vectorised step.
        :param log_interval: dump the logs every ``log_interval`` finished episodes (None or <= 0: never).
        :param tb_log_name: tensorboard run name (``None``: the class name, e.g. ``CEC_1``).
        :param reset_num_timesteps: start counting from 0 (and reset the envs).
        :param progress_bar: show a tqdm/rich progress bar.
        """
        if tb_log_name is None:
            tb_log_name = type(self).__name__
        total_timesteps, callback = self._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        callback.on_training_start(locals(), globals())
        assert self.env is not None and self._last_obs is not None
        n_envs = self.env.num_envs
        embed = self.policy.embedding

        # a "rollout" (SB3's on_rollout_start/end) is the collection between two memory updates
        callback.on_rollout_start()
        while self.num_timesteps < total_timesteps:
            self._update_current_progress_remaining(self.num_timesteps, total_timesteps)
            self.exploration_rate = float(self.exploration_schedule(self._current_progress_remaining))
            self.policy.exploration_rate = self.exploration_rate

            keys = embed(self._last_obs)
            actions, hits = self.policy.act(keys, deterministic=False)
            new_obs, rewards, dones, infos = self.env.step(actions)
            check_finite_rewards(
                rewards,
                f"at timestep {self.num_timesteps}",
                "episodic memory values must be finite (a NaN would spread to every value compared with it)",
            )
            self.num_timesteps += n_envs
            self._n_queries += n_envs
            self._n_hits += int(hits.sum())
            finished = self._episodes.record(keys, actions, rewards, dones, infos)

            callback.update_locals(locals())
            if not callback.on_step():
                break
            self._update_info_buffer(infos, dones)
            if dones.any():
                callback.on_rollout_end()
            for episode in finished:
                counts = self._update_memory(episode.keys, episode.actions, episode.returns(self.gamma))
                for name, count in counts.items():
                    self._memory_counts[name] = self._memory_counts.get(name, 0) + count
                self._episode_num += 1
                if log_interval and log_interval > 0 and self._episode_num % log_interval == 0:
                    self.dump_logs()
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones
            if dones.any():
                callback.on_rollout_start()
        callback.on_rollout_end()
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


def _episodic_algorithm_of(policy_class: Any) -> str | None:
    """Name of the :class:`EpisodicControlAlgorithm` whose policies ``policy_class`` belongs to, if any."""
    if not isinstance(policy_class, type):
        return None
    pending: list[type[EpisodicControlAlgorithm]] = [EpisodicControlAlgorithm]
    while pending:
        algorithm = pending.pop(0)  # breadth first: the library's class before a user's subclass of it
        pending.extend(algorithm.__subclasses__())
        if algorithm.policy_aliases and issubclass(policy_class, tuple(algorithm.policy_aliases.values())):
            return algorithm.__name__
    return None

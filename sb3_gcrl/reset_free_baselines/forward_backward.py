"""Forward-backward reset-free agent (the agent of MEDAL's official code; R3L in the thesis modifies it).

:class:`ForwardBackwardSAC` is an SB3 ``SAC`` (the forward policy: ``model.policy``, ``predict``, evaluation) that
holds a second SAC learner, :attr:`ForwardBackwardSAC.backward`, for the backward phases. Which of the two acts at a
step is the phase of the env, :attr:`~sb3_gcrl.reset_free_baselines.ForwardBackwardWrapper.phase` (the reset-free
wrappers decide the phases; the algorithm only follows them). Each policy has its own replay buffer
(:class:`~sb3_gcrl.reset_free_baselines.buffers.PhaseReplayBuffer`): a transition goes to the buffer of the policy
that acted. The forward policy learns from the env's reward for the commanded task goal; the backward policy from a
learned reward model of the next state (:meth:`ForwardBackwardSAC._backward_reward`, the subclasses: MEDAL's
discriminator, R3L's RND).

Updates follow MEDAL's code: only the policy that acted is updated (its ``gradient_steps`` share of each ``train``
call is the share of the steps its phase took since the last call), and the reward model is updated every
``reward_model_train_freq`` env steps once learning has started.
"""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.save_util import load_from_pkl, save_to_pkl
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.sac.policies import SACPolicy
from torch import nn

from sb3_gcrl.reset_free_baselines.buffers import PhaseReplayBuffer, RelabeledRewards
from sb3_gcrl.reset_free_baselines.reward_models import as_tensor

SelfForwardBackwardSAC = TypeVar("SelfForwardBackwardSAC", bound="ForwardBackwardSAC")

#: the env attribute that tells a forward-backward env (``ForwardBackwardWrapper``) apart
PHASE_ENV_ATTR = "forward_backward_steps"


class _PrefixedLogger:
    """Passes ``record`` calls to a logger under another section (``train/x`` -> ``<section>/x``)."""

    def __init__(self, logger: Any, section: str) -> None:
        self.logger, self.section = logger, section

    def record(self, key: str, value: Any, exclude: Any = None) -> None:
        self.logger.record(f"{self.section}/{key.split('/', 1)[-1]}", value, exclude)


class _PhaseRouter:
    """``add`` of a replay buffer that sends each env's row to the buffer of the policy that acted."""

    def __init__(self, forward: PhaseReplayBuffer, backward: PhaseReplayBuffer, backward_acted: np.ndarray) -> None:
        self.buffers = (forward, backward)
        self.backward_acted = backward_acted

    def add(
        self,
        obs: dict[str, np.ndarray],
        next_obs: dict[str, np.ndarray],
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        for i, backward in enumerate(self.backward_acted):
            row = slice(i, i + 1)
            self.buffers[int(backward)].add(
                {k: v[row] for k, v in obs.items()},
                {k: v[row] for k, v in next_obs.items()},
                action[row],
                reward[row],
                done[row],
                [infos[i]],
            )


class ForwardBackwardSAC(SAC):
    """A forward SAC (this object) and a backward SAC (:attr:`backward`) alternating by the env's phases.

    Use it on a goal env wrapped in :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` (``segment_length`` = phase length)
    and :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardWrapper`, and pass
    :class:`~sb3_gcrl.callbacks.ResetFreeCallback` to ``learn`` (it switches the training env to reset-free mode).
    The SAC arguments are SB3's (both policies use them); the others:

    :param state_key: key of the Dict observation that the reward model reads (the state).
    :param reward_model_train_freq: env steps between two reward-model updates (MEDAL: 10).
    :param reward_model_gradient_steps: gradient steps of the reward model per update (MEDAL: 1).
    :param reward_model_batch_size: batch of a reward-model step.
    :param reward_model_kwargs: keyword arguments of the reward model (e.g. ``hidden``, ``learning_rate``).
    """

    #: section of the logger keys of this algorithm (``<prefix>/backward_reward``, ...)
    log_prefix: ClassVar[str] = "forward_backward"
    reward_model: nn.Module
    backward: SAC
    backward_buffer: PhaseReplayBuffer

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 3e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 100,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        ent_coef: str | float = "auto",
        target_update_interval: int = 1,
        target_entropy: str | float = "auto",
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        state_key: str = "observation",
        reward_model_train_freq: int = 10,
        reward_model_gradient_steps: int = 1,
        reward_model_batch_size: int = 256,
        reward_model_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
    ) -> None:
        if replay_buffer_class is not None and not issubclass(replay_buffer_class, PhaseReplayBuffer):
            raise ValueError(
                f"{type(self).__name__} keeps one PhaseReplayBuffer per policy; replay_buffer_class "
                f"{replay_buffer_class.__name__} is not one (HER relabeling is not part of MEDAL/R3L): leave it out"
            )
        for name, value in (
            ("reward_model_train_freq", reward_model_train_freq),
            ("reward_model_gradient_steps", reward_model_gradient_steps),
            ("reward_model_batch_size", reward_model_batch_size),
        ):
            if int(value) != value or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value}")
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=action_noise,
            replay_buffer_class=replay_buffer_class or PhaseReplayBuffer,
            replay_buffer_kwargs=replay_buffer_kwargs,
            ent_coef=ent_coef,
            target_update_interval=target_update_interval,
            target_entropy=target_entropy,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self.state_key = state_key
        self.reward_model_train_freq = int(reward_model_train_freq)
        self.reward_model_gradient_steps = int(reward_model_gradient_steps)
        self.reward_model_batch_size = int(reward_model_batch_size)
        self.reward_model_kwargs = dict(reward_model_kwargs or {})
        #: env steps taken by the forward and by the backward policy (all envs), in total and since the last train
        self.phase_steps = np.zeros(2, dtype=np.int64)
        self._pending_steps = np.zeros(2, dtype=np.int64)
        self._update_credit = np.zeros(2, dtype=np.float64)
        self._reward_model_timestep: int | None = None
        self._backward_acted = np.zeros(1, dtype=bool)
        if self.env is not None:
            self._check_phase_env(self.env)
        if _init_setup_model:
            self._setup_model()

    # --- construction -----------------------------------------------------------------------------------------
    def _check_phase_env(self, env: VecEnv) -> None:
        if not env.has_attr(PHASE_ENV_ATTR):
            raise ValueError(
                f"{type(self).__name__} follows the forward/backward phases of the env: wrap it as "
                "ForwardBackwardWrapper(ResetFreeWrapper(env, segment_length=300, ...)) "
                "(sb3_gcrl.reset_free_baselines.ForwardBackwardWrapper; RL-Zoo: env_wrapper) and pass "
                "ResetFreeCallback() to learn"
            )

    def _state_dim(self) -> int:
        if not isinstance(self.observation_space, spaces.Dict) or self.state_key not in self.observation_space.spaces:
            raise ValueError(
                f"{type(self).__name__} needs a Dict observation with the state under state_key={self.state_key!r}; "
                f"got {self.observation_space}"
            )
        return spaces.flatdim(self.observation_space[self.state_key])

    def _make_buffer(self) -> PhaseReplayBuffer:
        assert self.replay_buffer_class is not None
        return self.replay_buffer_class(  # type: ignore[return-value]
            self.buffer_size,
            self.observation_space,
            self.action_space,
            device=self.device,
            n_envs=1,  # each env's rows are added one by one, to the buffer of the policy that acted
            optimize_memory_usage=False,
            **self.replay_buffer_kwargs,
        )

    def _make_reward_model(self, state_dim: int) -> nn.Module:
        """The backward policy's reward model (subclasses)."""
        raise NotImplementedError

    def _setup_model(self) -> None:
        state_dim = self._state_dim()
        self.replay_buffer = self._make_buffer()
        super()._setup_model()
        self.backward_buffer = self._make_buffer()
        self.backward = SAC(
            self.policy_class,
            None,  # type: ignore[arg-type]
            learning_rate=self.learning_rate,
            buffer_size=self.buffer_size,
            batch_size=self.batch_size,
            tau=self.tau,
            gamma=self.gamma,
            ent_coef=self.ent_coef,
            target_update_interval=self.target_update_interval,
            target_entropy=self.target_entropy,  # a float by now (SAC's "auto" resolved above)
            policy_kwargs=self.policy_kwargs,
            device=self.device,
            _init_setup_model=False,
        )
        self.backward.observation_space, self.backward.action_space = self.observation_space, self.action_space
        self.backward.n_envs = 1
        self.backward.replay_buffer = RelabeledRewards(self.backward_buffer, self._backward_reward)  # type: ignore
        self.backward._setup_model()
        self.reward_model = self._make_reward_model(state_dim).to(self.device)

    # --- acting and storing -----------------------------------------------------------------------------------
    def _read_phases(self) -> np.ndarray:
        assert self.env is not None
        return np.array([phase == "backward" for phase in self.env.get_attr("phase")], dtype=bool)

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """The forward policy's action for envs in a forward phase, the backward policy's for the others."""
        self._backward_acted = self._read_phases()
        action, buffer_action = super()._sample_action(learning_starts, action_noise, n_envs)
        if self.num_timesteps < learning_starts or not self._backward_acted.any():
            return action, buffer_action  # warm-up: uniform actions for both policies
        unscaled, _ = self.backward.predict(self._last_obs, deterministic=False)  # type: ignore[arg-type]
        scaled = self.policy.scale_action(unscaled)
        if action_noise is not None:
            scaled = np.clip(scaled + action_noise(), -1, 1)
        rows = self._backward_acted
        buffer_action = buffer_action.copy()
        buffer_action[rows] = scaled[rows]
        action = self.policy.unscale_action(buffer_action)
        return action, buffer_action

    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: np.ndarray | dict[str, np.ndarray],
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store each env's transition in the buffer of the policy that acted (forward or backward)."""
        backward = self._backward_acted
        counts = np.array([len(backward) - backward.sum(), backward.sum()], dtype=np.int64)
        self.phase_steps += counts
        self._pending_steps += counts
        router = _PhaseRouter(self.replay_buffer, self.backward_buffer, backward)  # type: ignore[arg-type]
        super()._store_transition(router, buffer_action, new_obs, reward, dones, infos)  # type: ignore[arg-type]

    # --- training -----------------------------------------------------------------------------------------------
    def _backward_reward(self, next_observations: dict[str, th.Tensor]) -> th.Tensor:
        """The backward reward of sampled next observations, ``(batch, 1)`` (subclasses); logged."""
        reward = self._reward_of_states(
            next_observations[self.state_key].reshape(len(next_observations[self.state_key]), -1).float()
        )
        self.logger.record(f"{self.log_prefix}/backward_reward", float(reward.mean()))
        return reward

    def _reward_of_states(self, states: th.Tensor) -> th.Tensor:
        raise NotImplementedError

    def _reward_model_step(self) -> float | None:
        """One reward-model gradient step (subclasses); None when there is no data for it yet."""
        raise NotImplementedError

    def _train_reward_model(self) -> None:
        if self._reward_model_timestep is None:
            self._reward_model_timestep = self.num_timesteps - self.reward_model_train_freq
        due = (self.num_timesteps - self._reward_model_timestep) // self.reward_model_train_freq
        self._reward_model_timestep += due * self.reward_model_train_freq
        losses = []
        for _ in range(due * self.reward_model_gradient_steps):
            loss = self._reward_model_step()
            if loss is None:
                break
            losses.append(loss)
        if losses:
            self.logger.record(f"{self.log_prefix}/{self._reward_model_loss_name}", float(np.mean(losses)))

    _reward_model_loss_name: ClassVar[str] = "reward_model_loss"

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """Update the reward model if due, then the forward and backward SAC by the steps each phase took."""
        self._train_reward_model()
        total = int(self._pending_steps.sum())
        if total > 0:
            self._update_credit += gradient_steps * self._pending_steps / total
            self._pending_steps[:] = 0
        updates = np.floor(self._update_credit + 1e-9).astype(int)
        self._update_credit -= updates
        if updates[0] > 0 and self.replay_buffer is not None and self.replay_buffer.size() > 0:
            super().train(int(updates[0]), batch_size)
        if updates[1] > 0 and self.backward_buffer.size() > 0:
            self.backward._current_progress_remaining = self._current_progress_remaining
            self.backward._logger = _PrefixedLogger(self.logger, "backward")  # type: ignore[assignment]
            self.backward.train(int(updates[1]), batch_size)
        self.logger.record(
            f"{self.log_prefix}/forward_step_share", float(self.phase_steps[0] / max(self.phase_steps.sum(), 1))
        )
        self.logger.record(
            f"{self.log_prefix}/backward_step_share", float(self.phase_steps[1] / max(self.phase_steps.sum(), 1))
        )

    def learn(
        self: SelfForwardBackwardSAC,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfForwardBackwardSAC:
        """SB3's ``learn`` (pass :class:`~sb3_gcrl.callbacks.ResetFreeCallback` for reset-free training).

        :param tb_log_name: tensorboard run name (default: the class name).
        """
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=type(self).__name__ if tb_log_name is None else tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        super().set_env(env, force_reset)
        assert self.env is not None
        self._check_phase_env(self.env)

    # --- saving ------------------------------------------------------------------------------------------------
    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "backward", "backward_buffer", "reward_model", "_backward_acted"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        state_dicts = [*state_dicts, "backward.policy", "backward.actor.optimizer", "backward.critic.optimizer"]
        if self.backward.ent_coef_optimizer is not None:
            state_dicts.append("backward.ent_coef_optimizer")
            variables = [*variables, "backward.log_ent_coef"]
        else:
            variables = [*variables, "backward.ent_coef_tensor"]
        return [*state_dicts, "reward_model", "reward_model.optimizer"], variables

    def save_replay_buffer(self, path: Any) -> None:
        """Save both replay buffers (forward and backward) in one pickle file.

        :param path: file path or file object.
        """
        save_to_pkl(path, {"forward": self.replay_buffer, "backward": self.backward_buffer}, self.verbose)

    def load_replay_buffer(self, path: Any, truncate_last_traj: bool = True) -> None:
        """Load both replay buffers saved by :meth:`save_replay_buffer`.

        :param path: file path or file object.
        :param truncate_last_traj: unused (no HER buffer here); kept for SB3's signature.
        """
        buffers = load_from_pkl(path, self.verbose)
        if not (
            isinstance(buffers, dict)
            and set(buffers) == {"forward", "backward"}
            and all(isinstance(b, PhaseReplayBuffer) for b in buffers.values())
        ):
            raise ValueError(
                f"{path} does not hold the forward and backward buffers of {type(self).__name__}.save_replay_buffer"
            )
        for buffer in buffers.values():
            buffer.device = self.device
        self.replay_buffer, self.backward_buffer = buffers["forward"], buffers["backward"]
        self.backward.replay_buffer = RelabeledRewards(self.backward_buffer, self._backward_reward)  # type: ignore

    # --- helpers for the subclasses ----------------------------------------------------------------------------
    def _visited_states(self, n: int) -> th.Tensor | None:
        """``n`` next states of rows the backward policy collected (with replacement), or None if there is none."""
        states = self.backward_buffer.sample_visited_states(n, self.state_key)
        return None if states is None else as_tensor(states, self.device)

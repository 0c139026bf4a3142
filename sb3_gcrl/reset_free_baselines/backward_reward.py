"""The backward policy of MEDAL and R3L learns from a learned reward model of the next state.

:class:`BackwardRewardSAC` is a :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC` (the two learners, their
phases and buffers) whose backward SAC samples its buffer through
:class:`~sb3_gcrl.reset_free_baselines.buffers.RelabeledRewards`: the stored env reward is replaced, at sampling
time, by the reward model's value of the next state (as MEDAL's official code does). The reward model (MEDAL's
discriminator, R3L's RND; the subclasses) is updated every ``reward_model_train_freq`` env steps once learning has
started. Both buffers are :class:`~sb3_gcrl.reset_free_baselines.buffers.PhaseReplayBuffer` (they mark demonstration
rows) with one column, so that several envs in different phases can share a step.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.sac.policies import MultiInputPolicy, SACPolicy
from torch import nn

from sb3_gcrl.common.seeding import SeededGeneratorMixin
from sb3_gcrl.common.validation import check_int
from sb3_gcrl.reset_free_baselines.buffers import PhaseReplayBuffer, RelabeledRewards
from sb3_gcrl.reset_free_baselines.forward_backward import ForwardBackwardSAC
from sb3_gcrl.reset_free_baselines.reward_models import as_tensor


class BackwardRewardSAC(SeededGeneratorMixin, ForwardBackwardSAC):
    """A :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC` whose backward policy learns from a reward model.

    The forward policy learns from the env's reward for the commanded task goal; the backward policy from the reward
    model's value of the next state (:meth:`_backward_reward`). Subclasses give the reward model
    (:meth:`_make_reward_model`, with a ``reward(states)`` method, and :meth:`_reward_model_step`). The states of a
    reward-model batch are drawn with the algorithm's own generator (seeded from ``seed``, saved with the model).

    :param policy: SAC policy (``"MultiInputPolicy"``).
    :param env: goal env wrapped in ``ResetFreeWrapper`` and ``ForwardBackwardWrapper``.
    :param state_key: key of the Dict observation that the reward model reads (the state).
    :param reward_model_train_freq: env steps between two reward-model updates (MEDAL: 10).
    :param reward_model_gradient_steps: gradient steps of the reward model per update (MEDAL: 1).
    :param reward_model_batch_size: batch of a reward-model step (None: the algorithm's official value,
        :attr:`default_reward_model_batch_size`).
    :param reward_model_kwargs: keyword arguments of the reward model (e.g. ``hidden``, ``learning_rate``).
    :param replay_buffer_class: a :class:`~sb3_gcrl.reset_free_baselines.PhaseReplayBuffer` (subclass), the default.
    :param _init_setup_model: build the networks at construction (SB3's load passes False).
    :param kwargs: SB3's SAC arguments, see :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC`.
    """

    #: SB3's SAC aliases for the observations supported: Dict only (the reward model reads ``state_key``)
    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MultiInputPolicy": MultiInputPolicy}
    _single_column_buffers: ClassVar[bool] = True
    _reward_model_loss_name: ClassVar[str] = "reward_model_loss"
    #: ``reward_model_batch_size`` when none is given (the one place where each algorithm's default lives)
    default_reward_model_batch_size: ClassVar[int] = 256
    reward_model: nn.Module
    replay_buffer: PhaseReplayBuffer  # type: ignore[assignment]
    backward_buffer: PhaseReplayBuffer

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str | None,
        state_key: str = "observation",
        reward_model_train_freq: int = 10,
        reward_model_gradient_steps: int = 1,
        reward_model_batch_size: int | None = None,
        reward_model_kwargs: dict[str, Any] | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        if replay_buffer_class is not None and not issubclass(replay_buffer_class, PhaseReplayBuffer):
            raise ValueError(
                f"{type(self).__name__} keeps one PhaseReplayBuffer per policy; replay_buffer_class "
                f"{replay_buffer_class.__name__} is not one (HER relabeling is not part of MEDAL/R3L): leave it out"
            )
        self.state_key = state_key
        self.reward_model_train_freq = check_int("reward_model_train_freq", reward_model_train_freq)
        self.reward_model_gradient_steps = check_int("reward_model_gradient_steps", reward_model_gradient_steps)
        self.reward_model_batch_size = check_int(
            "reward_model_batch_size",
            self.default_reward_model_batch_size if reward_model_batch_size is None else reward_model_batch_size,
        )
        self.reward_model_kwargs = dict(reward_model_kwargs or {})
        self._reward_model_timestep: int | None = None
        super().__init__(
            policy,
            env,
            replay_buffer_class=replay_buffer_class or PhaseReplayBuffer,
            _init_setup_model=False,
            **kwargs,
        )
        if _init_setup_model:
            self._setup_model()

    # --- construction -----------------------------------------------------------------------------------------
    def _state_dim(self) -> int:
        if not isinstance(self.observation_space, spaces.Dict) or self.state_key not in self.observation_space.spaces:
            raise ValueError(
                f"{type(self).__name__} needs a Dict observation with the state under state_key={self.state_key!r}; "
                f"got {self.observation_space}"
            )
        return spaces.flatdim(self.observation_space[self.state_key])

    def _make_reward_model(self, state_dim: int) -> nn.Module:
        """The backward policy's reward model (subclasses).

        :param state_dim: size of the flattened state.
        """
        raise NotImplementedError

    def _backward_sampling_view(self, buffer: ReplayBuffer) -> RelabeledRewards:
        """The backward buffer with the rewards relabelled by :meth:`_backward_reward` at sampling time.

        :param buffer: the backward buffer.
        """
        return RelabeledRewards(buffer, self._backward_reward)  # type: ignore[arg-type]

    def _setup_model(self) -> None:
        state_dim = self._state_dim()
        super()._setup_model()
        self.reward_model = self._make_reward_model(state_dim).to(self.device)

    # --- training -----------------------------------------------------------------------------------------------
    def _backward_reward(self, next_observations: dict[str, th.Tensor]) -> th.Tensor:
        """The backward reward of sampled next observations, ``(batch, 1)``; logged.

        :param next_observations: a sampled batch of next observations.
        """
        reward = self._reward_of_states(
            next_observations[self.state_key].reshape(len(next_observations[self.state_key]), -1).float()
        )
        self.logger.record(f"{self.log_prefix}/backward_reward", float(reward.mean()))
        return reward

    def _reward_of_states(self, states: th.Tensor) -> th.Tensor:
        """The reward model's reward (its ``reward`` method) of a batch of flattened states.

        :param states: ``(batch, state_dim)``.
        """
        return self.reward_model.reward(states)  # type: ignore[operator]

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

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """Update the reward model if due, then the forward and backward SAC by the steps each phase took.

        :param gradient_steps: gradient steps of the two SAC learners (shared by phase).
        :param batch_size: minibatch size of the SAC updates.
        """
        self._train_reward_model()
        super().train(gradient_steps, batch_size)

    def _visited_states(self, n: int) -> th.Tensor | None:
        """``n`` next states of rows the backward policy collected (with replacement), or None if there is none.

        :param n: number of states.
        """
        states = self.backward_buffer.sample_visited_states(n, self.state_key, self._rng)
        return None if states is None else as_tensor(states, self.device)

    # --- saving ------------------------------------------------------------------------------------------------
    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "reward_model"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return [*state_dicts, "reward_model", "reward_model.optimizer"], variables

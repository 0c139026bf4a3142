"""MEDAL (Sharma et al. 2022, "A state-distribution matching approach to non-episodic RL"), thesis Ch. 3 baseline.

A forward policy learns the task from the env's reward; a backward policy brings the agent back to the states of the
demonstrations, rewarded by a discriminator between demonstration states and the states it visits
(:class:`~sb3_gcrl.reset_free_baselines.reward_models.Discriminator`). Defaults are those of the official code
(``architsharma97/medal``, ``cfgs/medal.yaml``); the departures are listed in ``docs/reset_free_baselines.md``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.sac.policies import SACPolicy

from sb3_gcrl.common.validation import check_int
from sb3_gcrl.reset_free_baselines.backward_reward import BackwardRewardSAC
from sb3_gcrl.reset_free_baselines.demos import Demonstrations, load_demos
from sb3_gcrl.reset_free_baselines.reward_models import Discriminator, as_tensor


class MEDAL(BackwardRewardSAC):
    """MEDAL: forward SAC on the env's reward, backward SAC rewarded by a demonstration-state discriminator.

    Other arguments: :class:`~sb3_gcrl.reset_free_baselines.BackwardRewardSAC` (the reward model's schedule) and
    :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC` (SB3's SAC arguments). Official defaults: SAC lr
    3e-4, batch 256, tau 0.005, gamma 0.99, one gradient step per env step for the policy that acts; discriminator MLP
    128, lr 3e-4, batch 800, mixup, one step every 10 env steps.

    :param policy: SAC policy (``"MultiInputPolicy"``).
    :param env: goal env wrapped in ``ResetFreeWrapper`` and ``ForwardBackwardWrapper``.
    :param demos: demonstrations: a ``.npz`` path, a task id with shipped demonstrations (e.g.
        ``"GCRL/PointUMazeGoal-v0"``) or a :class:`~sb3_gcrl.reset_free_baselines.Demonstrations`.
    :param demos_to_buffers: put the demonstrations into both replay buffers (the official code does).
    :param reward_model_batch_size: discriminator batch, half demonstration states, half backward states (None:
        the official 800; at least 2).
    :param kwargs: see :class:`~sb3_gcrl.reset_free_baselines.BackwardRewardSAC`.
    """

    log_prefix: ClassVar[str] = "medal"
    _reward_model_loss_name: ClassVar[str] = "discriminator_loss"
    default_reward_model_batch_size: ClassVar[int] = 800
    reward_model: Discriminator

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str,
        demos: str | Path | Demonstrations | None = None,
        demos_to_buffers: bool = True,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        self.demos = demos
        self.demos_to_buffers = demos_to_buffers
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        check_int("reward_model_batch_size (half positives, half negatives)", self.reward_model_batch_size, minimum=2)
        if _init_setup_model:
            self._setup_model()

    @property
    def discriminator(self) -> Discriminator:
        """The discriminator (the reward model)."""
        return self.reward_model

    def _make_reward_model(self, state_dim: int) -> Discriminator:
        return Discriminator(state_dim, **self.reward_model_kwargs)

    def _setup_model(self) -> None:
        if self.demos is None:
            raise ValueError(
                "MEDAL needs demonstrations: demos='<task id>' for a shipped set (see "
                "sb3_gcrl.reset_free_baselines.available_demos()), or a .npz path (scripts/make_demos.py)"
            )
        super()._setup_model()
        if isinstance(self.demos, Demonstrations):
            demos = self.demos
            demos.check_spaces(self.observation_space, self.action_space, "MEDAL's demos")
        else:
            demos = load_demos(self.demos, self.observation_space, self.action_space)
        self._demos = demos
        self._demo_states = demos.states(self.state_key)
        if self.demos_to_buffers:
            self._add_demos_to_buffers(demos)

    def _add_demos_to_buffers(self, demos: Demonstrations) -> None:
        """Add every demonstration transition to the forward and the backward buffer (flagged as demonstrations)."""
        actions = self.policy.scale_action(np.asarray(demos.actions, dtype=np.float32))
        for buffer in (self.replay_buffer, self.backward_buffer):
            for i in range(len(demos)):
                buffer.add_demo(  # type: ignore[union-attr]
                    {k: v[i : i + 1] for k, v in demos.observations.items()},
                    {k: v[i : i + 1] for k, v in demos.next_observations.items()},
                    actions[i : i + 1],
                    demos.rewards[i : i + 1],
                    np.zeros(1, dtype=np.float32),
                    [{}],
                )

    def _reward_model_step(self) -> float | None:
        half = self.reward_model_batch_size // 2
        negatives = self._visited_states(self.reward_model_batch_size - half)
        if negatives is None:
            return None
        positives = self._demo_states[self._rng.integers(0, len(self._demo_states), size=half)]
        return self.reward_model.train_step(as_tensor(positives, self.device), negatives)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_demos", "_demo_states"]

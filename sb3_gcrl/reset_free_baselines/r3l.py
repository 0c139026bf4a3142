"""R3L (Zhu et al. 2020, "The ingredients of real-world robotic reinforcement learning"), thesis Ch. 3 baseline.

As the thesis runs it (Section 3.7.2): MEDAL's forward-backward agent with the backward policy replaced by a
perturbation controller rewarded by Random Network Distillation novelty
(:class:`~sb3_gcrl.reset_free_baselines.reward_models.RND`, DI-engine's defaults). The forward policy learns from the
env's sparse reward (departure: the thesis's R3L learns a VICE-style goal classifier as its forward reward; see
``docs/reset_free_baselines.md``). R3L needs no demonstrations.
"""

from __future__ import annotations

from typing import ClassVar

from sb3_gcrl.reset_free_baselines.backward_reward import BackwardRewardSAC
from sb3_gcrl.reset_free_baselines.reward_models import RND


class R3L(BackwardRewardSAC):
    """R3L: forward SAC on the env's reward, backward (perturbation) SAC rewarded by RND novelty.

    :param policy: SAC policy (``"MultiInputPolicy"``).
    :param env: goal env wrapped in ``ResetFreeWrapper`` and ``ForwardBackwardWrapper``.
    :param reward_model_batch_size: RND predictor batch (None: DI-engine's 64).
    :param kwargs: see :class:`~sb3_gcrl.reset_free_baselines.BackwardRewardSAC`; ``reward_model_kwargs`` go to
        :class:`~sb3_gcrl.reset_free_baselines.reward_models.RND` (``hidden``, ``learning_rate``, ``obs_clip``).
    """

    log_prefix: ClassVar[str] = "r3l"
    _reward_model_loss_name: ClassVar[str] = "rnd_loss"
    default_reward_model_batch_size: ClassVar[int] = 64
    reward_model: RND

    @property
    def rnd(self) -> RND:
        """The RND networks (the reward model)."""
        return self.reward_model

    def _make_reward_model(self, state_dim: int) -> RND:
        return RND(state_dim, **self.reward_model_kwargs)

    def _reward_model_step(self) -> float | None:
        states = self._visited_states(self.reward_model_batch_size)
        return None if states is None else self.reward_model.train_step(states)

"""EMAC, Episodic Memory Actor-Critic (Kuznetsov & Filchenkov, IJCAI 2021): the thesis's Ch. 4 baseline (Fig. 4.3)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import TD3
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer
from torch.nn import functional as F

from sb3_gcrl.common.runs import ClassNamedRunsMixin
from sb3_gcrl.common.saving import ModelFileMixin
from sb3_gcrl.common.transitions import Transition, TransitionHooksMixin
from sb3_gcrl.common.validation import (
    check_bool,
    check_choice,
    check_float,
    check_int,
    check_optional_int,
)
from sb3_gcrl.emac.memory import NEIGHBOUR_WEIGHTINGS, NeighbourWeighting
from sb3_gcrl.emac.policies import EMACPolicy, MultiInputEMACPolicy
from sb3_gcrl.memory.episode import EpisodeRecorder, EpisodeRecordingMixin
from sb3_gcrl.memory.knn import KNN_BACKENDS, KNNBackend


class EMAC(EpisodeRecordingMixin, ModelFileMixin, ClassNamedRunsMixin, TransitionHooksMixin, TD3):
    """Episodic Memory Actor-Critic: DDPG whose critic also regresses onto an episodic memory's Monte-Carlo estimate.

    Critic loss of the paper, for each critic ``Q_i`` (one, as in DDPG, by default)::

        L = (1 - alpha) * MSE(Q_i(s, a), r + gamma * (1 - done) * Q'(s', mu'(s'))) + alpha * MSE(Q_i(s, a), Q_M(s, a))

    ``Q_M(s, a)`` is the memory estimate: the ``k`` nearest rows of a memory of (random projection of (s, a),
    discounted Monte-Carlo return) pairs, weighted by softmin of their distance (authors' code; ``"uniform"``: plain
    mean); see :mod:`sb3_gcrl.emac.memory`. Every finished episode writes each of its steps into the memory, with the
    return discounted by ``gamma``, through the package's episode layer
    (:class:`~sb3_gcrl.memory.episode.EpisodeRecorder`). While the memory is still empty the critic loss is the plain
    TD loss. The actor is DDPG's (maximise ``Q_1(s, mu(s))``); acting and ``predict`` use the actor only.

    Base algorithm: the paper builds EMAC on DDPG (thesis Sec. 4.3: "EMAC combines values from the EM with 1-step TD
    target in DDPG"). SB3's DDPG is TD3 with one critic, no delayed policy update and no target smoothing, so EMAC
    subclasses :class:`~stable_baselines3.TD3` with exactly those defaults (``n_critics=1`` in ``policy_kwargs``,
    ``policy_delay=1``, ``target_noise_clip=0``); setting them back to TD3's gives the memory-augmented TD3.

    Not implemented: the paper's episodic-based replay prioritization (uniform replay here; see ``docs/emac.md``).
    Like SB3's TD3/DDPG, ``action_noise=None`` explores only through ``learning_starts`` random steps; the authors
    add Gaussian noise of std 0.1 (the zoo configs set ``noise_type: normal``, ``noise_std: 0.1``).

    :param policy: ``"MlpPolicy"``, ``"MultiInputPolicy"`` or an :class:`~sb3_gcrl.emac.policies.EMACPolicy` subclass.
    :param env: env with a Box action space, or its id.
    :param alpha: weight of the memory term in the critic loss (paper: 0.1), in [0, 1]; 0 is DDPG.
    :param n_neighbors: ``k`` of the memory estimate (paper: 2).
    :param projection_dim: random-projection dimension of the (state, action) keys (paper: 4; ``None``: raw).
    :param memory_capacity: memory rows (paper: the training budget; first in first out beyond).
    :param neighbour_weighting: ``"softmin"`` or ``"uniform"`` weights of the ``k`` neighbours' returns.
    :param observation_keys: Dict observation keys in the memory key (default: observation, desired_goal).
    :param memory_update_truncated: also write time-limit-truncated episodes into the memory, with the returns of the
        steps that were seen (the authors instead run the policy on past the limit to complete the return; SB3
        cannot step an env past its end). ``False`` writes terminated episodes only.
    :param knn_backend: kNN backend of the memory (see :class:`~sb3_gcrl.memory.KNNIndex`).
    :param learning_starts: random steps before training (authors: 1000).
    :param policy_delay: actor/target update every ``policy_delay`` critic updates (DDPG: 1).
    :param target_policy_noise: std of TD3's target smoothing noise (inactive with ``target_noise_clip=0``).
    :param target_noise_clip: clip of that noise (DDPG: 0, no smoothing).
    :param kwargs: every other :class:`~stable_baselines3.TD3` argument, whose TD3 defaults are the authors' values:
        ``learning_rate`` (Adam, actor and critic: 1e-3, PyTorch's default), ``buffer_size`` (1e6), ``batch_size``
        (256), ``tau`` (0.005), ``gamma`` (0.99: the discount of the TD target and of the memory's returns); and
        ``train_freq``, ``action_noise``, ...
    :raises ValueError: naming the fix, for a non-Box action space, ``alpha`` outside [0, 1], a bad ``k``,
        projection, capacity or weighting, a memory setting given in ``policy_kwargs``, or a HER replay buffer.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": EMACPolicy,
        "MultiInputPolicy": MultiInputEMACPolicy,
    }
    policy: EMACPolicy

    def __init__(
        self,
        policy: str | type[EMACPolicy],
        env: GymEnv | str,
        alpha: float = 0.1,
        n_neighbors: int = 2,
        projection_dim: int | None = 4,
        memory_capacity: int = 1_000_000,
        neighbour_weighting: NeighbourWeighting = "softmin",
        observation_keys: Sequence[str] | None = None,
        memory_update_truncated: bool = True,
        knn_backend: KNNBackend = "auto",
        learning_starts: int = 1000,
        policy_delay: int = 1,
        target_policy_noise: float = 0.1,
        target_noise_clip: float = 0.0,
        **kwargs: Any,
    ) -> None:
        if env is not None:
            env = maybe_make_env(env, 0)
            if not isinstance(env.action_space, spaces.Box):
                raise ValueError(
                    f"EMAC needs a continuous (Box) action space, got {env.action_space}; its critic takes the "
                    "action as input. For discrete actions use sb3_gcrl.TwoMemoryDQN or sb3_gcrl.MFEC"
                )
        self.alpha = check_float("alpha", alpha, 0.0, 1.0)
        self.n_neighbors = check_int("n_neighbors (k)", n_neighbors)
        self.projection_dim = check_optional_int("projection_dim", projection_dim)
        self.memory_capacity = check_int("memory_capacity", memory_capacity)
        self.neighbour_weighting = check_choice("neighbour_weighting", neighbour_weighting, NEIGHBOUR_WEIGHTINGS)
        self.observation_keys = None if observation_keys is None else list(observation_keys)
        self.memory_update_truncated = check_bool("memory_update_truncated", memory_update_truncated)
        self.knn_backend = check_choice("knn_backend", knn_backend, KNN_BACKENDS)
        policy_kwargs = dict(kwargs.pop("policy_kwargs", None) or {})  # never the caller's dict
        for name in ("memory_capacity", "n_neighbors", "projection_dim", "neighbour_weighting", "observation_keys"):
            if name in policy_kwargs:
                raise ValueError(f"pass {name} to EMAC itself, not in policy_kwargs")
        policy_kwargs.setdefault("n_critics", 1)  # DDPG's single critic
        replay_buffer_class = kwargs.get("replay_buffer_class")
        if isinstance(replay_buffer_class, type) and issubclass(replay_buffer_class, HerReplayBuffer):
            raise ValueError(
                "EMAC cannot use a HerReplayBuffer: its memory holds the returns of the goals that were commanded, "
                "so a relabeled sample would be regressed onto the return of another goal; use the default buffer"
            )
        self._episodes = EpisodeRecorder()
        super().__init__(
            policy,
            env,
            learning_starts=learning_starts,
            policy_delay=check_int("policy_delay", policy_delay),
            target_policy_noise=check_float("target_policy_noise", target_policy_noise, minimum=0.0),
            target_noise_clip=check_float("target_noise_clip", target_noise_clip, minimum=0.0),
            policy_kwargs=policy_kwargs,
            **kwargs,
        )

    def _setup_model(self) -> None:
        if not (isinstance(self.policy_class, type) and issubclass(self.policy_class, EMACPolicy)):
            raise ValueError(
                f"EMAC needs an EMACPolicy (aliases {sorted(self.policy_aliases)}), got "
                f"{getattr(self.policy_class, '__name__', self.policy_class)}"
            )
        self.policy_kwargs = {
            "memory_seed": self.seed,  # the projection matrix follows the model's seed (a loaded model keeps its own)
            **self.policy_kwargs,
            "memory_capacity": self.memory_capacity,
            "n_neighbors": self.n_neighbors,
            "projection_dim": self.projection_dim,
            "neighbour_weighting": self.neighbour_weighting,
            "observation_keys": self.observation_keys,
            "knn_backend": self.knn_backend,
        }
        super()._setup_model()

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        result = super()._setup_learn(*args, **kwargs)
        normalize = self._vec_normalize_env
        if normalize is not None and normalize.norm_reward:
            raise ValueError(
                "EMAC's memory stores Monte-Carlo returns of the env's rewards, which VecNormalize(norm_reward=True) "
                "rescales with changing statistics before the critic sees them; use norm_reward=False"
            )
        return result

    def _on_transition(self, transition: Transition) -> None:
        """Record the step into the running episodes; a finished episode's returns go into the memory.

        :param transition: the step of every training env.
        """
        # keys from what the critic is trained on: the observation the action was taken in and the action scaled
        # to [-1, 1]
        keys = self.policy.memory_keys(transition.observations, transition.actions)
        actions, rewards, dones, infos = transition.actions, transition.rewards, transition.dones, transition.infos
        for episode in self._episodes.record(keys, actions, rewards, dones, infos):
            if episode.updates_memory(self.memory_update_truncated):
                self.policy.memory.add_episode(episode.keys, episode.returns(self.gamma))

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """TD3's training step (SB3) with EMAC's critic loss.

        :param gradient_steps: gradient steps.
        :param batch_size: minibatch size.
        """
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])

        actor_losses, critic_losses, td_losses, memory_losses, memory_values = [], [], [], [], []
        for _ in range(gradient_steps):
            self._n_updates += 1
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma

            with th.no_grad():
                noise = replay_data.actions.clone().data.normal_(0, self.target_policy_noise)
                noise = noise.clamp(-self.target_noise_clip, self.target_noise_clip)
                next_actions = (self.actor_target(replay_data.next_observations) + noise).clamp(-1, 1)
                next_q_values = th.cat(self.critic_target(replay_data.next_observations, next_actions), dim=1)
                next_q_values, _ = th.min(next_q_values, dim=1, keepdim=True)
                target_q_values = replay_data.rewards + (1 - replay_data.dones) * discounts * next_q_values
            memory_q_values = self.policy.memory_estimate(replay_data.observations, replay_data.actions)

            current_q_values = self.critic(replay_data.observations, replay_data.actions)
            critic_loss = self.critic_loss(current_q_values, target_q_values, memory_q_values)
            critic_losses.append(critic_loss.item())
            with th.no_grad():  # the two terms, logged separately
                td_losses.append(sum(F.mse_loss(q, target_q_values).item() for q in current_q_values))
                if memory_q_values is not None:
                    memory_losses.append(sum(F.mse_loss(q, memory_q_values).item() for q in current_q_values))
                    memory_values.append(memory_q_values.mean().item())

            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()

            if self._n_updates % self.policy_delay == 0:
                actor_loss = -self.critic.q1_forward(
                    replay_data.observations, self.actor(replay_data.observations)
                ).mean()
                actor_losses.append(actor_loss.item())
                self.actor.optimizer.zero_grad()
                actor_loss.backward()
                self.actor.optimizer.step()

                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                polyak_update(self.actor.parameters(), self.actor_target.parameters(), self.tau)
                polyak_update(self.critic_batch_norm_stats, self.critic_batch_norm_stats_target, 1.0)
                polyak_update(self.actor_batch_norm_stats, self.actor_batch_norm_stats_target, 1.0)

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if actor_losses:
            self.logger.record("train/actor_loss", np.mean(actor_losses))
        self.logger.record("train/critic_loss", np.mean(critic_losses))
        self.logger.record("train/critic_td_loss", np.mean(td_losses))
        if memory_losses:
            self.logger.record("train/critic_memory_loss", np.mean(memory_losses))
            self.logger.record("train/memory_q_mean", np.mean(memory_values))
        self.logger.record("memory/size", len(self.policy.memory))

    def critic_loss(
        self,
        current_q_values: Sequence[th.Tensor],
        target_q_values: th.Tensor,
        memory_q_values: th.Tensor | None,
    ) -> th.Tensor:
        """EMAC's critic objective, summed over the critics as SB3's TD3 does:
        ``sum_i (1 - alpha) * MSE(Q_i, y) + alpha * MSE(Q_i, Q_M)``; the plain TD loss ``sum_i MSE(Q_i, y)`` while
        the memory is empty (``memory_q_values is None``).

        :param current_q_values: ``(n, 1)`` estimates of each critic.
        :param target_q_values: ``(n, 1)`` TD targets ``y = r + gamma * (1 - done) * min_i Q'_i(s', mu'(s'))``.
        :param memory_q_values: ``(n, 1)`` memory estimates ``Q_M(s, a)``, or ``None``.
        :return: the scalar loss.
        """
        if memory_q_values is None:
            loss = sum(F.mse_loss(q, target_q_values) for q in current_q_values)
        else:
            loss = sum(
                (1.0 - self.alpha) * F.mse_loss(q, target_q_values) + self.alpha * F.mse_loss(q, memory_q_values)
                for q in current_q_values
            )
        assert isinstance(loss, th.Tensor)
        return loss

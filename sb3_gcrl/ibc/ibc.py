"""IBC, Implicit and Bidirectional Curriculum (J. Kim et al., ICML 2023): the reset-free baseline of thesis Ch. 3.

Two goal-conditioned SAC agents (the authors' base learner), each with its own replay buffer (HER in the configs, as
the authors' ``use_forward_her``/``use_backward_her``):

* the **forward** agent is this SAC itself (``self.policy``): it runs the ``forward`` and ``auxiliary`` segments, and
  it is what :meth:`~stable_baselines3.SAC.predict` and evaluation use (episodic, on rho_g*);
* the **backward** agent (:attr:`IBC.backward`, an SB3 ``SAC``) runs the ``back`` segments, toward the backward
  curriculum goals.

Which segment runs, and toward which goal, is decided by the env: :func:`~sb3_gcrl.ibc.ibc_go_explore` wraps it in the
package's :class:`~sb3_gcrl.wrappers.GoExploreWrapper` (switched to reset-free mode by
:class:`~sb3_gcrl.callbacks.ResetFreeCallback`) with an :class:`~sb3_gcrl.ibc.IBCCurriculumScheduler`, which this
algorithm attaches to at the start of ``learn`` so that the curriculum reads the forward agent's values. The kind of
the current segment (the wrapper's ``goal_kind``) picks the acting agent and the buffer of each transition. On an env
without that wrapper every step is a forward step (plain goal-conditioned SAC).
"""

from __future__ import annotations

import io
import pathlib
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.save_util import load_from_pkl, save_to_pkl
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer
from stable_baselines3.sac.policies import SACPolicy

from sb3_gcrl.ibc.curriculum import BACK, FORWARD_KINDS, IBCCurriculumScheduler, find_ibc_scheduler
from sb3_gcrl.reset_free_baselines.forward_backward import _PrefixedLogger  # the backward agent's train/* as backward/*

SelfIBC = TypeVar("SelfIBC", bound="IBC")


def _has_samples(buffer: ReplayBuffer) -> bool:
    """Whether ``buffer`` can be sampled (a HER buffer needs one finished episode)."""
    if isinstance(buffer, HerReplayBuffer):
        return bool(np.any(buffer.ep_length > 0))
    return buffer.size() > 0


class IBC(SAC):
    """IBC: forward and backward goal-conditioned SAC agents with IBC's curriculum (reset-free, thesis Ch. 3 baseline).

    Every SAC argument applies to both agents (the authors use the same settings for both). Defaults follow SB3's SAC;
    the authors' values (learning rate 1e-4, batch 512, tau 0.01, initial temperature 0.5, 3 x 512 networks, HER
    ``future`` with 4 sampled goals) are in the ``ibc_<task>.yml`` configs.

    :param policy: policy class or alias (``"MultiInputPolicy"``: goal observations are Dicts).
    :param env: goal env, normally wrapped by :func:`~sb3_gcrl.ibc.ibc_go_explore` (one env: the phase of the
        segment picks the agent and the buffer for the whole VecEnv).
    :param learning_rate: see :class:`~stable_baselines3.SAC` (this and the other SAC arguments apply to both agents).
    :param buffer_size: rows of each agent's replay buffer.
    :param learning_starts: random-action warm-up steps (both phases); no update before.
    :param batch_size: minibatch size of each update.
    :param tau: soft target-update coefficient.
    :param gamma: discount (also the curriculum's, official 0.99).
    :param train_freq: env steps between two updates of the agent that acted.
    :param gradient_steps: gradient steps per update.
    :param action_noise: extra action noise (none in the official code).
    :param replay_buffer_class: buffer class of both agents (the configs: SB3's ``HerReplayBuffer``).
    :param replay_buffer_kwargs: its keyword arguments.
    :param ent_coef: SAC's entropy coefficient (official: learned, from 0.5: ``"auto_0.5"``).
    :param target_update_interval: gradient steps between target-network updates (official: 2).
    :param target_entropy: SAC's target entropy (official: -dim(A), SB3's ``"auto"``).
    :param stats_window_size: episodes (segments) in the rollout statistics.
    :param tensorboard_log: tensorboard folder.
    :param policy_kwargs: keyword arguments of both agents' policies.
    :param verbose: verbosity.
    :param seed: random seed.
    :param device: torch device.
    :param value_samples: policy actions averaged in the curriculum's value V(s -> g) = E_a min(Q1, Q2)(s, g, a)
        (official: 10).
    :param _init_setup_model: build the networks at construction (SB3's load passes False).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = SAC.policy_aliases  # type: ignore[assignment]
    backward: SAC

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str | None,
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
        value_samples: int = 10,
        _init_setup_model: bool = True,
    ) -> None:
        if int(value_samples) != value_samples or value_samples < 1:
            raise ValueError(f"value_samples must be an integer >= 1, got {value_samples}")
        self.value_samples = int(value_samples)
        self._acting = FORWARD_KINDS[0]
        #: env steps taken by each agent
        self.agent_steps = {"forward": 0, "backward": 0}
        super().__init__(
            policy,
            env,  # type: ignore[arg-type]
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=action_noise,
            replay_buffer_class=replay_buffer_class,
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
            _init_setup_model=_init_setup_model,
        )
        if self.env is not None:
            self._check_env(self.env)

    # --- set-up ---------------------------------------------------------------------------------------------------
    def _check_env(self, env: VecEnv) -> None:
        if not isinstance(self.observation_space, spaces.Dict) or "desired_goal" not in self.observation_space.spaces:
            raise TypeError("IBC trains goal-conditioned agents: the env must have a Dict goal observation")
        if self.action_space is not None and not isinstance(self.action_space, spaces.Box):
            raise TypeError("IBC's agents are SAC: Box actions only")
        schedulers = env.get_attr("scheduler") if env.num_envs > 1 and env.has_attr("scheduler") else []
        if any(isinstance(s, IBCCurriculumScheduler) for s in schedulers):
            raise ValueError(
                "IBC routes each segment to the forward or the backward agent for the whole VecEnv: train on one "
                "env wrapped in ibc_go_explore (n_envs=1)"
            )

    def _setup_model(self) -> None:
        super()._setup_model()
        # the backward agent: the same SAC settings (read from this model, so that load-time overrides reach both)
        self.backward = SAC(
            self.policy_class,
            None,  # type: ignore[arg-type]
            learning_rate=self.learning_rate,
            buffer_size=self.buffer_size,
            learning_starts=0,  # the warm-up is this model's (it draws the random actions of both phases)
            batch_size=self.batch_size,
            tau=self.tau,
            gamma=self.gamma,
            gradient_steps=self.gradient_steps,
            ent_coef=self.ent_coef,
            target_update_interval=self.target_update_interval,
            target_entropy=self.target_entropy,  # resolved from the action space (the backward agent has no env)
            policy_kwargs=self.policy_kwargs,
            device=self.device,
            _init_setup_model=False,
        )
        self.backward.observation_space = self.observation_space
        self.backward.action_space = self.action_space
        self.backward.n_envs = self.n_envs
        self.backward.env = self.env
        self.backward.replay_buffer_class = self.replay_buffer_class
        self.backward.replay_buffer_kwargs = dict(self.replay_buffer_kwargs)
        self.backward._setup_model()

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "backward"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        back_dicts, back_variables = self.backward._get_torch_save_params()
        return (
            [*state_dicts, *(f"backward.{name}" for name in back_dicts)],
            [*variables, *(f"backward.{name}" for name in back_variables)],
        )

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        super().set_env(env, force_reset)
        assert self.env is not None
        self._check_env(self.env)
        self.backward.env = self.env
        self.backward.n_envs = self.n_envs
        if isinstance(self.backward.replay_buffer, HerReplayBuffer) and self.backward.replay_buffer.env is None:
            self.backward.replay_buffer.set_env(self.env)

    def save_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase) -> None:
        """Save both agents' replay buffers (forward and backward) in one pickle file.

        :param path: file path or file object.
        """
        save_to_pkl(path, {"forward": self.replay_buffer, "backward": self.backward.replay_buffer}, self.verbose)

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True) -> None:
        """Load both replay buffers saved by :meth:`save_replay_buffer` (HER buffers get the model's env).

        :param path: file path or file object.
        :param truncate_last_traj: end the last, unfinished HER episode of each buffer (see SB3's ``HerReplayBuffer``).
        """
        buffers = load_from_pkl(path, self.verbose)
        if not (
            isinstance(buffers, dict)
            and set(buffers) == {"forward", "backward"}
            and all(isinstance(b, ReplayBuffer) for b in buffers.values())
        ):
            raise ValueError(f"{path} does not hold the forward and backward buffers of IBC.save_replay_buffer")
        for agent, buffer in ((self, buffers["forward"]), (self.backward, buffers["backward"])):
            if isinstance(buffer, HerReplayBuffer):
                if self.env is None:
                    raise ValueError("HER replay buffers need the env: load the model with env=... first")
                buffer.set_env(self.env)
                if truncate_last_traj:
                    buffer.truncate_last_trajectory()
            buffer.device = self.device
            agent.replay_buffer = buffer

    # --- phases ----------------------------------------------------------------------------------------------------
    def _schedulers(self) -> list[IBCCurriculumScheduler]:
        env = self.env
        if env is None:
            return []
        base = env.unwrapped if isinstance(env, VecEnvWrapper) else env
        if isinstance(base, DummyVecEnv):
            found = [find_ibc_scheduler(e) for e in base.envs]
            return [s for s in found if s is not None]
        return []

    def _segment_kind(self) -> str:
        """Kind of the segment the (single) env is in: ``forward``/``auxiliary`` (forward agent) or ``back``."""
        assert self.env is not None
        if not self.env.has_attr("goal_kind") or not self.env.has_attr("training"):
            return FORWARD_KINDS[0]
        kinds = [
            k if t else FORWARD_KINDS[0] for k, t in zip(self.env.get_attr("goal_kind"), self.env.get_attr("training"))
        ]
        return BACK if BACK in kinds else kinds[0]

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        out = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        self.backward.set_logger(_PrefixedLogger(self.logger, "backward"))  # type: ignore[arg-type]
        for scheduler in self._schedulers():
            scheduler.attach(self)
        return out

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        self._acting = self._segment_kind()
        if self._acting != BACK:
            self.agent_steps["forward"] += n_envs
            return super()._sample_action(learning_starts, action_noise, n_envs)
        self.agent_steps["backward"] += n_envs
        if self.num_timesteps < learning_starts:  # the random warm-up actions are shared
            return super()._sample_action(learning_starts, action_noise, n_envs)
        self.backward._last_obs = self._last_obs
        return self.backward._sample_action(0, action_noise, n_envs)

    def _store_transition(self, replay_buffer: ReplayBuffer, *args: Any, **kwargs: Any) -> None:
        buffer = self.backward.replay_buffer if self._acting == BACK else replay_buffer
        super()._store_transition(buffer, *args, **kwargs)  # type: ignore[arg-type]

    # --- training --------------------------------------------------------------------------------------------------
    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """Update the agent that acted last (official: only the acting agent updates), once it has data."""
        assert self.replay_buffer is not None and self.backward.replay_buffer is not None
        if self._acting != BACK:
            if _has_samples(self.replay_buffer):
                super().train(gradient_steps, batch_size)
        elif _has_samples(self.backward.replay_buffer):
            self.backward._current_progress_remaining = self._current_progress_remaining
            self.backward.train(gradient_steps, batch_size)

    def curriculum_values(self, observations: dict[str, np.ndarray]) -> np.ndarray:
        """The forward agent's V(s -> g) = mean over ``value_samples`` actions a ~ pi(s, g) of min(Q1, Q2)(s, g, a).

        :param observations: a batch of goal observations (the env's, unnormalised).
        :return: shape ``(n,)``.
        """
        obs_tensor, _ = self.policy.obs_to_tensor(observations)
        with th.no_grad():
            n = int(next(iter(obs_tensor.values())).shape[0])  # type: ignore[union-attr]
            tiled = {k: v.repeat(self.value_samples, *([1] * (v.dim() - 1))) for k, v in obs_tensor.items()}  # type: ignore[union-attr]
            actions, _ = self.actor.action_log_prob(tiled)
            q_values = th.min(th.cat(self.critic(tiled, actions), dim=1), dim=1).values
            return q_values.view(self.value_samples, n).mean(dim=0).cpu().numpy()

    # --- logging ---------------------------------------------------------------------------------------------------
    def dump_logs(self) -> None:
        self.record_ibc_logs()
        super().dump_logs()

    def record_ibc_logs(self) -> None:
        """Record the phase shares and the curriculum state (``ibc/`` keys) in the logger."""
        total = max(sum(self.agent_steps.values()), 1)
        self.logger.record("ibc/forward_step_share", self.agent_steps["forward"] / total)
        self.logger.record("ibc/backward_step_share", self.agent_steps["backward"] / total)
        schedulers = self._schedulers()
        if not schedulers:
            return
        counts: dict[str, int] = {}
        for scheduler in schedulers:
            for kind, count in scheduler.segment_counts.items():
                counts[kind] = counts.get(kind, 0) + count
        n_segments = max(sum(counts.values()), 1)
        for kind, count in counts.items():
            self.logger.record(f"ibc/{kind}_segment_share", count / n_segments)
        scheduler = schedulers[0]
        self.logger.record("ibc/curriculum_updates", scheduler.n_updates)
        self.logger.record("ibc/curriculum_trajectories", len(scheduler.trajectories))
        if scheduler.n_updates:
            self.logger.record("ibc/curriculum_goal_cost", scheduler.last_cost)
            self.logger.record("ibc/curriculum_goal_distance_to_task", scheduler.last_target_distance)
        if scheduler.forward_pool is not None:
            mean = scheduler.forward_pool.mean(axis=0)
            for i, value in enumerate(mean[:8]):
                self.logger.record(f"ibc/curriculum_goal_mean_{i}", float(value))

    def learn(  # type: ignore[override]
        self: SelfIBC,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "IBC",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfIBC:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

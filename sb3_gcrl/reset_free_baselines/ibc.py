"""IBC, Implicit and Bidirectional Curriculum (J. Kim et al., ICML 2023): the reset-free baseline of thesis Ch. 3.

Two goal-conditioned SAC agents (the authors' base learner), each with its own replay buffer (HER in the configs, as
the authors' ``use_forward_her``/``use_backward_her``), on the package's forward-backward mechanism
(:class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC`, shared with MEDAL and R3L):

* the **forward** agent is this SAC itself (``self.policy``): it runs the ``forward`` and ``auxiliary`` segments, and
  it is what :meth:`~stable_baselines3.SAC.predict` and evaluation use (episodic, on rho_g*);
* the **backward** agent (:attr:`IBC.backward`, an SB3 ``SAC``) runs the ``back`` segments, toward the backward
  curriculum goals.

Which segment runs, and toward which goal, is decided by the env:
:func:`~sb3_gcrl.reset_free_baselines.ibc_go_explore` wraps it in the package's
:class:`~sb3_gcrl.wrappers.GoExploreWrapper` (switched to reset-free mode by
:class:`~sb3_gcrl.callbacks.ResetFreeCallback`) with an
:class:`~sb3_gcrl.reset_free_baselines.IBCCurriculumScheduler`, which this algorithm attaches to at the start of
``learn`` so that the curriculum reads the forward agent's values (in the training process: a ``DummyVecEnv``).
The kind of the current segment (the wrapper's ``goal_kind``) picks the acting agent and the buffer of each
transition. On an env without that wrapper every step is a forward step (plain goal-conditioned SAC).
"""

from __future__ import annotations

import warnings
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper
from stable_baselines3.sac.policies import MultiInputPolicy, SACPolicy

from sb3_gcrl.reset_free_baselines.forward_backward import ForwardBackwardSAC
from sb3_gcrl.reset_free_baselines.ibc_curriculum import BACK, IBCCurriculumScheduler, find_ibc_scheduler


class IBC(ForwardBackwardSAC):
    """IBC: forward and backward goal-conditioned SAC agents with IBC's curriculum (reset-free, thesis Ch. 3 baseline).

    The two agents, their buffers, the phase routing of actions and transitions, the shared updates and save/load are
    those of :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC`; the phase is the kind of the curriculum
    segment (``back``: the backward agent). Every SAC argument applies to
    both agents (the authors use the same settings for both). Defaults follow SB3's SAC; the authors' values (learning
    rate 1e-4, batch 512, tau 0.01, target update every 2 steps, initial temperature 0.5 (``ent_coef="auto_0.5"``),
    3 x 512 networks, HER ``future`` with 4 sampled goals (``replay_buffer_class=HerReplayBuffer``) on both agents)
    are in ``zoo_configs/ibc_thesis.yml`` (``zoo_configs/ibc.yml``: the CPU presets). Only the agent that acted is
    updated (official), one gradient step per env step with ``train_freq=1``.

    :param policy: policy class or alias (``"MultiInputPolicy"``: goal observations are Dicts).
    :param env: goal env, normally wrapped by :func:`~sb3_gcrl.reset_free_baselines.ibc_go_explore` (one env in a
        ``DummyVecEnv``: the phase of the segment picks the agent and the buffer for the whole VecEnv).
    :param value_samples: policy actions averaged in the curriculum's value V(s -> g) = E_a min(Q1, Q2)(s, g, a)
        (official: 10).
    :param _init_setup_model: build the networks at construction (SB3's load passes False).
    :param kwargs: SB3's SAC arguments, see :class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC` (``gamma`` is
        also the curriculum's, official 0.99; ``replay_buffer_class`` is both agents' buffer class).
    """

    log_prefix: ClassVar[str] = "ibc"
    #: SB3's SAC aliases for the observations supported: Dict goal observations only
    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MultiInputPolicy": MultiInputPolicy}

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str | None,
        value_samples: int = 10,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        if int(value_samples) != value_samples or value_samples < 1:
            raise ValueError(f"value_samples must be an integer >= 1, got {value_samples}")
        self.value_samples = int(value_samples)
        super().__init__(policy, env, _init_setup_model=_init_setup_model, **kwargs)

    @property
    def agent_steps(self) -> dict[str, int]:
        """Env steps taken by each agent (``forward``, ``backward``)."""
        return {"forward": int(self.phase_steps[0]), "backward": int(self.phase_steps[1])}

    # --- phases ----------------------------------------------------------------------------------------------------
    def _check_phase_env(self, env: VecEnv) -> None:
        """Goal observations and Box actions; one env when IBC's curriculum commands the segments.

        :param env: the training env.
        """
        if not isinstance(self.observation_space, spaces.Dict) or "desired_goal" not in self.observation_space.spaces:
            raise TypeError("IBC trains goal-conditioned agents: the env must have a Dict goal observation")
        if self.action_space is not None and not isinstance(self.action_space, spaces.Box):
            raise TypeError("IBC's agents are SAC: Box actions only")
        # whether the env commands IBC's segments (looked up once here, not at every step)
        self._commands_segments = env.has_attr("goal_kind") and env.has_attr("training")
        if not self._commands_segments:
            warnings.warn(
                "IBC: the training env is not wrapped in sb3_gcrl.reset_free_baselines.ibc_go_explore, so every step "
                "is the forward agent's and IBC trains as plain goal-conditioned SAC (no backward agent, no "
                "curriculum); wrap the env with ibc_go_explore (the env_wrapper of the shipped ibc.yml)",
                stacklevel=3,
            )
        base = env.unwrapped if isinstance(env, VecEnvWrapper) else env
        if self._commands_segments and not isinstance(base, DummyVecEnv):
            raise TypeError(
                "IBC's curriculum (ibc_go_explore) reads the forward agent's critic, which it reaches only in the "
                f"training process, not inside a {type(base).__name__}: train on a DummyVecEnv (the default of "
                "make_vec_env, RL-Zoo's --vec-env dummy)"
            )
        schedulers = env.get_attr("scheduler") if env.num_envs > 1 and env.has_attr("scheduler") else []
        if any(isinstance(s, IBCCurriculumScheduler) for s in schedulers):
            raise ValueError(
                "IBC routes each segment to the forward or the backward agent for the whole VecEnv: train on one "
                "env wrapped in ibc_go_explore (n_envs=1)"
            )

    def _backward_phases(self) -> np.ndarray:
        """Per env, whether it is in a ``back`` segment (training mode; every step is forward without the wrapper).

        :return: bool array of shape ``(n_envs,)``.
        """
        assert self.env is not None
        if not self._commands_segments:
            return np.zeros(self.env.num_envs, dtype=bool)
        kinds, training = self.env.get_attr("goal_kind"), self.env.get_attr("training")
        return np.array([kind == BACK and t for kind, t in zip(kinds, training)], dtype=bool)

    # --- curriculum ------------------------------------------------------------------------------------------------
    def _schedulers(self) -> list[IBCCurriculumScheduler]:
        """The curriculum schedulers of the training envs (in this process: :meth:`_check_phase_env` refuses other
        VecEnvs)."""
        env = self.env
        if env is None:
            return []
        base = env.unwrapped if isinstance(env, VecEnvWrapper) else env
        if isinstance(base, DummyVecEnv):
            found = [find_ibc_scheduler(e) for e in base.envs]
            return [s for s in found if s is not None]
        return []

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        out = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        for scheduler in self._schedulers():
            scheduler.attach(self)
        return out

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
        """Record the curriculum state, then the phase shares and SB3's logs (all ``ibc/`` keys)."""
        self.record_ibc_logs()
        super().dump_logs()

    def record_ibc_logs(self) -> None:
        """Record the curriculum state (``ibc/`` keys) in the logger; the phase shares come with ``dump_logs``."""
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

"""The learn loop of the model-based MoReFree agent: the Go/Explore wrapper's protocol and data collection.

:class:`MoReFreeCollector` is the base class of :class:`~sb3_gcrl.morefree.MoReFree` (as SB3's
``OffPolicyAlgorithm`` is SAC's). Through the wrapper's public interface (``VecEnv.get_attr`` / ``env_method``, so
any VecEnv works, ``SubprocVecEnv`` included) it declares the agent as the goal planner of the envs that take
planned goals, reads alpha and the Go-phase length H_G, tells per env whether pi_G (Go phase) or pi_E (Explore
phase) acts, and answers the envs' goal requests with PEG's planner (:mod:`~sb3_gcrl.morefree.peg`). Data
collection filters each env's latent across its continuous stream, acts, and appends the executed actions to the
sequence replay, restarting a stream only at a physical reset; every ``train_ratio`` env steps the agent's
``train`` runs one training step.
"""

from __future__ import annotations

import sys
import time
from abc import abstractmethod
from typing import Any, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.utils import safe_mean
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

from sb3_gcrl.common.runs import warn_if_learning_never_starts
from sb3_gcrl.common.saving import atomic_save_to_pkl
from sb3_gcrl.goals.task_goals import TaskRelevantGoals
from sb3_gcrl.morefree.buffer import SequenceReplayBuffer
from sb3_gcrl.morefree.networks import LatentState
from sb3_gcrl.morefree.peg import goal_box, plan_goal
from sb3_gcrl.morefree.policies import MoReFreePolicy, state_vector
from sb3_gcrl.wrappers.go_explore import ACTING_GOAL, GOAL_REQUEST_KEY

SelfCollector = TypeVar("SelfCollector", bound="MoReFreeCollector")

#: thesis Sec. 3.7.3: alpha = 0.2 for all tasks
DEFAULT_ALPHA = 0.2


class MoReFreeCollector(BaseAlgorithm):
    """The learn loop of :class:`~sb3_gcrl.morefree.MoReFree` (its base class, as SB3's ``OffPolicyAlgorithm`` is
    SAC's): the Go/Explore wrapper's protocol, data collection into the sequence replay, the replay's file and the
    logs. It holds no settings of its own: it reads the agent's (documented there)."""

    policy: MoReFreePolicy
    replay_buffer: SequenceReplayBuffer
    learning_starts: int
    batch_length: int
    train_ratio: int
    n_threads: int | None
    imagination_alpha: float | None
    imagination_horizon: int
    gamma: float
    lambda_: float
    expl_reward_scale: float
    peg_samples: int
    peg_iterations: int
    peg_elite_fraction: float
    peg_horizon: int | None
    _rng: np.random.Generator
    #: the latent state of each env's stream, the action executed before it, the observations the streams continue
    _latent: LatentState | None
    _prev_action: th.Tensor | None
    _stream_obs: Any
    _task_goals: TaskRelevantGoals | None
    #: envs whose goal requests the agent answers (set during learn), whether the envs report acting_policy
    _planned_envs: list[int]
    _reads_acting_policy: bool
    _go_steps: int | None
    _alpha: float

    @abstractmethod
    def train(self) -> None:
        """One training step (the agent's)."""

    # --- learn ----------------------------------------------------------------------------------------------------
    def dump_logs(self) -> None:
        """Write the log data (SB3's public hook): episodes, returns, success, speed, the counters of the goal hooks."""
        time_elapsed = max((time.time_ns() - self.start_time) / 1e9, sys.float_info.epsilon)
        fps = int((self.num_timesteps - self._num_timesteps_at_start) / time_elapsed)
        self.logger.record("time/episodes", self._episode_num, exclude="tensorboard")
        if len(self.ep_info_buffer) > 0 and len(self.ep_info_buffer[0]) > 0:
            self.logger.record("rollout/ep_rew_mean", safe_mean([ep["r"] for ep in self.ep_info_buffer]))
            self.logger.record("rollout/ep_len_mean", safe_mean([ep["l"] for ep in self.ep_info_buffer]))
        if len(self.ep_success_buffer) > 0:
            self.logger.record("rollout/success_rate", safe_mean(self.ep_success_buffer))
        self.logger.record("time/fps", fps)
        self.logger.record("time/time_elapsed", int(time_elapsed), exclude="tensorboard")
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        if self._planned_envs and self.env is not None:
            counts = self.env.get_attr("planned_goal_counts", indices=self._planned_envs)
            self.logger.record("morefree/peg_goals_planned", sum(c["planned"] for c in counts))
            self.logger.record("morefree/peg_goals_fallback", sum(c["fallback"] for c in counts))
        self.logger.dump(step=self.num_timesteps)

    def learn(
        self: SelfCollector,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "MoReFree",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfCollector:
        """SB3's ``learn``: collect ``train_ratio`` env steps, then one training step, until ``total_timesteps``.

        :param total_timesteps: env steps (all envs together).
        :param callback: SB3 callbacks.
        :param log_interval: dump the logs every ``log_interval`` finished episodes.
        :param tb_log_name: tensorboard run name.
        :param reset_num_timesteps: start the step count again (False: continue a run).
        :param progress_bar: show a progress bar.
        :return: the trained agent.
        """
        warn_if_learning_never_starts(self, total_timesteps, reset_num_timesteps)
        total_timesteps, callback = self._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        callback.on_training_start(locals(), globals())
        threads = th.get_num_threads()
        if self.n_threads is not None:
            th.set_num_threads(self.n_threads)
        self._attach()
        if self._last_obs is not self._stream_obs or self._latent is None:
            self._start_streams()
        try:
            while self.num_timesteps < total_timesteps:
                remaining = -(-(total_timesteps - self.num_timesteps) // self.n_envs)
                if not self.collect_rollouts(callback, min(self.train_ratio, remaining), log_interval):
                    break
                if self.num_timesteps > self.learning_starts and self.replay_buffer.can_sample(self.batch_length):
                    self.train()
        finally:
            self._detach()
            th.set_num_threads(threads)
        self.dump_logs()
        callback.on_training_end()
        return self

    def save_replay_buffer(self, path: str) -> None:
        """Pickle the sequence replay buffer, atomically (a trusted file only can be loaded back)."""
        atomic_save_to_pkl(path, self.replay_buffer, self.verbose)

    def load_replay_buffer(self, path: str, truncate_last_traj: bool = True) -> None:
        """Load a buffer saved by :meth:`save_replay_buffer` (pickle: load trusted files only).

        :param path: the pickled buffer.
        :param truncate_last_traj: SB3's signature (RL-Zoo passes it); nothing to truncate here: the next ``learn``
            starts a new stream (``is_first``), so the trajectory cut off by the save is never continued.
        """
        from stable_baselines3.common.save_util import load_from_pkl

        buffer = load_from_pkl(path, self.verbose)
        if not isinstance(buffer, SequenceReplayBuffer) or buffer.n_envs != self.n_envs:
            raise ValueError(f"{path} does not hold a SequenceReplayBuffer for {self.n_envs} env(s)")
        self.replay_buffer = buffer

    # --- the Go/Explore wrapper's public interface ------------------------------------------------------------
    def _base_vec_env(self) -> VecEnv:
        """The training VecEnv under its VecEnv wrappers (it holds the reset infos)."""
        env = self.env
        assert env is not None
        return env.unwrapped if isinstance(env, VecEnvWrapper) else env  # type: ignore[return-value]

    def _attach(self) -> None:
        """Declare the agent as the goal planner of the envs that take planned goals; read alpha and H_G; set up
        task goals."""
        env = self.env
        assert env is not None
        self._reads_acting_policy = env.has_attr("acting_policy")
        self._planned_envs = []
        if env.has_attr("takes_planned_goals"):
            self._planned_envs = [i for i, takes in enumerate(env.get_attr("takes_planned_goals")) if takes]
        if self._planned_envs:
            env.env_method("set_goal_planning", True, indices=self._planned_envs)
        if self.imagination_alpha is None:
            alpha = env.get_attr("task_goal_alpha")[0] if env.has_attr("task_goal_alpha") else None
            self._alpha = DEFAULT_ALPHA if alpha is None else float(alpha)
        self._go_steps = int(env.get_attr("go_steps")[0]) if env.has_attr("go_steps") else None
        if not env.has_attr("sample_task_goals") and self._task_goals is None:
            base = self._base_vec_env()
            source = base.envs[0] if isinstance(base, DummyVecEnv) else env
            self._task_goals = TaskRelevantGoals(source, self.policy.goal_dim)  # type: ignore[arg-type]

    def _detach(self) -> None:
        """Stop answering goal requests (the envs take their fallback goals until the next ``learn``)."""
        if self._planned_envs and self.env is not None:
            self.env.env_method("set_goal_planning", False, indices=self._planned_envs)

    def _phases(self) -> list[str]:
        """Per env, ``"explore"`` where the next step is an Explore-phase step (pi_E acts), else ``"go"``."""
        assert self.env is not None
        if not self._reads_acting_policy:
            return ["go"] * self.n_envs
        return ["go" if acting == ACTING_GOAL else "explore" for acting in self.env.get_attr("acting_policy")]

    def task_goal_samples(self, kind: str, n: int, rng: np.random.Generator | None = None) -> np.ndarray:
        """Task-relevant goals: ``n`` draws of rho_0 (``kind="initial"``) or rho_g* (``"evaluation"``), from the env's
        Back-and-Forth scheduler where it states them, else from the goals learned from the env's resets.

        :param kind: ``"initial"`` or ``"evaluation"``.
        :param n: number of goals.
        :param rng: the generator of goals learned from resets (``None``: the agent's own).
        :return: goals ``(n, goal_dim)``.
        """
        assert self.env is not None
        if self._task_goals is None:
            return np.asarray(self.env.env_method("sample_task_goals", kind, n, indices=[0])[0], dtype=np.float32)
        rng = self._rng if rng is None else rng
        return self._task_goals.sample(kind, rng, n).astype(np.float32)  # type: ignore[arg-type]

    def plan_exploratory_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray | None:
        """PEG's exploratory goal (Hu et al., 2023; :func:`~sb3_gcrl.morefree.peg.plan_goal`): the cross-entropy
        search over goal space (the ``desired_goal`` box, :func:`~sb3_gcrl.morefree.peg.goal_box`) for the goal whose
        imagined pi_G path, ``peg_horizon`` steps from the env's current latent, is worth most to the explorer.

        :param obs: the env's current observation (one env).
        :param rng: the scheduler's generator (candidate draws).
        :return: the goal, or None before training starts.
        """
        if self.num_timesteps < self.learning_starts or self.replay_buffer.size() == 0:
            return None
        box = goal_box(self.observation_space["desired_goal"], self.replay_buffer)  # type: ignore[index]
        horizon = self.peg_horizon or self._go_steps or self.imagination_horizon
        state = th.as_tensor(state_vector(obs), device=self.device).reshape(1, -1)
        return plan_goal(
            self.policy,
            state,
            obs["achieved_goal"],
            box,
            rng,
            self.peg_samples,
            self.peg_iterations,
            self.peg_elite_fraction,
            horizon,
            self.gamma,
            self.lambda_,
            self.expl_reward_scale,
        )

    def _answer_goal_requests(self, new_obs: dict[str, np.ndarray], dones: np.ndarray) -> None:
        """Plan the goals the envs asked for at the resets of this step and write them into ``new_obs``.

        Each request carries the observation and the env's generator; the plan draws from that generator (and the
        env continues from it), so the run is the same in a ``DummyVecEnv`` and a ``SubprocVecEnv``.
        """
        env = self.env
        assert env is not None
        reset_infos = self._base_vec_env().reset_infos
        for i in np.flatnonzero(dones):
            if not reset_infos[i].get(GOAL_REQUEST_KEY, False):
                continue
            obs, rng = env.env_method("goal_request", indices=[i])[0]
            goal = self.plan_exploratory_goal(obs, rng)
            commanded = env.env_method("answer_goal_request", goal, rng, indices=[i])[0]
            new_obs["desired_goal"][i] = commanded["desired_goal"]

    # --- acting ------------------------------------------------------------------------------------------------
    def _start_streams(self) -> None:
        """Begin every env's replay stream and latent state at the current observations (a physical start)."""
        assert self._last_obs is not None and isinstance(self._last_obs, dict)
        states = state_vector(self._last_obs)
        for i in range(self.n_envs):
            self.replay_buffer.add(i, states[i], None)
            self._record_reset(self._last_obs, i)
        action_dim = int(np.prod(self.action_space.shape))
        self._latent = self.policy.world_model.rssm.initial(self.n_envs, self.device)
        self._prev_action = th.zeros(self.n_envs, action_dim, device=self.device)
        self._stream_obs = self._last_obs

    def _record_reset(self, obs: dict[str, np.ndarray], i: int) -> None:
        if self._task_goals is not None and not self._task_goals.declared:
            self._task_goals.record_reset({k: obs[k][i] for k in ("achieved_goal", "desired_goal")})

    def _act(self, obs: dict[str, np.ndarray], phases: list[str]) -> np.ndarray:
        """Actions in [-1, 1]: filter the latent with the new observation, then pi_G (Go) or pi_E (Explore)."""
        assert self._latent is not None and self._prev_action is not None
        policy = self.policy
        with th.no_grad():
            states, goals = policy.states_to_tensor(obs)
            self._latent = policy.filter(self._latent, self._prev_action, states)
            if self.num_timesteps < self.learning_starts:
                actions = self._rng.uniform(-1, 1, (self.n_envs, *self.action_space.shape)).astype(np.float32)
                return actions
            feat = self._latent.feat
            if all(p == "explore" for p in phases):
                return policy.actor_e.act(feat)[0].cpu().numpy()
            actions = policy.actor_g.act(feat, goals)[0]
            if "explore" in phases:
                explore = th.as_tensor([p == "explore" for p in phases], device=self.device).unsqueeze(-1)
                actions = th.where(explore, policy.actor_e.act(feat)[0], actions)
        return actions.cpu().numpy()

    def _store(
        self, new_obs: dict[str, np.ndarray], scaled: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> None:
        """Append the step to the replay streams (executed actions) and restart streams at physical resets."""
        assert self._prev_action is not None and self._latent is not None and self.env is not None
        states = state_vector(new_obs)
        executed = scaled.copy()
        for i, info in enumerate(infos):
            if "executed_action" in info:
                executed[i] = self.policy.scale_action(np.asarray(info["executed_action"], dtype=np.float32))
        self._prev_action = th.as_tensor(executed, device=self.device)
        for i in range(self.n_envs):
            if not dones[i]:
                self.replay_buffer.add(i, states[i], executed[i])
                continue
            terminal = infos[i].get("terminal_observation")
            if terminal is not None:
                self.replay_buffer.add(i, state_vector(terminal), executed[i])
            physical = self._base_vec_env().reset_infos[i].get("physical_reset", True)
            if physical:
                self.replay_buffer.add(i, states[i], None)
                self._record_reset(new_obs, i)
                self._prev_action[i] = 0.0
                self._latent.deter[i] = 0.0
                self._latent.stoch[i] = 0.0

    def collect_rollouts(self, callback: BaseCallback, n_steps: int, log_interval: int | None) -> bool:
        """Step the envs ``n_steps`` times (one training interval); False when a callback stops training.

        :param callback: the learn callback.
        :param n_steps: vectorised env steps.
        :param log_interval: dump the logs every ``log_interval`` finished episodes.
        :return: whether to continue.
        """
        env = self.env
        assert env is not None and self._last_obs is not None
        callback.on_rollout_start()
        for _ in range(n_steps):
            obs = self._last_obs
            assert isinstance(obs, dict)
            scaled = self._act(obs, self._phases())
            actions = self.policy.unscale_action(scaled)
            new_obs, rewards, dones, infos = env.step(actions)
            if self._planned_envs and dones.any():
                self._answer_goal_requests(new_obs, dones)  # type: ignore[arg-type]
            self.num_timesteps += env.num_envs
            callback.update_locals(locals())
            if not callback.on_step():
                self._last_obs = new_obs  # type: ignore[assignment]
                self._store(new_obs, scaled, dones, infos)  # type: ignore[arg-type]
                self._stream_obs = new_obs
                callback.on_rollout_end()
                return False
            self._update_info_buffer(infos, dones)
            self._store(new_obs, scaled, dones, infos)  # type: ignore[arg-type]
            self._last_obs = self._stream_obs = new_obs  # type: ignore[assignment]
            self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)
            for done in dones:
                if done:
                    self._episode_num += 1
                    if log_interval is not None and self._episode_num % log_interval == 0:
                        self.dump_logs()
        callback.on_rollout_end()
        return True

"""Goal commanding: override ``desired_goal`` with a scheduled goal and recompute reward/success.

At the start of every segment (every ``reset()`` SB3 calls) the wrapper asks its
:class:`~sb3_gcrl.goals.GoalScheduler` for a goal, writes it into ``desired_goal`` and recomputes the reward with
the env's own vectorised ``compute_reward(achieved_goal, commanded_goal, info)``; ``info["is_success"]`` is
recomputed for the commanded goal too. The wrapper also owns the env's task-relevant goals (rho_0, rho_g*,
:class:`~sb3_gcrl.goals.TaskRelevantGoals`), which it learns from the env's physical resets when the env does not
declare them, and serves them to the replay buffer (:meth:`sample_task_goals`).

Like :class:`~sb3_gcrl.wrappers.ResetFreeWrapper`, commanding is active only in training mode
(``set_training_mode(True)``, called for the training env by :class:`~sb3_gcrl.callbacks.ResetFreeCallback`, and
passed on to a :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` below); in evaluation mode (``rl_zoo3 enjoy``, the
eval env) the env's own goal is kept, i.e. the agent starts from rho_0 and is evaluated on rho_g*.

Goals of any gymnasium space work (SB3's ``BitFlippingEnv`` in all its variants): ``Box`` vectors, ``MultiBinary``
and ``Discrete`` goals (commanded as the env's own integer), and image goals (commanded pixel for pixel; only the
binned visited-goal schedulers refuse them at construction).
"""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import unwrap_wrapper

from sb3_gcrl.common.validation import check_finite_rewards, check_float
from sb3_gcrl.goals.schedulers import GoalScheduler, make_scheduler
from sb3_gcrl.goals.task_goals import GoalKind, TaskRelevantGoals
from sb3_gcrl.wrappers.goal_env import check_goal_env, record_constructor_args
from sb3_gcrl.wrappers.mode import TrainingModeMixin


def scalar_reward(reward: Any) -> float:
    """A reward from a vectorised ``compute_reward`` called on one goal (a scalar or an array of one value)."""
    try:
        return float(reward)
    except TypeError:  # e.g. BitFlippingEnv returns shape (1,), which numpy 2 will not convert with float()
        return float(np.asarray(reward).reshape(-1)[0])


class GoalCommandWrapper(
    TrainingModeMixin,
    gym.Wrapper[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray], np.ndarray],
    gym.utils.RecordConstructorArgs,
):
    """Command scheduled goals to a goal env (reset-free training), recomputing reward and success.

    :param env: a gymnasium-robotics style goal env (usually wrapped in :class:`ResetFreeWrapper`).
    :param scheduler: a :class:`~sb3_gcrl.goals.GoalScheduler`, or the name of one for
        :func:`~sb3_gcrl.goals.make_scheduler` (``env_default``, ``evaluation``, ``uniform_visited``,
        ``novelty``, ``back_and_forth``).
    :param scheduler_kwargs: keyword arguments of :func:`~sb3_gcrl.goals.make_scheduler` when ``scheduler`` is a
        name (e.g. ``{"alpha": 0.2, "exploratory": "novelty", "goal_low": [-2, -2], "goal_high": [2, 2]}``);
        without ``goal_low``/``goal_high`` the bins follow the goals the env shows (never the nominal bounds of
        the ``achieved_goal`` space, often far wider than the goals that occur).
    :param success_distance: success means ``||achieved_goal - goal|| <= success_distance``; ``None`` means the
        reward for the commanded goal equals the reward the env gives at the goal itself (exact for sparse
        rewards, e.g. PointMaze's 0/1 and Fetch's -1/0; pass a distance for dense rewards).
    :param task_goal_capacity: resets remembered when rho_0/rho_g* are learned from the env's resets.
    """

    run_state_attributes = ("task_goals", "scheduler", "goal_counts", "goal_reached", "_rng", "_task_goal_rng")

    def __init__(
        self,
        env: gym.Env,
        scheduler: GoalScheduler | str = "env_default",
        scheduler_kwargs: dict[str, Any] | None = None,
        success_distance: float | None = None,
        task_goal_capacity: int = 10_000,
    ) -> None:
        check_goal_env(env, type(self).__name__)
        record_constructor_args(self, locals())
        super().__init__(env)
        goal_space = env.observation_space["desired_goal"]
        self._goal_shape = goal_space.shape
        self._discrete_goal = isinstance(goal_space, spaces.Discrete)  # the env's goals are Python/numpy integers
        self._goal_dtype = np.int64 if self._discrete_goal else goal_space.dtype
        goal_dim = int(np.prod(self._goal_shape))
        self.task_goals = TaskRelevantGoals(env, goal_dim, capacity=task_goal_capacity)
        if isinstance(scheduler, GoalScheduler):
            if scheduler_kwargs:
                raise ValueError("scheduler_kwargs only apply when scheduler is given by name")
            self.scheduler = scheduler
        else:
            achieved_space = env.observation_space["achieved_goal"]
            self.scheduler = make_scheduler(
                scheduler, self.task_goals, achieved_goal_space=achieved_space, **(scheduler_kwargs or {})
            )
        self.success_distance = None
        if success_distance is not None:
            self.success_distance = check_float("success_distance", success_distance, 0.0, exclusive_minimum=True)
        # a mode-switched wrapper below (ResetFreeWrapper) gets the switches passed on and warns instead of this one
        self._mode_below: TrainingModeMixin | None = unwrap_wrapper(env, TrainingModeMixin)
        self._init_training_mode(warns=self._mode_below is None)
        self._pass_mode_to(self._mode_below)  # this wrapper reports the segments, not the one below
        self.goal: np.ndarray | None = None
        self.goal_kind = "env"
        #: goals commanded / reached (at least once while commanded), per scheduler label
        self.goal_counts: dict[str, int] = {}
        self.goal_reached: dict[str, int] = {}
        self._reached = False
        self._success_reward: float | None = None
        self._compute_reward = env.unwrapped.compute_reward
        self._goal_obs: Any = None
        self._rng = np.random.default_rng()
        self._task_goal_rng = np.random.default_rng()

    # --- mode -------------------------------------------------------------------------------------------------
    def _on_training_mode(self, training: bool) -> None:
        """Pass the switch on to a mode-switched wrapper below (a :class:`ResetFreeWrapper`)."""
        if self._mode_below is not None:
            self._mode_below.set_training_mode(training)

    def _on_run_state_loaded(self) -> None:
        """The restored task goals sample from this env's declared samplers (the env is not saved with them)."""
        self.task_goals.attach(self.env)

    @property
    def task_goal_alpha(self) -> float | None:
        """alpha of the scheduler (Back-and-Forth, Algorithm 3), None when it has none.

        :class:`~sb3_gcrl.her.TaskRelevantHerReplayBuffer` reads it so that alpha is stated once.
        """
        alpha = getattr(self.scheduler, "alpha", None)
        return None if alpha is None else float(alpha)

    # --- task-relevant goals for the replay buffer -----------------------------------------------------------
    def sample_task_goals(self, kind: GoalKind, n: int) -> np.ndarray:
        """Draw ``n`` goals from rho_0 (``"initial"``) or rho_g* (``"evaluation"``), shape ``(n, goal_dim)``."""
        return self.task_goals.sample(kind, self._task_goal_rng, n)

    def sample_relabel_task_goals(self, n: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
        """Task-relevant goals for ``n`` relabeled transitions (thesis Sec. 3.4.2): each one independently gets a
        goal of rho_g* with probability alpha/2, a goal of rho_0 with probability alpha/2, and keeps its replayed
        goal otherwise.

        Drawn with this env's task-goal generator (seeded by ``reset(seed=...)`` from SB3's seed, and saved in
        checkpoints), so relabeling is reproducible under a fixed seed.

        :param n: relabeled transitions.
        :param alpha: the share of task-relevant goals, in [0, 1].
        :return: ``(indices, goals)``: the transitions (indices in ``[0, n)``) that get a task-relevant goal, and
            their goals, shape ``(len(indices), goal_dim)``.
        """
        u = self._task_goal_rng.random(n)
        rows = np.flatnonzero(u < alpha)
        evaluation = u[rows] < alpha / 2.0
        goals = np.empty((rows.size, self.task_goals.goal_dim))
        for kind, mask in (("evaluation", evaluation), ("initial", ~evaluation)):
            if mask.any():
                goals[mask] = self.sample_task_goals(kind, int(mask.sum()))  # type: ignore[arg-type]
        return rows, goals

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """The env's vectorised reward (gymnasium 1.x wrappers do not forward attributes)."""
        return self._compute_reward(achieved_goal, desired_goal, info)

    # --- success ----------------------------------------------------------------------------------------------
    def is_success(self, achieved_goal: np.ndarray, goal: np.ndarray, info: dict[str, Any]) -> bool:
        """Whether ``achieved_goal`` reaches ``goal`` (see ``success_distance``)."""
        if self.success_distance is not None:
            return bool(np.linalg.norm(np.asarray(achieved_goal, np.float64) - goal) <= self.success_distance)
        if self._success_reward is None:
            # the reward the env gives exactly at a goal: constant for sparse rewards, so computed once
            self._success_reward = scalar_reward(self._compute_reward(achieved_goal, achieved_goal, info))
        return bool(scalar_reward(self._compute_reward(achieved_goal, goal, info)) >= self._success_reward)

    # --- gym API ----------------------------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if seed is not None:
            seeds = np.random.SeedSequence(seed).spawn(2)
            self._rng = np.random.default_rng(seeds[0])
            self._task_goal_rng = np.random.default_rng(seeds[1])
        obs, info = self.env.reset(seed=seed, options=options)
        self._segments.begin()
        physical = info.get("physical_reset", True)
        if physical:
            if not self.task_goals.declared:
                self.task_goals.record_reset(obs)
            self.scheduler.observe_task_goal(np.ravel(obs["desired_goal"]))  # e.g. inferred goal bins span rho_g*
        if not self.training:
            if physical and self._mode_below is None:
                self._arm_mode_check()
            self._set_goal(obs["desired_goal"])
            self.goal_kind = "env"
            return obs, info
        if physical:
            self.scheduler.reset_pending()
        self.scheduler.observe(obs["achieved_goal"])
        self._set_goal(self.scheduler.next_goal(obs, self._rng))
        self.goal_kind = self.scheduler.kind
        self.goal_counts[self.goal_kind] = self.goal_counts.get(self.goal_kind, 0) + 1
        self._reached = False
        return self._command(obs), info

    def _set_goal(self, goal: Any) -> None:
        """Command ``goal`` (flat or shaped) until the next reset.

        :attr:`goal` keeps it in float64 in the goal space's shape; the observations, and ``compute_reward``, get it
        in the env's own representation (its dtype; a Python ``int`` for a ``Discrete`` goal space).
        """
        self.goal = np.asarray(goal, dtype=np.float64).reshape(self._goal_shape)
        if self._discrete_goal:
            self._goal_obs = int(round(float(self.goal)))
        else:
            self._goal_obs = self.goal.astype(self._goal_dtype)

    def _command(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        # a new dict: inner wrappers keep references to the observations they returned
        commanded = dict(obs)
        commanded["desired_goal"] = self._goal_obs if self._discrete_goal else self._goal_obs.copy()
        return commanded

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        if not self.training:
            obs, reward, terminated, truncated, info = self._evaluation_step(action)
            self._check_reward(reward)
            return obs, reward, terminated, truncated, info
        obs, reward, terminated, truncated, info = self._training_step(action)
        self._check_reward(reward)
        if self._recording:  # the outermost mode-switched wrapper reports the segments (Monitor CSV, rollout/*)
            self._segments.step(reward, terminated or truncated, info, self.goal_kind)  # type: ignore[arg-type]
        return obs, reward, terminated, truncated, info

    def _evaluation_step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        """One step in evaluation mode: the env's own goal, reward and success."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._mode_check_armed:
            self._check_mode()
        if "is_success" not in info:
            info["is_success"] = self.is_success(obs["achieved_goal"], obs["desired_goal"], info)
        return obs, reward, terminated, truncated, info

    def _training_step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        """One step in training mode toward the commanded goal (subclasses extend it; :meth:`step` records it)."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        # hot path (every training step): one compute_reward call, no other numpy work
        achieved = obs["achieved_goal"]
        self.scheduler.observe(achieved)
        reward = scalar_reward(self._compute_reward(achieved, self._goal_obs, info))
        if not math.isfinite(reward):  # (math, not numpy: the hot path) a NaN would reach the networks' losses
            check_finite_rewards(
                reward,
                f"for the commanded goal {self.goal}",
                "the agent learns from it (a NaN makes the networks' losses and actions NaN)",
                source="The env's compute_reward",
            )
        if self.success_distance is None:
            if self._success_reward is None:
                self._success_reward = scalar_reward(self._compute_reward(achieved, achieved, info))
            success = reward >= self._success_reward
        else:
            success = self.is_success(achieved, self.goal, info)  # type: ignore[arg-type]
        info["is_success"] = success
        if success and not self._reached:
            self._reached = True
            self.goal_reached[self.goal_kind] = self.goal_reached.get(self.goal_kind, 0) + 1
        return self._command(obs), reward, terminated, truncated, info

"""Goal commanding: override ``desired_goal`` with a scheduled goal and recompute reward/success.

DESIGN.md contract 3. At the start of every segment (every ``reset()`` SB3 calls) the wrapper asks its
:class:`~sb3_gcrl.goals.GoalScheduler` for a goal, writes it into ``desired_goal`` and recomputes the reward with
the env's own vectorised ``compute_reward(achieved_goal, commanded_goal, info)``; ``info["is_success"]`` is
recomputed for the commanded goal too. The wrapper also owns the env's task-relevant goals (rho_0, rho_g*,
:class:`~sb3_gcrl.goals.TaskRelevantGoals`), which it learns from the env's physical resets when the env does not
declare them, and serves them to the replay buffer (:meth:`sample_task_goals`).

Like :class:`~sb3_gcrl.wrappers.ResetFreeWrapper`, commanding is active only in ``"reset_free"`` mode, switched on
for the training env by :class:`~sb3_gcrl.callbacks.ResetFreeCallback`; in ``"episodic"`` mode (evaluation,
``rl_zoo3 enjoy``) the env's own goal is kept, i.e. the agent starts from rho_0 and is evaluated on rho_g*.
"""

from __future__ import annotations

from typing import Any, Literal, SupportsFloat

import gymnasium as gym
import numpy as np

from sb3_gcrl.goals.schedulers import GoalScheduler, make_scheduler
from sb3_gcrl.goals.task_goals import GoalKind, TaskRelevantGoals
from sb3_gcrl.wrappers.goal_env import check_goal_env

Mode = Literal["episodic", "reset_free"]


class GoalCommandWrapper(
    gym.Wrapper[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray], np.ndarray], gym.utils.RecordConstructorArgs
):
    """Command scheduled goals to a goal env (reset-free training), recomputing reward and success.

    :param env: a gymnasium-robotics style goal env (usually wrapped in :class:`ResetFreeWrapper`).
    :param scheduler: a :class:`~sb3_gcrl.goals.GoalScheduler`, or the name of one for
        :func:`~sb3_gcrl.goals.make_scheduler` (``env_default``, ``evaluation``, ``uniform_visited``,
        ``novelty``, ``back_and_forth``).
    :param scheduler_kwargs: keyword arguments of :func:`~sb3_gcrl.goals.make_scheduler` when ``scheduler`` is a
        name (e.g. ``{"alpha": 0.2, "exploratory": "novelty", "goal_low": [-2, -2], "goal_high": [2, 2]}``);
        ``goal_low``/``goal_high`` default to the bounds of a bounded ``achieved_goal`` space.
    :param success_distance: success means ``||achieved_goal - goal|| <= success_distance``; ``None`` means the
        reward for the commanded goal equals the reward the env gives at the goal itself (exact for sparse
        rewards, e.g. PointMaze's 0/1 and Fetch's -1/0; pass a distance for dense rewards).
    :param task_goal_capacity: resets remembered when rho_0/rho_g* are learned from the env's resets.
    """

    def __init__(
        self,
        env: gym.Env,
        scheduler: GoalScheduler | str = "env_default",
        scheduler_kwargs: dict[str, Any] | None = None,
        success_distance: float | None = None,
        task_goal_capacity: int = 10_000,
    ) -> None:
        check_goal_env(env, type(self).__name__)
        gym.utils.RecordConstructorArgs.__init__(
            self,
            scheduler=scheduler,
            scheduler_kwargs=scheduler_kwargs,
            success_distance=success_distance,
            task_goal_capacity=task_goal_capacity,
        )
        super().__init__(env)
        goal_dim = int(np.prod(env.observation_space["achieved_goal"].shape))
        self.task_goals = TaskRelevantGoals(env, goal_dim, capacity=task_goal_capacity)
        if isinstance(scheduler, GoalScheduler):
            if scheduler_kwargs:
                raise ValueError("scheduler_kwargs only apply when scheduler is given by name")
            self.scheduler = scheduler
        else:
            kwargs = dict(scheduler_kwargs or {})
            achieved_space = env.observation_space["achieved_goal"]
            if "goal_low" not in kwargs and "goal_high" not in kwargs and achieved_space.is_bounded():
                # bins over the achieved-goal space when it is bounded (e.g. GCRL/PointUMazeGoal-v0)
                kwargs["goal_low"], kwargs["goal_high"] = achieved_space.low.tolist(), achieved_space.high.tolist()
            self.scheduler = make_scheduler(scheduler, self.task_goals, **kwargs)
        if success_distance is not None and not success_distance > 0:
            raise ValueError(f"success_distance must be > 0, got {success_distance}")
        self.success_distance = success_distance
        self.mode: Mode = "episodic"
        self.goal: np.ndarray | None = None
        self.goal_kind = "env"
        #: goals commanded / reached (at least once while commanded), per scheduler label
        self.goal_counts: dict[str, int] = {}
        self.goal_reached: dict[str, int] = {}
        self._reached = False
        self._success_reward: float | None = None
        self._compute_reward = env.unwrapped.compute_reward
        self._goal_obs = np.zeros(goal_dim)
        self._rng = np.random.default_rng()
        self._task_goal_rng = np.random.default_rng()

    # --- mode -------------------------------------------------------------------------------------------------
    def enable_reset_free(self) -> None:
        """Switch to reset-free mode (training env only); propagates to a :class:`ResetFreeWrapper` below."""
        self.mode = "reset_free"
        inner = self.env
        while isinstance(inner, gym.Wrapper):
            if hasattr(inner, "enable_reset_free"):
                inner.enable_reset_free()
                break
            inner = inner.env

    # --- task-relevant goals for the replay buffer -----------------------------------------------------------
    def sample_task_goals(self, kind: GoalKind, n: int) -> np.ndarray:
        """Draw ``n`` goals from rho_0 (``"initial"``) or rho_g* (``"evaluation"``), shape ``(n, goal_dim)``."""
        return self.task_goals.sample(kind, self._task_goal_rng, n)

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """The env's vectorised reward (gymnasium 1.x wrappers do not forward attributes)."""
        return self._compute_reward(achieved_goal, desired_goal, info)

    # --- success ----------------------------------------------------------------------------------------------
    def is_success(self, achieved_goal: np.ndarray, goal: np.ndarray, info: dict[str, Any]) -> bool:
        """Whether ``achieved_goal`` reaches ``goal`` (see ``success_distance``)."""
        if self.success_distance is not None:
            return bool(np.linalg.norm(achieved_goal - goal) <= self.success_distance)
        if self._success_reward is None:
            # the reward the env gives exactly at a goal: constant for sparse rewards, so computed once
            self._success_reward = float(self._compute_reward(achieved_goal, achieved_goal, info))
        return bool(float(self._compute_reward(achieved_goal, goal, info)) >= self._success_reward)

    # --- gym API ----------------------------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if seed is not None:
            seeds = np.random.SeedSequence(seed).spawn(2)
            self._rng = np.random.default_rng(seeds[0])
            self._task_goal_rng = np.random.default_rng(seeds[1])
        obs, info = self.env.reset(seed=seed, options=options)
        physical = info.get("physical_reset", True)
        if physical and not self.task_goals.declared:
            self.task_goals.record_reset(obs)
        if self.mode == "episodic":
            self.goal, self.goal_kind = np.array(obs["desired_goal"], dtype=np.float64), "env"
            return obs, info
        if physical:
            self.scheduler.reset_pending()
        self.scheduler.observe(obs["achieved_goal"])
        self._set_goal(self.scheduler.next_goal(obs, self._rng), obs)
        self.goal_kind = self.scheduler.kind
        self.goal_counts[self.goal_kind] = self.goal_counts.get(self.goal_kind, 0) + 1
        self._reached = False
        return self._command(obs), info

    def _set_goal(self, goal: np.ndarray, obs: dict[str, np.ndarray]) -> None:
        """Command ``goal`` until the next reset (kept in float64 and, for the observations, in their dtype)."""
        self.goal = np.asarray(goal, dtype=np.float64).reshape(obs["desired_goal"].shape)
        self._goal_obs = self.goal.astype(obs["desired_goal"].dtype)

    def _command(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        # a new dict: inner wrappers keep references to the observations they returned
        commanded = dict(obs)
        commanded["desired_goal"] = self._goal_obs.copy()
        return commanded

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.mode == "episodic":
            if "is_success" not in info:
                info["is_success"] = self.is_success(obs["achieved_goal"], obs["desired_goal"], info)
            return obs, reward, terminated, truncated, info
        # hot path (every training step): one compute_reward call, no other numpy work
        achieved = obs["achieved_goal"]
        self.scheduler.observe(achieved)
        reward = float(self._compute_reward(achieved, self.goal, info))
        if self.success_distance is None:
            if self._success_reward is None:
                self._success_reward = float(self._compute_reward(achieved, achieved, info))
            success = reward >= self._success_reward
        else:
            success = self.is_success(achieved, self.goal, info)  # type: ignore[arg-type]
        info["is_success"] = success
        if success and not self._reached:
            self._reached = True
            self.goal_reached[self.goal_kind] = self.goal_reached.get(self.goal_kind, 0) + 1
        return self._command(obs), reward, terminated, truncated, info

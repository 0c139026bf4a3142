"""IBC's goal curriculum as a goal scheduler of the package (J. Kim et al., ICML 2023; the baseline of thesis Ch. 3).

IBC ("Implicit and Bidirectional Curriculum") trains a forward and a backward goal-conditioned agent reset-free.
This module holds what chooses the goals; the agents are :class:`~sb3_gcrl.reset_free_baselines.IBC`. Following the
authors' code:

* **Phases** (the implicit curriculum): a forward segment (at most ``go_steps`` steps, ended at success) commands a
  curriculum goal to the forward agent. If it reached its goal, the forward agent goes on with a new curriculum goal
  (the *auxiliary* phase, kind ``"auxiliary"``); otherwise the backward agent gets a backward curriculum goal
  (kind ``"back"``). After a backward segment the forward agent takes over again (kind ``"forward"``); so does it
  after every physical reset.
* **Bidirectional curriculum** (optimal transport, as HGG): every ``update_every`` forward segments (and at the
  fifth), K target pairs (s0_j ~ rho_0, g*_j ~ rho_g*) are matched one to one to stored forward trajectories by a
  minimum-cost bipartite matching. The cost of trajectory i for pair j is
  ``min_t [||ag_t - g*_j|| - V(s0_i -> ag_t) * (1 - gamma) * d_max / L] + c * ||ag_0 - s0_j||``,
  with V the forward agent's value of reaching ag_t from the trajectory's start (clipped to
  ``[-(r_max - r_min) / (1 - gamma), 0]`` after shifting by ``r_max / (1 - gamma)``) and ``d_max`` the largest
  distance between a rho_0 and a rho_g* sample. The matched trajectory's minimising achieved goal becomes forward
  curriculum goal j and its first achieved goal backward curriculum goal j.
* **Goal draw**: a uniformly drawn entry of the pool (plus Gaussian ``goal_noise``); an entry already reached at the
  current state is redrawn once, and after two reached draws a forward segment gets a task goal g* ~ rho_g* instead.

The forward agent's values come from the agent attached with :meth:`IBCCurriculumScheduler.attach` (the
:class:`~sb3_gcrl.reset_free_baselines.IBC` algorithm does it at the start of ``learn``); before that (or without an
agent, e.g. ``rl_zoo3 enjoy``) the values are 0 and the matching uses distances only.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from scipy.optimize import linear_sum_assignment
from stable_baselines3.common.env_util import unwrap_wrapper

from sb3_gcrl.goals.schedulers import GoalScheduler
from sb3_gcrl.goals.task_goals import TaskRelevantGoals
from sb3_gcrl.wrappers.go_explore import GoExploreWrapper
from sb3_gcrl.wrappers.reset_free import ResetFreeWrapper

#: goal kinds of the IBC phases (the first two are run by the forward agent)
FORWARD, AUXILIARY, BACK = "forward", "auxiliary", "back"
FORWARD_KINDS = (FORWARD, AUXILIARY)


class CurriculumValueSource(Protocol):
    """What :class:`IBCCurriculumScheduler` asks the agent (implemented by
    :class:`~sb3_gcrl.reset_free_baselines.IBC`)."""

    gamma: float

    def curriculum_values(self, observations: dict[str, np.ndarray]) -> np.ndarray:
        """Forward value V(s -> g) of a batch of goal observations, shape ``(n,)``."""


class IBCCurriculumScheduler(GoalScheduler):
    """IBC's phases and bidirectional curriculum goals (see the module docstring).

    :param task_goals: the env's task-relevant goals (rho_0, rho_g*).
    :param success: ``success(achieved_goal, goal) -> bool``, the commanding wrapper's success test.
    :param n_targets: K, the target pairs and curriculum goals (official: 50).
    :param update_every: forward segments between two curriculum updates (official: 20; the first is at the 5th).
    :param trajectory_capacity: forward trajectories kept for the matching (official: 1000).
    :param min_displacement: a forward trajectory is kept only if its achieved goal moved more than this
        (official: 0.1 in PointUMaze, 0.01 elsewhere).
    :param hgg_c: weight c of the distance to the target's initial state (official: 3).
    :param hgg_l: L, the scale of the value term (official: 5).
    :param goal_noise: standard deviation of the Gaussian noise added to a drawn curriculum goal (official: 0.3 in
        IBC's PointUMaze, 0.1 Tabletop, 0.005 Sawyer Door, 0.03 Fetch).
    :param init_noise: standard deviation around rho_0 of the pool before the first update (official: the success
        threshold of the task).
    :param reward_range: the env's (failure, success) rewards, which bound the values.
    """

    kind = FORWARD

    def __init__(
        self,
        task_goals: TaskRelevantGoals,
        success: Callable[[np.ndarray, np.ndarray], bool],
        n_targets: int = 50,
        update_every: int = 20,
        trajectory_capacity: int = 1000,
        min_displacement: float = 0.01,
        hgg_c: float = 3.0,
        hgg_l: float = 5.0,
        goal_noise: float = 0.0,
        init_noise: float = 0.0,
        reward_range: tuple[float, float] = (0.0, 1.0),
    ) -> None:
        for name, value in (("n_targets", n_targets), ("update_every", update_every)):
            if int(value) != value or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value}")
        if int(trajectory_capacity) != trajectory_capacity or trajectory_capacity < n_targets:
            raise ValueError(f"trajectory_capacity must be an integer >= n_targets, got {trajectory_capacity}")
        for name, value in (
            ("min_displacement", min_displacement),
            ("hgg_c", hgg_c),
            ("goal_noise", goal_noise),
            ("init_noise", init_noise),
        ):
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
        if not np.isfinite(hgg_l) or hgg_l <= 0:
            raise ValueError(f"hgg_l must be > 0, got {hgg_l}")
        low, high = (float(r) for r in reward_range)
        if not low < high:
            raise ValueError(
                f"reward_range must be (failure reward, success reward) with failure < success, got {reward_range}"
            )
        self.task_goals = task_goals
        self.success = success
        self.n_targets = int(n_targets)
        self.update_every = int(update_every)
        self.trajectory_capacity = int(trajectory_capacity)
        self.min_displacement = float(min_displacement)
        self.hgg_c = float(hgg_c)
        self.hgg_l = float(hgg_l)
        self.goal_noise = float(goal_noise)
        self.init_noise = float(init_noise)
        self.reward_range = (low, high)
        self.agent: CurriculumValueSource | None = None
        #: forward curriculum goals / backward curriculum goals, shape (K, goal_dim); None before the first draw
        self.forward_pool: np.ndarray | None = None
        self.backward_pool: np.ndarray | None = None
        #: the K target pairs (rho_0, rho_g*) drawn once, at the first update
        self.targets: tuple[np.ndarray, np.ndarray] | None = None
        #: stored forward trajectories: (first observation, achieved goals (T, goal_dim))
        self.trajectories: list[tuple[dict[str, np.ndarray], np.ndarray]] = []
        self._n_inserted = 0
        #: forward segments so far, curriculum updates, mean matching cost and mean distance of the forward pool to
        #: its target task goals at the last update
        self.n_forward_segments = 0
        self.n_updates = 0
        self.last_cost = float("nan")
        self.last_target_distance = float("nan")
        #: segments per kind
        self.segment_counts = {FORWARD: 0, AUXILIARY: 0, BACK: 0}
        self.goal: np.ndarray | None = None
        self._start_obs: dict[str, np.ndarray] | None = None
        self._achieved: list[np.ndarray] = []

    # --- hooks ------------------------------------------------------------------------------------------------
    def attach(self, agent: CurriculumValueSource | None) -> None:
        """Let ``agent``'s forward values drive the curriculum (None detaches)."""
        self.agent = agent

    def observe(self, achieved_goal: np.ndarray) -> None:
        if self._start_obs is not None:
            self._achieved.append(np.array(achieved_goal, dtype=np.float64).reshape(-1))

    def reset_pending(self) -> None:
        """After a physical reset the forward agent starts (the segment in progress is not stored)."""
        self.kind = BACK  # so that the next segment is a forward one
        self.goal = None
        self._start_obs, self._achieved = None, []

    def __getstate__(self) -> dict[str, Any]:
        # the agent is re-attached at the start of learn; never pickle it with the env
        return {**self.__dict__, "agent": None}

    # --- phases -----------------------------------------------------------------------------------------------
    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        achieved = np.asarray(obs["achieved_goal"], dtype=np.float64).reshape(-1)
        previous = self.kind if self.goal is not None else BACK
        if previous in FORWARD_KINDS:
            self._store_trajectory()
            self.n_forward_segments += 1
            if self.n_forward_segments == 5 or self.n_forward_segments % self.update_every == 0:
                self.update(rng)
        reached = previous in FORWARD_KINDS and self.goal is not None and self.success(achieved, self.goal)
        if previous in FORWARD_KINDS and not reached:
            self.kind = BACK
        else:
            self.kind = AUXILIARY if reached else FORWARD
        self.goal = self._draw(achieved, rng)
        self.segment_counts[self.kind] += 1
        self._start_obs = {key: np.array(value, copy=True) for key, value in obs.items()}
        self._achieved = [achieved.copy()]
        return self.goal.copy()

    def _draw(self, achieved: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A curriculum goal of the current kind not yet reached at ``achieved`` (official: two tries)."""
        pool = self._pool(BACK if self.kind == BACK else FORWARD, rng)
        goal = pool[0]  # replaced below
        for _ in range(2):
            goal = pool[rng.integers(len(pool))]
            if self.goal_noise > 0:
                goal = goal + rng.normal(0.0, self.goal_noise, goal.shape)
            if not self.success(achieved, goal):
                return goal
        if self.kind == BACK:
            return goal
        return np.asarray(self.task_goals.sample("evaluation", rng)[0], dtype=np.float64).reshape(-1)

    def _pool(self, kind: str, rng: np.random.Generator) -> np.ndarray:
        if self.forward_pool is None or self.backward_pool is None:
            # official: before the first update both pools are rho_0 with noise of the success threshold's size
            initial = np.asarray(self.task_goals.sample("initial", rng, self.n_targets), dtype=np.float64)
            initial = initial.reshape(self.n_targets, -1)
            noise = rng.normal(0.0, self.init_noise, (2, *initial.shape)) if self.init_noise > 0 else np.zeros(2)
            self.forward_pool, self.backward_pool = initial + noise[0], initial + noise[1]
        return self.backward_pool if kind == BACK else self.forward_pool

    # --- curriculum -------------------------------------------------------------------------------------------
    def _store_trajectory(self) -> None:
        if self._start_obs is None or len(self._achieved) < 2:
            return
        achieved = np.stack(self._achieved)
        if np.linalg.norm(achieved[-1] - achieved[0]) <= self.min_displacement:
            return
        entry = (self._start_obs, achieved)
        if len(self.trajectories) < self.trajectory_capacity:
            self.trajectories.append(entry)
        else:
            self.trajectories[self._n_inserted % self.trajectory_capacity] = entry
        self._n_inserted += 1

    def trajectory_values(self, start_obs: dict[str, np.ndarray], achieved: np.ndarray) -> np.ndarray:
        """V(s0 -> ag_t) for every achieved goal of one trajectory, shifted and clipped to ``[-v_span, 0]``.

        :param start_obs: the trajectory's first observation.
        :param achieved: its achieved goals, shape ``(T, goal_dim)``.
        :return: shape ``(T,)``; zeros without an attached agent.
        """
        if self.agent is None:
            return np.zeros(len(achieved))
        gamma = float(self.agent.gamma)
        n = len(achieved)
        batch = {key: np.repeat(np.asarray(value)[None], n, axis=0) for key, value in start_obs.items()}
        batch["desired_goal"] = achieved.reshape(batch["desired_goal"].shape).astype(batch["desired_goal"].dtype)
        values = np.asarray(self.agent.curriculum_values(batch), dtype=np.float64).reshape(-1)
        low, high = self.reward_range
        return np.clip(values - high / (1.0 - gamma), -(high - low) / (1.0 - gamma), 0.0)

    def update(self, rng: np.random.Generator | None = None) -> None:
        """Match the K target pairs to stored forward trajectories and refill both curriculum pools."""
        rng = np.random.default_rng() if rng is None else rng
        if self.targets is None:
            initial = self.task_goals.sample("initial", rng, self.n_targets).reshape(self.n_targets, -1)
            final = self.task_goals.sample("evaluation", rng, self.n_targets).reshape(self.n_targets, -1)
            self.targets = (np.asarray(initial, np.float64), np.asarray(final, np.float64))
        initial, final = self.targets
        if not self.trajectories:  # official: the task goals themselves until a trajectory is stored
            self.forward_pool, self.backward_pool = final.copy(), initial.copy()
            return
        gamma = 0.99 if self.agent is None else float(self.agent.gamma)
        d_max = max(float(np.max(np.linalg.norm(initial - final, axis=1))), 1e-8)
        scale = (1.0 - gamma) * d_max / self.hgg_l
        n_traj = len(self.trajectories)
        costs = np.empty((self.n_targets, n_traj))
        best_t = np.empty((self.n_targets, n_traj), dtype=np.int64)
        for i, (start_obs, achieved) in enumerate(self.trajectories):
            values = self.trajectory_values(start_obs, achieved)
            distance = np.linalg.norm(achieved[None, :, :] - final[:, None, :], axis=2)  # (K, T)
            res = distance - values[None, :] * scale
            best_t[:, i] = np.argmin(res, axis=1)
            costs[:, i] = res.min(axis=1) + self.hgg_c * np.linalg.norm(achieved[0][None] - initial, axis=1)
        # official: the trajectory pool is repeated up to its capacity, so one trajectory can serve several targets
        copies = int(np.ceil(self.trajectory_capacity / n_traj)) if n_traj < self.trajectory_capacity else 1
        columns = np.tile(np.arange(n_traj), copies)[: max(self.trajectory_capacity, n_traj)]
        rows, chosen = linear_sum_assignment(costs[:, columns])
        trajectories = columns[chosen]
        self.forward_pool = np.stack(
            [self.trajectories[i][1][best_t[j, i]] for j, i in zip(rows, trajectories, strict=True)]
        )
        self.backward_pool = np.stack([self.trajectories[i][1][0] for i in trajectories])
        self.last_cost = float(costs[rows, trajectories].mean())
        self.last_target_distance = float(np.linalg.norm(self.forward_pool - final[rows], axis=1).mean())
        self.n_updates += 1


def ibc_go_explore(
    env: gym.Env,
    go_steps: int | None = None,
    curriculum_kwargs: dict[str, Any] | None = None,
    success_distance: float | None = None,
) -> GoExploreWrapper:
    """IBC's phase switching on the package's Go/Explore wrapper: an ``env_wrapper`` entry.

    Builds a :class:`~sb3_gcrl.wrappers.GoExploreWrapper` with no Explore phase (``explore_steps=0``) whose Go phase
    ends at ``go_steps`` or at success (official ``done_on_success``), with an :class:`IBCCurriculumScheduler`.

    :param env: goal env wrapped in :class:`~sb3_gcrl.wrappers.ResetFreeWrapper`.
    :param go_steps: longest segment (official ``max_episode_timesteps``: 100 PointUMaze and Tabletop, 200 Sawyer
        Door, 50 Fetch); default: the ``eval_horizon`` of the ResetFreeWrapper below.
    :param curriculum_kwargs: keyword arguments of :class:`IBCCurriculumScheduler` (not ``task_goals``/``success``).
    :param success_distance: see :class:`~sb3_gcrl.wrappers.GoalCommandWrapper`.
    :return: the wrapped env.
    """
    kwargs = dict(curriculum_kwargs or {})
    for key in ("task_goals", "success"):
        if key in kwargs:
            raise ValueError(f"ibc_go_explore sets {key} itself: remove it from curriculum_kwargs")
    if go_steps is None:
        reset_free = unwrap_wrapper(env, ResetFreeWrapper)
        if reset_free is None or reset_free.eval_horizon is None:
            raise ValueError("ibc_go_explore needs go_steps, or a ResetFreeWrapper below that states eval_horizon")
        go_steps = int(reset_free.eval_horizon)
    wrapped = GoExploreWrapper(
        env,
        "env_default",
        go_steps=go_steps,
        explore_steps=0,
        end_go_on_success=True,
        success_distance=success_distance,
    )
    wrapped.scheduler = IBCCurriculumScheduler(wrapped.task_goals, _SuccessTest(wrapped), **kwargs)
    return wrapped


class _SuccessTest:
    """``success(achieved_goal, goal)`` of a goal-commanding wrapper (picklable, unlike a lambda)."""

    def __init__(self, wrapper: GoExploreWrapper) -> None:
        self.wrapper = wrapper

    def __call__(self, achieved_goal: np.ndarray, goal: np.ndarray) -> bool:
        return self.wrapper.is_success(achieved_goal, np.asarray(goal, dtype=np.float64), {})


def find_ibc_scheduler(env: gym.Env) -> IBCCurriculumScheduler | None:
    """The IBC scheduler inside one (wrapped) env, if any."""
    wrapper = unwrap_wrapper(env, GoExploreWrapper)
    scheduler = None if wrapper is None else wrapper.scheduler
    return scheduler if isinstance(scheduler, IBCCurriculumScheduler) else None

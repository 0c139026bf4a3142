"""The chapter's metric: greedy success at reaching *every* goal (thesis Sec. 6.5.1).

Unlike Go-Explore, which scores one final goal, the thesis tests "the ability of the agent to reach every
possible state in the whole state space" with the greedy policy. :func:`evaluate_all_goals` does this for
discrete goal envs (every reachable goal of a :class:`~sb3_gcrl.imgep.TabularGoalEnv`) and for continuous goal
envs (a fixed grid of goals over the reachable space, commanded through ``reset(options={"goal": g})`` of
:class:`~sb3_gcrl.post_exploration.PostExplorationWrapper` or any env accepting that option; named grids in
:data:`GOAL_GRIDS`); :class:`AllGoalsEvalCallback` runs it periodically, logs ``eval/all_goals_success`` with the
visitation entropy (Eq. 6.7) and coverage of the training data, and keeps one row per evaluation
(:data:`ALL_GOALS_COLUMNS`), which ``sb3-gcrl compare`` stores as ``all_goals.csv``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_gcrl.common.validation import check_int, check_optional_int
from sb3_gcrl.post_exploration.interface import GoalExplorationAgent
from sb3_gcrl.post_exploration.metrics import coverage, training_visit_counts, visitation_entropy

#: columns of an all-goals evaluation row (:attr:`AllGoalsEvalCallback.records`; ``all_goals.csv`` of a comparison)
ALL_GOALS_COLUMNS: tuple[str, ...] = (
    "timesteps",
    "num_timesteps",
    "all_goals_success",
    "n_goals",
    "visitation_entropy",
    "coverage",
)


def evaluate_all_goals(
    model: BaseAlgorithm,
    env: gym.Env,
    goals: np.ndarray | None = None,
    max_steps: int | None = None,
    stop_on_loop: bool = True,
) -> np.ndarray:
    """Greedy success for every goal (one episode per goal).

    :param model: a goal-conditioned model (``predict`` on Dict observations).
    :param env: a goal env whose ``reset(options={"goal": g})`` commands ``g`` and whose ``info["is_success"]``
        says whether it was reached (e.g. :class:`~sb3_gcrl.imgep.TabularGoalEnv` with ``terminate_at_goal``).
    :param goals: goals to test (default: ``env.reachable_goals``).
    :param max_steps: step cap per goal (default: the env's time limit ends the episode).
    :param stop_on_loop: stop a goal as failed as soon as the greedy policy revisits an observation (Discrete
        observations only). Exact for deterministic envs and policies (the tabular MiniGrid tasks): the agent is
        then in a cycle; pass False for an env with random transitions.
    :return: boolean array, one entry per goal.
    """
    if goals is None:
        try:
            goals = env.get_wrapper_attr("reachable_goals")
        except AttributeError:
            raise ValueError("Pass goals=... (the env declares no reachable_goals)") from None
    goals = np.asarray(goals)
    detect_loops = (
        stop_on_loop
        and isinstance(env.observation_space, gym.spaces.Dict)
        and isinstance(env.observation_space["observation"], gym.spaces.Discrete)
    )
    success = np.zeros(len(goals), dtype=bool)
    for i, goal in enumerate(goals):
        obs, _ = env.reset(options={"goal": goal})
        seen: set[int] = set()
        steps = 0
        while True:
            if detect_loops:
                state = int(obs["observation"])
                if state in seen:
                    break
                seen.add(state)
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
            if info.get("is_success", False):
                success[i] = True
                break
            if terminated or truncated or (max_steps is not None and steps >= max_steps):
                break
    return success


def fetch_target_grid(env: gym.Env) -> np.ndarray:
    """3 x 3 x 3 goals around the initial gripper position of a Fetch task, spanning its target range.

    :param env: a gymnasium-robotics Fetch env (``initial_gripper_xpos`` and ``target_range``), possibly wrapped.
    :return: array ``(27, 3)``.
    """
    base = env.unwrapped
    if not hasattr(base, "initial_gripper_xpos") or not hasattr(base, "target_range"):
        raise TypeError(f"goals='fetch_target_grid' needs a Fetch env, got {type(base).__name__}")
    centre, radius = np.asarray(base.initial_gripper_xpos), float(base.target_range)
    axes = [np.linspace(c - radius, c + radius, 3) for c in centre]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def maze_cell_grid(env: gym.Env) -> np.ndarray:
    """4 goals in each free cell of a gymnasium-robotics maze (offsets of a quarter cell from its centre).

    :param env: a PointMaze / AntMaze env (``maze`` with ``maze_map`` and ``cell_rowcol_to_xy``), possibly wrapped.
    :return: array ``(4 * n_free_cells, 2)``.
    """
    maze = getattr(env.unwrapped, "maze", None)
    if maze is None:
        raise TypeError(f"goals='maze_cells' needs a maze env, got {type(env.unwrapped).__name__}")
    offsets = np.array([[-0.25, -0.25], [-0.25, 0.25], [0.25, -0.25], [0.25, 0.25]]) * maze.maze_size_scaling
    cells = [
        maze.cell_rowcol_to_xy(np.array([i, j]))
        for i, row in enumerate(maze.maze_map)
        for j, cell in enumerate(row)
        if cell != 1  # free cells, reset and goal cells included
    ]
    return np.concatenate([cell + offsets for cell in cells])


#: named evaluation goal sets (YAML: ``goals: maze_cells``), each built from the evaluation env
GOAL_GRIDS: dict[str, Callable[[gym.Env], np.ndarray]] = {
    "fetch_target_grid": fetch_target_grid,
    "maze_cells": maze_cell_grid,
}


def recreate_env(env_spec: gym.envs.registration.EnvSpec | None, base_only: bool = False) -> gym.Env:
    """A fresh copy of an env from the spec of a built one: its id, constructor kwargs and the wrappers that
    record their constructor arguments (``env_wrapper`` of an RL-Zoo config); the others (SB3's ``Monitor``, which
    RL-Zoo puts below ``env_wrapper``) cannot be rebuilt and are left out.

    :param env_spec: ``env.spec`` of the built env (gymnasium lists its wrappers in ``additional_wrappers``).
    :param base_only: build the registered env only (no additional wrapper).
    :return: the new env.
    :raises ValueError: for an env without a spec (not made by ``gym.make``), naming ``eval_env=...``.
    """
    if env_spec is None:
        raise ValueError(
            "AllGoalsEvalCallback: the training env has no spec (not made by gym.make), so no evaluation env "
            "can be built from it; pass eval_env=..."
        )
    wrappers = () if base_only else tuple(w for w in env_spec.additional_wrappers if w.kwargs is not None)
    return gym.make(replace(env_spec, additional_wrappers=wrappers))


class AllGoalsEvalCallback(BaseCallback):
    """Every ``eval_freq`` steps, evaluate the greedy success rate over all goals (thesis Sec. 6.5.1).

    Each evaluation is logged (``eval/all_goals_success``, and ``eval/visitation_entropy`` / ``eval/coverage``
    when the training data has visit counts) and kept as a row of :attr:`records` (columns
    :data:`ALL_GOALS_COLUMNS`; ``timesteps`` is the scheduled step ``k * eval_freq``, ``num_timesteps`` the step
    at which it ran), as in :attr:`timesteps` / :attr:`success_rates` / :attr:`per_goal` (per goal), for the
    curves of Fig. 6.3 / 6.5. The visitation entropy (Eq. 6.7) and coverage are those of the agent's own goal
    space when it is a :class:`~sb3_gcrl.post_exploration.interface.GoalExplorationAgent`
    (:class:`~sb3_gcrl.imgep.TabularIMGEP`: reachable cells), else those of the training envs'
    :class:`~sb3_gcrl.post_exploration.PostExplorationWrapper` bins (all bins of the goal box); NaN without either.

    :param eval_env: separate goal env for evaluation (see :func:`evaluate_all_goals`). None: built at the start
        of training: the agent's ``make_all_goals_env()`` for a
        :class:`~sb3_gcrl.post_exploration.interface.GoalExplorationAgent` (``TabularGoalEnv(gym.make(env_id,
        **kwargs))`` for a :class:`~sb3_gcrl.imgep.TabularIMGEP`), else the training env rebuilt from its spec with
        the wrappers that record their constructor arguments (the ``env_wrapper`` of an RL-Zoo config, left in
        episodic mode).
    :param eval_freq: evaluate every this many training env steps (at the first step at or past each multiple,
        so any ``n_envs`` works), at the start and at the end of training. ``sb3-gcrl compare`` sets it to the
        run's ``eval_freq`` so that the rows line up with ``evaluations.csv``.
    :param goals: goals to test: an array, a name in :data:`GOAL_GRIDS` (deep tasks: ``"fetch_target_grid"``,
        ``"maze_cells"``), or None for the env's ``reachable_goals`` (tabular tasks).
    :param max_steps: step cap per goal (None: the env's time limit).
    :param verbose: 1 prints each result.
    """

    def __init__(
        self,
        eval_env: gym.Env | None = None,
        eval_freq: int = 10_000,
        goals: np.ndarray | str | None = None,
        max_steps: int | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if isinstance(goals, str) and goals not in GOAL_GRIDS:
            raise ValueError(f"Unknown goal grid {goals!r}; choose one of {sorted(GOAL_GRIDS)} or pass an array")
        self.eval_env = eval_env
        self.eval_freq = check_int("eval_freq", eval_freq)
        self.goals = goals
        self.max_steps = check_optional_int("max_steps", max_steps)
        self.timesteps: list[int] = []
        self.success_rates: list[float] = []
        self.per_goal: list[np.ndarray] = []
        self.records: list[dict[str, float]] = []
        self._last_eval = -1
        self._next_eval = self.eval_freq
        self._scheduled = 0

    def _build_eval_env(self) -> gym.Env:
        """The evaluation env when none was given (see ``eval_env``)."""
        if isinstance(self.model, GoalExplorationAgent):
            return self.model.make_all_goals_env()
        return recreate_env(self.training_env.get_attr("spec", indices=[0])[0])

    def _evaluate(self) -> None:
        if self._last_eval == self.num_timesteps:
            return  # on_training_end may follow an evaluation at the same step
        self._last_eval = self.num_timesteps
        if self.eval_env is None:  # built at the first evaluation (the start of training)
            self.eval_env = self._build_eval_env()
            self.eval_env.reset(seed=None if self.model.seed is None else self.model.seed + 1)
        if isinstance(self.goals, str):
            self.goals = GOAL_GRIDS[self.goals](self.eval_env)
        success = evaluate_all_goals(self.model, self.eval_env, self.goals, self.max_steps)  # type: ignore[arg-type]
        entropy, visited = self._visit_statistics()
        self.timesteps.append(self.num_timesteps)
        self.success_rates.append(float(success.mean()))
        self.per_goal.append(success)
        self.records.append(
            {
                "timesteps": int(self._scheduled),
                "num_timesteps": int(self.num_timesteps),
                "all_goals_success": float(success.mean()),
                "n_goals": int(success.size),
                "visitation_entropy": entropy,
                "coverage": visited,
            }
        )
        self.logger.record("eval/all_goals_success", float(success.mean()))
        if not math.isnan(entropy):
            self.logger.record("eval/visitation_entropy", entropy)
            self.logger.record("eval/coverage", visited)
        if self.verbose:
            print(f"{self.num_timesteps} steps: success over {success.size} goals = {success.mean():.3f}")

    def _visit_statistics(self) -> tuple[float, float]:
        """Visitation entropy (Eq. 6.7) and coverage of the training data so far (NaN, NaN when not counted)."""
        if isinstance(self.model, GoalExplorationAgent):
            return float(self.model.visitation_entropy()), float(self.model.coverage())
        counts = training_visit_counts(self.training_env) if isinstance(self.training_env, VecEnv) else None
        if counts is None:
            return math.nan, math.nan
        return visitation_entropy(counts), coverage(counts)

    def _on_training_start(self) -> None:
        self._scheduled = self.num_timesteps
        self._evaluate()
        self._next_eval = (self.num_timesteps // self.eval_freq + 1) * self.eval_freq

    def _on_step(self) -> bool:
        # ">=" and not "% eval_freq == 0": with n_envs > 1, num_timesteps grows by n_envs and can skip multiples
        if self.num_timesteps >= self._next_eval:
            self._scheduled = (self.num_timesteps // self.eval_freq) * self.eval_freq
            self._evaluate()
            self._next_eval = (self.num_timesteps // self.eval_freq + 1) * self.eval_freq
        return True

    def _on_training_end(self) -> None:
        self._scheduled = self.num_timesteps
        self._evaluate()

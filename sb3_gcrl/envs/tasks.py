"""The one table of the package's tasks: how each is registered, evaluated and trained.

:data:`TASKS` holds every ``GCRL/`` id with its entry point, its evaluation horizon (the registered
``max_episode_steps``), its training horizon (the hard-reset interval of a reset-free task), its goal space and its
success threshold. :func:`sb3_gcrl.envs.register_envs` registers from it, and
:class:`~sb3_gcrl.wrappers.ResetFreeWrapper` reads a task's hard-reset interval and evaluation horizon from it, so a
config states neither (a config may still override them, e.g. for an env of your own).

The reset-free tasks (thesis Section 3.7.1) carry their EARL/IBC protocol; each env module documents its task's
thesis source, spaces, reward and departures (table: docs/envs.md and docs/reset_free_envs.md).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

import sb3_gcrl.envs.reset_free.ant as ant
import sb3_gcrl.envs.reset_free.fetch as fetch
import sb3_gcrl.envs.reset_free.sawyer_door as sawyer_door
import sb3_gcrl.envs.reset_free.tabletop as tabletop
from sb3_gcrl.envs.point_maze import (
    FOUR_ROOMS_GOAL_CELL,
    FOUR_ROOMS_MAP,
    FOUR_ROOMS_START_CELL,
    FOUR_ROOMS_SUBGOAL_CELLS,
    SUCCESS_RADIUS,
)
from sb3_gcrl.envs.safety_nav import GOAL_SIZE


@dataclass(frozen=True)
class Task:
    """One registered task (thesis section in ``source``).

    :param env_id: registered id (``GCRL/...``).
    :param entry_point: ``module:callable`` that makes the env.
    :param eval_horizon: steps of an evaluation episode, the registered ``max_episode_steps`` (``None``: the env
        ends its episodes itself, as MiniGrid does).
    :param source: where the task comes from (thesis chapter, original benchmark).
    :param kwargs: keyword arguments of the entry point.
    :param hard_reset_every: for a reset-free task, the env steps between two physical resets in training (its
        training horizon; EARL/IBC protocol); ``None`` for an episodic task.
    :param goal_low: lower corner of the reachable goal-space box (binned visited-goal schedulers, visitation
        heatmaps); ``None`` where the task states none.
    :param goal_high: upper corner of that box.
    :param success_threshold: distance to the goal within which an episode counts as a success (the env's own
        test; ``None`` for tasks whose success is not a distance, e.g. reaching a grid cell).
    :param visitation_dims: the two goal dimensions a state-visitation heatmap shows, as the thesis's do (Figs.
        3.9-3.12): the mug's XY on Tabletop, the block's XZ on Pick&Place (hard), else the first two.
    :param requires: import names of optional packages the task needs: its id is registered only where all are
        installed (empty: always registered).
    """

    env_id: str
    entry_point: str
    eval_horizon: int | None
    source: str
    kwargs: dict[str, Any] = field(default_factory=dict, hash=False)  # a task stays hashable
    hard_reset_every: int | None = None
    goal_low: tuple[float, ...] | None = None
    goal_high: tuple[float, ...] | None = None
    success_threshold: float | None = None
    visitation_dims: tuple[int, int] = (0, 1)
    requires: tuple[str, ...] = ()

    @property
    def reset_free(self) -> bool:
        """Whether the task is one of the reset-free suite (it has a hard-reset interval)."""
        return self.hard_reset_every is not None

    @property
    def installed(self) -> bool:
        """Whether the optional packages the task needs (``requires``) are installed; imports none of them."""
        return all(importlib.util.find_spec(name) is not None for name in self.requires)

    @property
    def train_horizon(self) -> int | None:
        """Env steps between physical resets in training: the hard-reset interval of a reset-free task, else the
        evaluation horizon (episodic training)."""
        return self.hard_reset_every if self.reset_free else self.eval_horizon


_FOUR_ROOMS = {"maze_map": FOUR_ROOMS_MAP, "start_cell": FOUR_ROOMS_START_CELL, "goal_cell": FOUR_ROOMS_GOAL_CELL}
_MAZE = "sb3_gcrl.envs.point_maze"
_MINIGRID = "sb3_gcrl.envs.minigrid_tabular:make_tabular_minigrid"
_FETCH = "sb3_gcrl.envs.reset_free.fetch"
#: EARL's hard-reset interval (Tabletop, Sawyer Door, IBC PointUMaze, Ant; the default for an env of your own);
#: IBC's Fetch tasks reset every 1e5
EARL_HARD_RESET_EVERY = 200_000
_IBC_FETCH_HARD_RESET_EVERY = 100_000
#: what the real Safety-Gym tasks import (``pip install --no-deps safety-gymnasium==1.0.0 xmltodict``)
_SAFETY_GYMNASIUM = ("safety_gymnasium", "xmltodict")

#: Every task of the package, by id.
TASKS: dict[str, Task] = {
    task.env_id: task
    for task in (
        Task("GCRL/GrowingTree-v0", "sb3_gcrl.envs.growing_tree:GrowingTreeEnv", 200, "Ch. 4, Tab. 4.3"),
        Task("GCRL/GrowingTreeGoal-v0", "sb3_gcrl.envs.growing_tree:GrowingTreeGoalEnv", 200, "Ch. 4 (goal variant)"),
        Task("GCRL/WindyGrid-v0", "sb3_gcrl.envs.windy_grid:WindyGridEnv", 100, "Ch. 5, Fig. 5.4"),
        Task(
            "GCRL/SparseMountainCarContinuous-v0",
            "sb3_gcrl.envs.sparse_mountain_car:SparseMountainCarContinuousEnv",
            999,
            "Ch. 4, Fig. 4.4",
        ),
        Task(
            "GCRL/PointUMaze-v0", f"{_MAZE}:PointMazeTaskEnv", 1000, "Ch. 4, Fig. 4.3", success_threshold=SUCCESS_RADIUS
        ),
        Task(
            "GCRL/Point4Rooms-v0",
            f"{_MAZE}:PointMazeTaskEnv",
            1000,
            "Ch. 4, Fig. 4.3",
            kwargs=_FOUR_ROOMS,
            success_threshold=SUCCESS_RADIUS,
        ),
        Task(
            "GCRL/Point4RoomsSubgoals-v0",
            f"{_MAZE}:PointMazeTaskEnv",
            1000,
            "Ch. 4, Fig. 4.3 (mujoco_maze SubGoal4Rooms)",
            kwargs={**_FOUR_ROOMS, "subgoal_cells": FOUR_ROOMS_SUBGOAL_CELLS},
            success_threshold=SUCCESS_RADIUS,
        ),
        # 300 steps, not IBC's 100: IBC's maze is larger-scale; a waypoint controller needs ~160 steps in ours
        Task(
            "GCRL/PointUMazeGoal-v0",
            f"{_MAZE}:PointMazeGoalTaskEnv",
            300,
            "Ch. 3 (IBC PointUMaze), Ch. 6",
            hard_reset_every=EARL_HARD_RESET_EVERY,
            goal_low=(-1.5, -1.5),  # the U's free cells (cell size 1, walls from +-1.5 outwards)
            goal_high=(1.5, 1.5),
            success_threshold=SUCCESS_RADIUS,
        ),
        Task(
            "GCRL/Point4RoomsGoal-v0",
            f"{_MAZE}:PointMazeGoalTaskEnv",
            600,
            "Ch. 4 (goal variant)",
            kwargs=_FOUR_ROOMS,
            success_threshold=SUCCESS_RADIUS,
        ),
        # Safety-Gym's Goal0 level with the Point / Car robot (1000 steps as Safety-Gym)
        Task(
            "GCRL/PointGoal-v0",
            "sb3_gcrl.envs.safety_nav:PointGoalEnv",
            1000,
            "Ch. 4, Fig. 4.3, Tab. 4.2 (Safexp-PointGoal)",
            success_threshold=GOAL_SIZE,
        ),
        Task(
            "GCRL/CarGoal-v0",
            "sb3_gcrl.envs.safety_nav:CarGoalEnv",
            1000,
            "Ch. 4, Fig. 4.3, Tab. 4.2 (Safexp-CarGoal)",
            success_threshold=GOAL_SIZE,
        ),
        # safety-gymnasium's own Goal0 task and robots, where it is installed (the real env in the thesis's reading)
        Task(
            "GCRL/SafetyPointGoal0-v0",
            "sb3_gcrl.envs.safety_gymnasium_goal:SafetyGymnasiumGoalEnv",
            1000,
            "Ch. 4, Fig. 4.3 (safety-gymnasium SafetyPointGoal0-v0, sparse and terminating)",
            kwargs={"robot": "point"},
            success_threshold=GOAL_SIZE,
            requires=_SAFETY_GYMNASIUM,
        ),
        Task(
            "GCRL/SafetyCarGoal0-v0",
            "sb3_gcrl.envs.safety_gymnasium_goal:SafetyGymnasiumGoalEnv",
            1000,
            "Ch. 4, Fig. 4.3 (safety-gymnasium SafetyCarGoal0-v0, sparse and terminating)",
            kwargs={"robot": "car"},
            success_threshold=GOAL_SIZE,
            requires=_SAFETY_GYMNASIUM,
        ),
        # MiniGrid truncates at its own max_steps (FourRooms 100, LavaCrossingS9N1 324, LavaGapS7 196)
        Task(
            "GCRL/FourRoomsTabular-v0",
            _MINIGRID,
            None,
            "Ch. 6, Fig. 6.2 (MiniGrid FourRooms)",
            kwargs={"minigrid_id": "MiniGrid-FourRooms-v0", "cache_layout": True},
        ),
        Task(
            "GCRL/LavaCrossingTabular-v0",
            _MINIGRID,
            None,
            "Ch. 6, Fig. 6.2 (MiniGrid LavaCrossing)",
            kwargs={"minigrid_id": "MiniGrid-LavaCrossingS9N1-v0", "cache_layout": True},
        ),
        Task(
            "GCRL/LavaGapTabular-v0",
            _MINIGRID,
            None,
            "Ch. 6, Fig. 6.2 (MiniGrid LavaGap)",
            kwargs={"minigrid_id": "MiniGrid-LavaGapS7-v0", "cache_layout": True},
        ),
        # the reset-free suite of Ch. 3 (Section 3.7.1, Figure 3.3)
        Task(
            "GCRL/ErgodicFetchPush-v0",
            f"{_FETCH}:ErgodicFetchPushEnv",
            50,
            "Ch. 3 IBC ergodic Fetch Push",
            hard_reset_every=_IBC_FETCH_HARD_RESET_EVERY,
            goal_low=fetch.IBC_PUSH_GOAL_LOW,
            goal_high=fetch.IBC_PUSH_GOAL_HIGH,
            success_threshold=fetch.DISTANCE_THRESHOLD,
        ),
        Task(
            "GCRL/ErgodicFetchPickAndPlace-v0",
            f"{_FETCH}:ErgodicFetchPickAndPlaceEnv",
            50,
            "Ch. 3 IBC ergodic Fetch Pick&Place",
            hard_reset_every=_IBC_FETCH_HARD_RESET_EVERY,
            goal_low=fetch.IBC_PICK_AND_PLACE_GOAL_LOW,
            goal_high=fetch.IBC_PICK_AND_PLACE_GOAL_HIGH,
            success_threshold=fetch.DISTANCE_THRESHOLD,
        ),
        Task(
            "GCRL/FetchPushHard-v0",
            f"{_FETCH}:FetchPushHardEnv",
            50,
            "Ch. 3 Push (hard)",
            hard_reset_every=_IBC_FETCH_HARD_RESET_EVERY,
            goal_low=fetch.HARD_GOAL_LOW,
            goal_high=fetch.HARD_GOAL_HIGH,
            success_threshold=fetch.DISTANCE_THRESHOLD,
        ),
        Task(
            "GCRL/FetchPickAndPlaceHard-v0",
            f"{_FETCH}:FetchPickAndPlaceHardEnv",
            50,
            "Ch. 3 Pick&Place (hard)",
            hard_reset_every=_IBC_FETCH_HARD_RESET_EVERY,
            goal_low=fetch.HARD_GOAL_LOW,
            goal_high=fetch.HARD_GOAL_HIGH,
            success_threshold=fetch.DISTANCE_THRESHOLD,
            visitation_dims=(0, 2),  # Fig. 3.10: the block in the air
        ),
        Task(
            "GCRL/AntArena-v0",
            "sb3_gcrl.envs.reset_free.ant:AntArenaEnv",
            500,
            "Ch. 3 Ant (PEG's AntMaze, square arena)",
            hard_reset_every=EARL_HARD_RESET_EVERY,
            goal_low=ant.GOAL_LOW,
            goal_high=ant.GOAL_HIGH,
            success_threshold=ant.SUCCESS_THRESHOLD,
        ),
        Task(
            "GCRL/Tabletop-v0",
            "sb3_gcrl.envs.reset_free.tabletop:TabletopEnv",
            200,
            "Ch. 3 EARL Tabletop",
            hard_reset_every=EARL_HARD_RESET_EVERY,
            goal_low=tabletop.GOAL_LOW,
            goal_high=tabletop.GOAL_HIGH,
            success_threshold=tabletop.SUCCESS_THRESHOLD,
            visitation_dims=(2, 3),  # Fig. 3.9: the mug (the goal is fist xy, mug xy)
        ),
        Task(
            "GCRL/SawyerDoor-v0",
            "sb3_gcrl.envs.reset_free.sawyer_door:SawyerDoorEnv",
            300,
            "Ch. 3 EARL Sawyer Door (metaworld)",
            hard_reset_every=EARL_HARD_RESET_EVERY,
            goal_low=sawyer_door.GOAL_LOW,
            goal_high=sawyer_door.GOAL_HIGH,
            success_threshold=sawyer_door.SUCCESS_THRESHOLD,
        ),
    )
}

#: The reset-free suite's own envs (in :mod:`sb3_gcrl.envs.reset_free`; PointUMaze, its eighth task, is the Ch. 4
#: maze's goal variant)
RESET_FREE_ENV_IDS: tuple[str, ...] = tuple(
    task.env_id for task in TASKS.values() if task.entry_point.startswith("sb3_gcrl.envs.reset_free.")
)

#: The tasks that need an optional package (``Task.requires``), registered only where it is installed: the real
#: Safety-Gym tasks ``GCRL/SafetyPointGoal0-v0`` / ``GCRL/SafetyCarGoal0-v0`` (safety-gymnasium)
OPTIONAL_ENV_IDS: tuple[str, ...] = tuple(task.env_id for task in TASKS.values() if task.requires)


def find_task(env: gym.Env | str) -> Task | None:
    """The task of an env (made by ``gym.make`` from a registered id, any wrappers around it) or of an id.

    :param env: an env or an env id.
    :return: its :class:`Task`, or None for an env this package does not register (e.g. your own).
    """
    if isinstance(env, str):
        return TASKS.get(env)
    spec = env.unwrapped.spec
    return None if spec is None else TASKS.get(spec.id)


def register_tasks() -> None:
    """Register every task of :data:`TASKS` under its id (idempotent).

    ``GCRL/SawyerDoor-v0`` is always registered; making it without metaworld raises an ImportError that names the
    install command. The tasks of :data:`OPTIONAL_ENV_IDS` are registered only where their packages are installed.
    """
    for task in TASKS.values():
        if task.env_id not in gym.registry and task.installed:
            gym.register(
                task.env_id, entry_point=task.entry_point, max_episode_steps=task.eval_horizon, kwargs=task.kwargs
            )


__all__ = [
    "EARL_HARD_RESET_EVERY",
    "OPTIONAL_ENV_IDS",
    "RESET_FREE_ENV_IDS",
    "TASKS",
    "Task",
    "find_task",
    "register_tasks",
]

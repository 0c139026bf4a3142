"""Reset-free task suite of thesis Ch. 3 (Section 3.7.1, Figure 3.3) as registered goal environments.

Each env is a gymnasium-robotics-style goal env (Dict obs ``observation``/``achieved_goal``/``desired_goal``,
vectorised ``compute_reward``, ``info["is_success"]``) that declares its task-relevant goals on the unwrapped
env: ``sample_initial_goal(rng)`` (rho_0) and ``sample_evaluation_goal(rng)`` (rho_g*);
``reset(options={"goal": g})`` commands goal ``g`` instead of a draw from rho_g*. The envs themselves are
episodic (registered with ``max_episode_steps`` = the evaluation horizon); reset-free training wraps them
with the reset-free wrapper, using :data:`RESET_FREE_TASKS` for the hard-reset interval. PointUMaze, the
eighth task, is ``GCRL/PointUMazeGoal-v0``, registered by :mod:`sb3_gcrl.envs` with 300-step episodes; its entry
here carries the IBC reset-free protocol (evaluate 100 steps: pass ``eval_horizon`` to the reset-free wrapper).

=====================================  ==========  =================  =========================================
id                                     eval steps  hard reset every   source
=====================================  ==========  =================  =========================================
GCRL/ErgodicFetchPush-v0             50          1e5                IBC ergodic Fetch Push
GCRL/ErgodicFetchPickAndPlace-v0     50          1e5                IBC ergodic Fetch Pick&Place
GCRL/FetchPushHard-v0         50          1e5                thesis Push (hard)
GCRL/FetchPickAndPlaceHard-v0 50          1e5                thesis Pick&Place (hard)
GCRL/AntArena-v0              500         2e5                thesis Ant (from PEG's AntMaze)
GCRL/Tabletop-v0                       200         2e5                EARL Tabletop
GCRL/SawyerDoor-v0                     300         2e5                EARL Sawyer Door (needs metaworld)
GCRL/PointUMazeGoal-v0                 100         2e5                IBC PointUMaze (registered elsewhere)
=====================================  ==========  =================  =========================================
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym

from sb3_gcrl.envs.reset_free import ant, fetch, sawyer_door, tabletop


@dataclass(frozen=True)
class ResetFreeTask:
    """Evaluation protocol of one reset-free task (thesis Section 3.7.1).

    :param env_id: registered id.
    :param entry_point: ``module:Class`` of the env.
    :param eval_horizon: steps of an episodic evaluation episode (also the registered ``max_episode_steps``).
    :param hard_reset_every: physical reset interval of reset-free training (EARL/IBC/thesis).
    :param source: where the task comes from.
    :param goal_low: lower corner of the reachable goal-space box (for binned visited-goal schedulers such as
        the novelty scheduler's ``goal_low``, and for visitation heatmaps).
    :param goal_high: upper corner of that box.
    :param registered_here: False for PointUMaze, which :mod:`sb3_gcrl.envs` registers (with its own horizon).
    :param visitation_dims: the two goal dimensions a state-visitation heatmap shows, as the thesis's do (Figs.
        3.9-3.12): the mug's XY on Tabletop, the block's XZ on Pick&Place (hard), else the first two.
    """

    env_id: str
    entry_point: str
    eval_horizon: int
    hard_reset_every: int
    source: str
    goal_low: tuple[float, ...]
    goal_high: tuple[float, ...]
    registered_here: bool = True
    visitation_dims: tuple[int, int] = (0, 1)


_FETCH = "sb3_gcrl.envs.reset_free.fetch"
#: Every task of the suite by id. The reset-free configs read ``eval_horizon`` and ``hard_reset_every`` here.
RESET_FREE_TASKS: dict[str, ResetFreeTask] = {
    task.env_id: task
    for task in (
        ResetFreeTask(
            "GCRL/ErgodicFetchPush-v0",
            f"{_FETCH}:ErgodicFetchPushEnv",
            fetch.EVAL_HORIZON,
            fetch.HARD_RESET_EVERY,
            "IBC ergodic Fetch Push",
            fetch.IBC_PUSH_GOAL_LOW,
            fetch.IBC_PUSH_GOAL_HIGH,
        ),
        ResetFreeTask(
            "GCRL/ErgodicFetchPickAndPlace-v0",
            f"{_FETCH}:ErgodicFetchPickAndPlaceEnv",
            fetch.EVAL_HORIZON,
            fetch.HARD_RESET_EVERY,
            "IBC ergodic Fetch Pick&Place",
            fetch.IBC_PICK_AND_PLACE_GOAL_LOW,
            fetch.IBC_PICK_AND_PLACE_GOAL_HIGH,
        ),
        ResetFreeTask(
            "GCRL/FetchPushHard-v0",
            f"{_FETCH}:FetchPushHardEnv",
            fetch.EVAL_HORIZON,
            fetch.HARD_RESET_EVERY,
            "thesis Push (hard)",
            fetch.HARD_GOAL_LOW,
            fetch.HARD_GOAL_HIGH,
        ),
        ResetFreeTask(
            "GCRL/FetchPickAndPlaceHard-v0",
            f"{_FETCH}:FetchPickAndPlaceHardEnv",
            fetch.EVAL_HORIZON,
            fetch.HARD_RESET_EVERY,
            "thesis Pick&Place (hard)",
            fetch.HARD_GOAL_LOW,
            fetch.HARD_GOAL_HIGH,
            visitation_dims=(0, 2),  # Fig. 3.10: the block in the air
        ),
        ResetFreeTask(
            "GCRL/AntArena-v0",
            "sb3_gcrl.envs.reset_free.ant:AntArenaEnv",
            ant.EVAL_HORIZON,
            ant.HARD_RESET_EVERY,
            "thesis Ant (PEG AntMaze, square arena)",
            ant.GOAL_LOW,
            ant.GOAL_HIGH,
        ),
        ResetFreeTask(
            "GCRL/Tabletop-v0",
            "sb3_gcrl.envs.reset_free.tabletop:TabletopEnv",
            tabletop.EVAL_HORIZON,
            tabletop.HARD_RESET_EVERY,
            "EARL Tabletop",
            tabletop.GOAL_LOW,
            tabletop.GOAL_HIGH,
            visitation_dims=(2, 3),  # Fig. 3.9: the mug (the goal is fist xy, mug xy)
        ),
        ResetFreeTask(
            "GCRL/SawyerDoor-v0",
            "sb3_gcrl.envs.reset_free.sawyer_door:SawyerDoorEnv",
            sawyer_door.EVAL_HORIZON,
            sawyer_door.HARD_RESET_EVERY,
            "EARL Sawyer Door (metaworld)",
            sawyer_door.GOAL_LOW,
            sawyer_door.GOAL_HIGH,
        ),
        ResetFreeTask(
            "GCRL/PointUMazeGoal-v0",
            "sb3_gcrl.envs.point_maze:PointMazeGoalTaskEnv",
            100,
            200_000,
            "IBC PointUMaze",
            (-1.5, -1.5),  # the U's free cells (cell size 1, walls from +-1.5 outwards)
            (1.5, 1.5),
            registered_here=False,
        ),
    )
}
#: The ids this module registers (the suite without PointUMaze).
RESET_FREE_ENV_IDS: tuple[str, ...] = tuple(t.env_id for t in RESET_FREE_TASKS.values() if t.registered_here)


def register_reset_free_envs() -> None:
    """Register the reset-free task suite under ``GCRL/`` (idempotent).

    ``GCRL/SawyerDoor-v0`` is always registered; making it without metaworld raises an ImportError that names
    the install command.
    """
    for task in RESET_FREE_TASKS.values():
        if task.registered_here and task.env_id not in gym.registry:
            gym.register(id=task.env_id, entry_point=task.entry_point, max_episode_steps=task.eval_horizon)


__all__ = [
    "RESET_FREE_ENV_IDS",
    "RESET_FREE_TASKS",
    "ResetFreeTask",
    "register_reset_free_envs",
]

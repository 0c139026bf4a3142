"""The thesis's tasks as registered gymnasium environments (namespace ``GCRL/``).

:func:`register_envs` runs when ``sb3_gcrl`` is imported; it also registers the gymnasium-robotics
and MinAtar environments so that no extra user step is needed. ``GCRL_ENV_IDS`` lists our ids; each
module documents its task's thesis source, spaces, reward, horizon and departures (table: docs/envs.md).
"""

from __future__ import annotations

import importlib.util
from typing import Any

import gymnasium as gym

from sb3_gcrl.envs import robotics  # noqa: F401  (first: imports gymnasium-robotics quietly)
from sb3_gcrl.envs.growing_tree import GrowingTreeEnv, GrowingTreeGoalEnv
from sb3_gcrl.envs.minigrid_tabular import (
    FixedLayout,
    TabularMiniGridObservation,
    decode_state,
    encode_state,
    make_tabular_minigrid,
)
from sb3_gcrl.envs.point_maze import (
    FOUR_ROOMS_GOAL_CELL,
    FOUR_ROOMS_MAP,
    FOUR_ROOMS_START_CELL,
    FOUR_ROOMS_SUBGOAL_CELLS,
    PointMazeGoalTaskEnv,
    PointMazeTaskEnv,
)
from sb3_gcrl.envs.safety_nav import CarGoalEnv, PointGoalEnv, SafetyGoalEnv
from sb3_gcrl.envs.sparse_mountain_car import SparseMountainCarContinuousEnv
from sb3_gcrl.envs.windy_grid import (
    WindyGridEnv,
    windy_grid_optimal_value,
    windy_grid_policy_value,
    windy_grid_value_iteration,
)

NAMESPACE = "GCRL"

_FOUR_ROOMS = {"maze_map": FOUR_ROOMS_MAP, "start_cell": FOUR_ROOMS_START_CELL, "goal_cell": FOUR_ROOMS_GOAL_CELL}

# id -> (entry point, max_episode_steps, kwargs)
_ENV_SPECS: dict[str, tuple[str, int | None, dict]] = {
    "GCRL/GrowingTree-v0": ("sb3_gcrl.envs.growing_tree:GrowingTreeEnv", 200, {}),
    "GCRL/GrowingTreeGoal-v0": ("sb3_gcrl.envs.growing_tree:GrowingTreeGoalEnv", 200, {}),
    "GCRL/WindyGrid-v0": ("sb3_gcrl.envs.windy_grid:WindyGridEnv", 100, {}),
    "GCRL/SparseMountainCarContinuous-v0": (
        "sb3_gcrl.envs.sparse_mountain_car:SparseMountainCarContinuousEnv",
        999,
        {},
    ),
    "GCRL/PointUMaze-v0": ("sb3_gcrl.envs.point_maze:PointMazeTaskEnv", 1000, {}),
    "GCRL/Point4Rooms-v0": ("sb3_gcrl.envs.point_maze:PointMazeTaskEnv", 1000, _FOUR_ROOMS),
    "GCRL/PointUMazeGoal-v0": ("sb3_gcrl.envs.point_maze:PointMazeGoalTaskEnv", 300, {}),
    "GCRL/Point4RoomsGoal-v0": ("sb3_gcrl.envs.point_maze:PointMazeGoalTaskEnv", 600, _FOUR_ROOMS),
    "GCRL/Point4RoomsSubgoals-v0": (
        "sb3_gcrl.envs.point_maze:PointMazeTaskEnv",
        1000,
        {**_FOUR_ROOMS, "subgoal_cells": FOUR_ROOMS_SUBGOAL_CELLS},
    ),
    # Safety-Gym's Goal0 level with the Point / Car robot (1000 steps as Safety-Gym).
    "GCRL/PointGoal-v0": ("sb3_gcrl.envs.safety_nav:PointGoalEnv", 1000, {}),
    "GCRL/CarGoal-v0": ("sb3_gcrl.envs.safety_nav:CarGoalEnv", 1000, {}),
    # MiniGrid truncates at its own max_steps (FourRooms 100, LavaCrossingS9N1 324, LavaGapS7 196).
    "GCRL/FourRoomsTabular-v0": (
        "sb3_gcrl.envs.minigrid_tabular:make_tabular_minigrid",
        None,
        {"minigrid_id": "MiniGrid-FourRooms-v0", "cache_layout": True},
    ),
    "GCRL/LavaCrossingTabular-v0": (
        "sb3_gcrl.envs.minigrid_tabular:make_tabular_minigrid",
        None,
        {"minigrid_id": "MiniGrid-LavaCrossingS9N1-v0", "cache_layout": True},
    ),
    "GCRL/LavaGapTabular-v0": (
        "sb3_gcrl.envs.minigrid_tabular:make_tabular_minigrid",
        None,
        {"minigrid_id": "MiniGrid-LavaGapS7-v0", "cache_layout": True},
    ),
}

GCRL_ENV_IDS: tuple[str, ...] = tuple(_ENV_SPECS)
"""Every environment id this package registers itself (the reset-free suite adds its own)."""

MINATAR_ENV_IDS: tuple[str, ...] = tuple(
    f"MinAtar/{game}-v1" for game in ("Breakout", "SpaceInvaders", "Asterix", "Seaquest", "Freeway")
)
"""The five MinAtar games of the 2M chapter, registered by :func:`register_envs` (minimal action sets)."""


#: MinAtar's games (module names), registered by :func:`register_envs` as ``minatar.gym.register_envs`` does
_MINATAR_GAMES: tuple[str, ...] = ("asterix", "breakout", "freeway", "seaquest", "space_invaders")


#: what installs MinAtar (an optional extra: only the 2M chapter uses its games)
MINATAR_EXTRA = "pip install 'sb3-gcrl[minatar]'"


def minatar_missing(**kwargs: Any) -> gym.Env:
    """Entry point of the MinAtar ids when MinAtar is not installed: an error naming the extra that installs it.

    :param kwargs: the id's arguments (unused).
    :raises ModuleNotFoundError: always.
    """
    raise ModuleNotFoundError(
        f"The MinAtar games (thesis Ch. 5) need the MinAtar package, an optional extra of sb3-gcrl: {MINATAR_EXTRA}"
    )


def _register_minatar() -> None:
    """Register MinAtar's ids as ``minatar.gym.register_envs`` does (v0: full action set, v1: minimal), by entry
    point: importing MinAtar loads matplotlib and seaborn for its renderer (seconds), so it waits for ``gym.make``.
    Without MinAtar installed the ids still exist and say how to install it (:func:`minatar_missing`)."""
    entry_point = "minatar.gym:BaseEnv" if importlib.util.find_spec("minatar") else f"{__name__}:minatar_missing"
    for game in _MINATAR_GAMES:
        name = game.title().replace("_", "")
        for version, minimal in (("v0", False), ("v1", True)):
            env_id = f"MinAtar/{name}-{version}"
            if env_id not in gym.registry:
                kwargs = {"game": game, "use_minimal_action_set": minimal}
                gym.register(env_id, entry_point=entry_point, kwargs=kwargs)


def _register_third_party() -> None:
    import gymnasium_robotics

    gym.register_envs(gymnasium_robotics)
    _register_minatar()


def register_envs() -> None:
    """Register every environment of the package (idempotent)."""
    _register_third_party()
    for env_id, (entry_point, max_episode_steps, kwargs) in _ENV_SPECS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=entry_point, max_episode_steps=max_episode_steps, kwargs=kwargs)
    from sb3_gcrl.envs.reset_free import register_reset_free_envs  # reset-free task suite (thesis Ch. 3)

    register_reset_free_envs()


__all__ = [
    "GCRL_ENV_IDS",
    "MINATAR_ENV_IDS",
    "NAMESPACE",
    "CarGoalEnv",
    "FixedLayout",
    "GrowingTreeEnv",
    "GrowingTreeGoalEnv",
    "PointMazeGoalTaskEnv",
    "PointGoalEnv",
    "PointMazeTaskEnv",
    "SafetyGoalEnv",
    "SparseMountainCarContinuousEnv",
    "TabularMiniGridObservation",
    "WindyGridEnv",
    "decode_state",
    "encode_state",
    "make_tabular_minigrid",
    "register_envs",
    "windy_grid_optimal_value",
    "windy_grid_policy_value",
    "windy_grid_value_iteration",
]

"""The thesis's tasks as registered gymnasium environments (namespace ``GCRL/``).

:func:`register_envs` runs when ``sb3_gcrl`` is imported; it also registers the gymnasium-robotics
and MinAtar environments so that no extra user step is needed. ``GCRL_ENV_IDS`` lists our ids; each
module documents its task's thesis source, spaces, reward, horizon and departures (table: docs/envs.md).
:data:`~sb3_gcrl.envs.tasks.TASKS` is the one table of the tasks (horizons, goal space, success threshold).
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
from sb3_gcrl.envs.point_maze import PointMazeGoalTaskEnv, PointMazeTaskEnv
from sb3_gcrl.envs.safety_nav import CarGoalEnv, PointGoalEnv, SafetyGoalEnv
from sb3_gcrl.envs.sparse_mountain_car import SparseMountainCarContinuousEnv
from sb3_gcrl.envs.tasks import OPTIONAL_ENV_IDS, RESET_FREE_ENV_IDS, TASKS, Task, find_task, register_tasks
from sb3_gcrl.envs.windy_grid import (
    WindyGridEnv,
    windy_grid_optimal_value,
    windy_grid_policy_value,
    windy_grid_value_iteration,
)

NAMESPACE = "GCRL"

GCRL_ENV_IDS: tuple[str, ...] = tuple(
    task.env_id for task in TASKS.values() if task.env_id not in (*RESET_FREE_ENV_IDS, *OPTIONAL_ENV_IDS)
)
"""The package's ids outside the reset-free suite of Ch. 3 (:data:`~sb3_gcrl.envs.tasks.RESET_FREE_ENV_IDS`, which
needs MuJoCo scenes, and metaworld for Sawyer Door) and outside the tasks of optional packages
(:data:`~sb3_gcrl.envs.tasks.OPTIONAL_ENV_IDS`); :data:`~sb3_gcrl.envs.tasks.TASKS` has them all."""

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
    register_tasks()


__all__ = [
    "GCRL_ENV_IDS",
    "RESET_FREE_ENV_IDS",
    "MINATAR_ENV_IDS",
    "NAMESPACE",
    "OPTIONAL_ENV_IDS",
    "CarGoalEnv",
    "FixedLayout",
    "GrowingTreeEnv",
    "GrowingTreeGoalEnv",
    "PointMazeGoalTaskEnv",
    "PointGoalEnv",
    "PointMazeTaskEnv",
    "SafetyGoalEnv",
    "SparseMountainCarContinuousEnv",
    "TASKS",
    "Task",
    "TabularMiniGridObservation",
    "WindyGridEnv",
    "decode_state",
    "encode_state",
    "find_task",
    "make_tabular_minigrid",
    "register_envs",
    "windy_grid_optimal_value",
    "windy_grid_policy_value",
    "windy_grid_value_iteration",
]

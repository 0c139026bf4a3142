"""Reset-free task suite of thesis Ch. 3 (Section 3.7.1, Figure 3.3) as registered goal environments.

Each env is a gymnasium-robotics-style goal env (Dict obs ``observation``/``achieved_goal``/``desired_goal``,
vectorised ``compute_reward``, ``info["is_success"]``) that declares its task-relevant goals on the unwrapped
env: ``sample_initial_goal(rng)`` (rho_0) and ``sample_evaluation_goal(rng)`` (rho_g*);
``reset(options={"goal": g})`` commands goal ``g`` instead of a draw from rho_g*. The envs themselves are
episodic (registered with ``max_episode_steps`` = the evaluation horizon); reset-free training wraps them
with :class:`~sb3_gcrl.wrappers.ResetFreeWrapper`, which reads the hard-reset interval and the evaluation horizon
from the task table, :data:`sb3_gcrl.envs.tasks.TASKS`. PointUMaze, the eighth task, is ``GCRL/PointUMazeGoal-v0``.

=====================================  ==========  =================  =========================================
id                                     eval steps  hard reset every   source
=====================================  ==========  =================  =========================================
GCRL/ErgodicFetchPush-v0               50          1e5                IBC ergodic Fetch Push
GCRL/ErgodicFetchPickAndPlace-v0       50          1e5                IBC ergodic Fetch Pick&Place
GCRL/FetchPushHard-v0                  50          1e5                thesis Push (hard)
GCRL/FetchPickAndPlaceHard-v0          50          1e5                thesis Pick&Place (hard)
GCRL/AntArena-v0                       500         2e5                thesis Ant (from PEG's AntMaze)
GCRL/Tabletop-v0                       200         2e5                EARL Tabletop
GCRL/SawyerDoor-v0                     300         2e5                EARL Sawyer Door (needs metaworld)
GCRL/PointUMazeGoal-v0                 300         2e5                IBC PointUMaze (thesis: 100, larger maze)
=====================================  ==========  =================  =========================================

``RESET_FREE_TASKS``, ``RESET_FREE_ENV_IDS``, ``ResetFreeTask`` and ``register_reset_free_envs`` of this module are
deprecated names of the task table's (:mod:`sb3_gcrl.envs.tasks`), kept for one release.
"""

from __future__ import annotations

import warnings
from typing import Any

#: deprecated name -> (the name in :mod:`sb3_gcrl.envs.tasks`, what to use instead)
_DEPRECATED = {
    "RESET_FREE_TASKS": ("TASKS", "TASKS (the reset-free tasks are those with task.reset_free)"),
    "RESET_FREE_ENV_IDS": ("RESET_FREE_ENV_IDS", "RESET_FREE_ENV_IDS"),
    "ResetFreeTask": ("Task", "Task"),
    "register_reset_free_envs": ("register_tasks", "register_tasks"),
}


def __getattr__(name: str) -> Any:
    if name not in _DEPRECATED:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import sb3_gcrl.envs.tasks as tasks  # the table imports this package's env modules: import it when asked

    target, replacement = _DEPRECATED[name]
    warnings.warn(
        f"sb3_gcrl.envs.reset_free.{name} is deprecated: use sb3_gcrl.envs.tasks.{replacement}",
        DeprecationWarning,
        stacklevel=2,
    )
    if name == "RESET_FREE_TASKS":
        return {env_id: task for env_id, task in tasks.TASKS.items() if task.reset_free}
    return getattr(tasks, target)


__all__: list[str] = []

"""Wrappers of the reset-free setting (thesis Ch. 3): physical resets, goal commanding, Go/Explore phases.

Typical chain (innermost first): goal env -> :class:`IsSuccessWrapper` (only for envs without
``info["is_success"]``) -> :class:`ResetFreeWrapper` -> :class:`GoExploreWrapper` (or :class:`GoalCommandWrapper`).
All start in episodic mode; :class:`sb3_gcrl.callbacks.ResetFreeCallback` switches the training env to
reset-free mode, so evaluation envs built with the same wrappers stay episodic. Agents read and answer
:class:`GoExploreWrapper` through ``VecEnv.get_attr`` / ``env_method`` (``acting_policy``, goal requests of an
:class:`AgentGoalScheduler`), so any VecEnv works.
"""

from sb3_gcrl.wrappers.go_explore import EXECUTED_ACTION_KEY, GOAL_REQUEST_KEY, AgentGoalScheduler, GoExploreWrapper
from sb3_gcrl.wrappers.goal_command import GoalCommandWrapper
from sb3_gcrl.wrappers.goal_env import IsSuccessWrapper, check_goal_env
from sb3_gcrl.wrappers.reset_free import EARL_HARD_RESET_EVERY, ResetFreeWrapper

__all__ = [
    "EARL_HARD_RESET_EVERY",
    "EXECUTED_ACTION_KEY",
    "GOAL_REQUEST_KEY",
    "AgentGoalScheduler",
    "GoExploreWrapper",
    "GoalCommandWrapper",
    "IsSuccessWrapper",
    "ResetFreeWrapper",
    "check_goal_env",
]

"""Goal spaces and goal selection (step 2 of the GCRL loop): task-relevant goals, visited bins, schedulers."""

from sb3_gcrl.goals.goal_space import BinnedGoalSpace
from sb3_gcrl.goals.schedulers import (
    SCHEDULERS,
    BackAndForthScheduler,
    EnvDefaultScheduler,
    EvaluationGoalScheduler,
    GoalScheduler,
    NoveltyScheduler,
    UniformVisitedScheduler,
    make_scheduler,
)
from sb3_gcrl.goals.task_goals import TaskRelevantGoals, declared_task_goals, declares_task_goals

__all__ = [
    "SCHEDULERS",
    "BackAndForthScheduler",
    "BinnedGoalSpace",
    "EnvDefaultScheduler",
    "EvaluationGoalScheduler",
    "GoalScheduler",
    "NoveltyScheduler",
    "TaskRelevantGoals",
    "UniformVisitedScheduler",
    "declared_task_goals",
    "declares_task_goals",
    "make_scheduler",
]

"""HER replay buffers: executed-action storage and task-relevant relabeling (thesis Section 3.4.2)."""

from sb3_gcrl.common.validation import check_n_sampled_goal
from sb3_gcrl.her.executed_action import (
    ExecutedActionDictReplayBuffer,
    ExecutedActionHerReplayBuffer,
    ExecutedActionMixin,
    ExecutedActionReplayBuffer,
    check_stores_executed_actions,
)
from sb3_gcrl.her.task_relevant import TaskRelevantHerReplayBuffer

__all__ = [
    "ExecutedActionDictReplayBuffer",
    "ExecutedActionHerReplayBuffer",
    "ExecutedActionMixin",
    "ExecutedActionReplayBuffer",
    "TaskRelevantHerReplayBuffer",
    "check_n_sampled_goal",
    "check_stores_executed_actions",
]

"""HER replay buffers: executed-action storage and task-relevant relabeling (thesis Section 3.4.2), and the check that
the first update comes after the first reset-free segment."""

from sb3_gcrl.common.validation import check_n_sampled_goal
from sb3_gcrl.her.executed_action import (
    ExecutedActionDictReplayBuffer,
    ExecutedActionHerReplayBuffer,
    ExecutedActionMixin,
    ExecutedActionReplayBuffer,
    check_stores_executed_actions,
)
from sb3_gcrl.her.first_update import check_her_first_update
from sb3_gcrl.her.task_relevant import TaskRelevantHerReplayBuffer

__all__ = [
    "ExecutedActionDictReplayBuffer",
    "ExecutedActionHerReplayBuffer",
    "ExecutedActionMixin",
    "ExecutedActionReplayBuffer",
    "TaskRelevantHerReplayBuffer",
    "check_her_first_update",
    "check_n_sampled_goal",
    "check_stores_executed_actions",
]

"""Post-exploration (thesis Ch. 6): wrapper + callback for deep agents, length rules, metrics, evaluation.

Dependencies point one way: :mod:`sb3_gcrl.imgep` (the IMGEP loop, of which post-exploration is a step) uses this
package's rules, metrics and :class:`GoalExplorationAgent` interface; nothing here imports :mod:`sb3_gcrl.imgep`.
"""

from sb3_gcrl.post_exploration.callbacks import PostExplorationCallback
from sb3_gcrl.post_exploration.evaluation import AllGoalsEvalCallback, evaluate_all_goals
from sb3_gcrl.post_exploration.interface import GoalExplorationAgent
from sb3_gcrl.post_exploration.metrics import coverage, visitation_entropy
from sb3_gcrl.post_exploration.rules import (
    FixedSteps,
    NoveltyAdaptive,
    PostExplorationRule,
    ProportionalSteps,
    make_post_exploration_rule,
)
from sb3_gcrl.post_exploration.wrapper import POST_EXPLORATION_KEY, PostExplorationWrapper

__all__ = [
    "POST_EXPLORATION_KEY",
    "AllGoalsEvalCallback",
    "FixedSteps",
    "GoalExplorationAgent",
    "NoveltyAdaptive",
    "PostExplorationCallback",
    "PostExplorationRule",
    "PostExplorationWrapper",
    "ProportionalSteps",
    "coverage",
    "evaluate_all_goals",
    "make_post_exploration_rule",
    "visitation_entropy",
]

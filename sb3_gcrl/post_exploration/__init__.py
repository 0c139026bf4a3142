"""Post-exploration (thesis Ch. 6): wrapper + callback for deep agents, length rules, metrics, evaluation."""

from sb3_gcrl.post_exploration.callbacks import PostExplorationCallback
from sb3_gcrl.post_exploration.evaluation import AllGoalsEvalCallback, evaluate_all_goals
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

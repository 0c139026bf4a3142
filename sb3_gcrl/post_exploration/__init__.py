"""Post-exploration (thesis Ch. 6): rules for how long to explore after reaching a goal, metrics, evaluation."""

from sb3_gcrl.post_exploration.evaluation import AllGoalsEvalCallback, evaluate_all_goals
from sb3_gcrl.post_exploration.metrics import coverage, visitation_entropy
from sb3_gcrl.post_exploration.rules import (
    FixedSteps,
    NoveltyAdaptive,
    PostExplorationRule,
    ProportionalSteps,
    make_post_exploration_rule,
)

__all__ = [
    "AllGoalsEvalCallback",
    "FixedSteps",
    "NoveltyAdaptive",
    "PostExplorationRule",
    "ProportionalSteps",
    "coverage",
    "evaluate_all_goals",
    "make_post_exploration_rule",
    "visitation_entropy",
]

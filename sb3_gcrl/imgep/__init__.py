"""IMGEP agents of thesis Ch. 6: goal-conditioned tabular Q-learning with post-exploration and hindsight."""

from sb3_gcrl.imgep.imgep import TabularIMGEP
from sb3_gcrl.imgep.policies import TabularGoalPolicy
from sb3_gcrl.imgep.tabular_goal_env import TabularGoalEnv, minigrid_reachable_cells, minigrid_task_goal

__all__ = ["TabularGoalEnv", "TabularGoalPolicy", "TabularIMGEP", "minigrid_reachable_cells", "minigrid_task_goal"]

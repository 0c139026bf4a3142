"""sb3-gcrl: goal-conditioned RL methods of Zhao Yang's thesis (2025) for Stable-Baselines3.

Importing the package registers every environment (ours under the ``GCRL/`` namespace, plus the
gymnasium-robotics and MinAtar ones), so ``rl_zoo3 train --gym-packages sb3_gcrl`` sees them.
"""

from sb3_gcrl.callbacks import ResetFreeCallback, VisitationCallback
from sb3_gcrl.cec import CEC
from sb3_gcrl.emac import EMAC
from sb3_gcrl.envs import register_envs
from sb3_gcrl.her import ExecutedActionHerReplayBuffer, TaskRelevantHerReplayBuffer
from sb3_gcrl.ibc import IBC
from sb3_gcrl.imgep import TabularIMGEP
from sb3_gcrl.mfec import MFEC
from sb3_gcrl.morefree import MoReFree
from sb3_gcrl.post_exploration import PostExplorationCallback, PostExplorationWrapper
from sb3_gcrl.reset_free_baselines import MEDAL, R3L, ForwardBackwardWrapper
from sb3_gcrl.tabular import TabularEpisodicControl, TabularQLearning, TabularTwoMemory
from sb3_gcrl.two_memory import TwoMemoryDQN, TwoMemorySAC
from sb3_gcrl.version import __version__
from sb3_gcrl.wrappers import GoalCommandWrapper, GoExploreWrapper, ResetFreeWrapper

register_envs()

__all__ = [
    "CEC",
    "EMAC",
    "ExecutedActionHerReplayBuffer",
    "ForwardBackwardWrapper",
    "GoExploreWrapper",
    "GoalCommandWrapper",
    "IBC",
    "MEDAL",
    "MFEC",
    "MoReFree",
    "PostExplorationCallback",
    "PostExplorationWrapper",
    "R3L",
    "ResetFreeCallback",
    "ResetFreeWrapper",
    "TabularIMGEP",
    "TabularEpisodicControl",
    "TabularQLearning",
    "TabularTwoMemory",
    "TaskRelevantHerReplayBuffer",
    "TwoMemoryDQN",
    "TwoMemorySAC",
    "VisitationCallback",
    "__version__",
    "register_envs",
]

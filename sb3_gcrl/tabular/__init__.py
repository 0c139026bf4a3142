"""Tabular agents of thesis Sec. 5.5.1 (WindyGrid): Q-learning, episodic control, and their 2M combination."""

from sb3_gcrl.tabular.policies import TabularECPolicy, TabularQPolicy, TabularTwoMemoryPolicy
from sb3_gcrl.tabular.q_learning import TabularQLearning, q_learning_update
from sb3_gcrl.tabular.tabular_ec import TabularEpisodicControl
from sb3_gcrl.tabular.two_memory import TabularTwoMemory

__all__ = [
    "TabularECPolicy",
    "TabularEpisodicControl",
    "TabularQLearning",
    "TabularQPolicy",
    "TabularTwoMemory",
    "TabularTwoMemoryPolicy",
    "q_learning_update",
]

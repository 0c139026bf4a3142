"""sb3-gcrl: goal-conditioned RL methods of Zhao Yang's thesis (2025) for Stable-Baselines3.

Importing the package registers every environment (ours under the ``GCRL/`` namespace, plus the
gymnasium-robotics and MinAtar ones), so ``rl_zoo3 train --gym-packages sb3_gcrl`` sees them. The algorithms,
wrappers, callbacks and buffers below (and the subpackages) are imported on first access
(``sb3_gcrl.CEC``, ``from sb3_gcrl import CEC``), so that what needs no torch (the ``sb3-gcrl`` command line's
help, env registration) does not import torch, Stable-Baselines3 or RL-Zoo.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING, Any

from sb3_gcrl.envs import register_envs
from sb3_gcrl.version import __version__

if TYPE_CHECKING:
    from sb3_gcrl.callbacks import ResetFreeCallback, VisitationCallback
    from sb3_gcrl.cec import CEC
    from sb3_gcrl.emac import EMAC
    from sb3_gcrl.her import ExecutedActionHerReplayBuffer, TaskRelevantHerReplayBuffer
    from sb3_gcrl.imgep import TabularIMGEP
    from sb3_gcrl.mfec import MFEC
    from sb3_gcrl.morefree import MoReFree
    from sb3_gcrl.post_exploration import PostExplorationCallback, PostExplorationWrapper
    from sb3_gcrl.reset_free_baselines import IBC, MEDAL, R3L, ForwardBackwardWrapper
    from sb3_gcrl.tabular import TabularEpisodicControl, TabularQLearning, TabularTwoMemory
    from sb3_gcrl.two_memory import TwoMemoryDQN, TwoMemorySAC
    from sb3_gcrl.wrappers import GoalCommandWrapper, GoExploreWrapper, ResetFreeWrapper

#: exported name -> the subpackage that defines it (imported on first access)
_LAZY_EXPORTS: dict[str, str] = {
    "ResetFreeCallback": "callbacks",
    "VisitationCallback": "callbacks",
    "CEC": "cec",
    "EMAC": "emac",
    "ExecutedActionHerReplayBuffer": "her",
    "TaskRelevantHerReplayBuffer": "her",
    "IBC": "reset_free_baselines",
    "TabularIMGEP": "imgep",
    "MFEC": "mfec",
    "MoReFree": "morefree",
    "PostExplorationCallback": "post_exploration",
    "PostExplorationWrapper": "post_exploration",
    "MEDAL": "reset_free_baselines",
    "R3L": "reset_free_baselines",
    "ForwardBackwardWrapper": "reset_free_baselines",
    "TabularEpisodicControl": "tabular",
    "TabularQLearning": "tabular",
    "TabularTwoMemory": "tabular",
    "TwoMemoryDQN": "two_memory",
    "TwoMemorySAC": "two_memory",
    "GoalCommandWrapper": "wrappers",
    "GoExploreWrapper": "wrappers",
    "ResetFreeWrapper": "wrappers",
}


def __getattr__(name: str) -> Any:
    """Import an exported class (or a subpackage, ``sb3_gcrl.wrappers``) on first access.

    :param name: the attribute.
    :return: its value, cached in the package's namespace.
    """
    if name in _LAZY_EXPORTS:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY_EXPORTS[name]}"), name)
    elif importlib.util.find_spec(f"{__name__}.{name}") is not None:
        value = importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY_EXPORTS})


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

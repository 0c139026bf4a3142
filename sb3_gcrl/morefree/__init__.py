"""MoReFree on a world model (thesis Ch. 3): the model-based reset-free goal-conditioned agent.

Not to be confused with MoReFree-SAC (:mod:`sb3_gcrl.morefree_sac`), the model-free port of MoReFree's two
mechanisms on SAC + HER.
"""

from sb3_gcrl.morefree.buffer import SequenceReplayBuffer
from sb3_gcrl.morefree.diagnostics import MoReFreeDiagnosticsCallback
from sb3_gcrl.morefree.goals import PEGScheduler, morefree_go_explore
from sb3_gcrl.morefree.morefree import MoReFree
from sb3_gcrl.morefree.policies import CPU_NETWORK, THESIS_NETWORK, MoReFreePolicy

__all__ = [
    "CPU_NETWORK",
    "THESIS_NETWORK",
    "MoReFree",
    "MoReFreeDiagnosticsCallback",
    "MoReFreePolicy",
    "PEGScheduler",
    "SequenceReplayBuffer",
    "morefree_go_explore",
]

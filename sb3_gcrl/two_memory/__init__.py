"""Two-memory (2M) agents, thesis Ch. 5: per-episode dispatch between episodic control and an RL agent."""

from sb3_gcrl.two_memory.buffers import SourceTaggedReplayBuffer
from sb3_gcrl.two_memory.callbacks import TwoMemoryCallback
from sb3_gcrl.two_memory.dispatch import TwoMemoryDispatcher
from sb3_gcrl.two_memory.policies import (
    MinAtarCNN,
    MinAtarDQNPolicy,
    TwoMemoryDQNPolicy,
    TwoMemoryMinAtarPolicy,
    TwoMemoryMultiInputDQNPolicy,
    TwoMemoryMultiInputSACPolicy,
    TwoMemorySACPolicy,
)
from sb3_gcrl.two_memory.schedules import (
    EPISODIC,
    PARAMETRIC,
    AdaptiveSchedule,
    ConstantSchedule,
    ExponentialSchedule,
    PecSchedule,
    ScoreWindows,
    make_pec_schedule,
)
from sb3_gcrl.two_memory.two_memory import TwoMemoryDQN, TwoMemorySAC

__all__ = [
    "EPISODIC",
    "PARAMETRIC",
    "AdaptiveSchedule",
    "ConstantSchedule",
    "ExponentialSchedule",
    "MinAtarCNN",
    "MinAtarDQNPolicy",
    "PecSchedule",
    "ScoreWindows",
    "SourceTaggedReplayBuffer",
    "TwoMemoryCallback",
    "TwoMemoryDQN",
    "TwoMemoryDQNPolicy",
    "TwoMemoryDispatcher",
    "TwoMemoryMinAtarPolicy",
    "TwoMemoryMultiInputDQNPolicy",
    "TwoMemoryMultiInputSACPolicy",
    "TwoMemorySAC",
    "TwoMemorySACPolicy",
    "make_pec_schedule",
]

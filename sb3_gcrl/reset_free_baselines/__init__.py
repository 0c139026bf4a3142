"""Reset-free baselines of thesis Ch. 3: MEDAL, R3L and IBC (forward-backward agents built from SB3's SAC).

* :class:`ForwardBackwardWrapper` (with :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` below it): the forward and
  backward phases of the reset-free stream.
* :class:`ForwardBackwardSAC`: a forward SAC and a backward SAC acting and learning by phase, one buffer each (also
  the base of :class:`~sb3_gcrl.reset_free_baselines.IBC`).
* :class:`BackwardRewardSAC`: a :class:`ForwardBackwardSAC` whose backward policy learns from a learned reward model.
* :class:`MEDAL`: backward reward from a demonstration-state :class:`Discriminator`; demonstrations from
  :func:`load_demos` (shipped for some tasks, made by ``scripts/make_demos.py``).
* :class:`R3L`: backward reward from :class:`RND` novelty.
* :class:`IBC`: forward and backward agents with IBC's curriculum (:class:`IBCCurriculumScheduler`), whose phases
  and goals :func:`ibc_go_explore` puts on the package's Go/Explore wrapper.

Docs: ``docs/reset_free_baselines.md``.
"""

from sb3_gcrl.reset_free_baselines.backward_reward import BackwardRewardSAC
from sb3_gcrl.reset_free_baselines.buffers import PhaseReplayBuffer
from sb3_gcrl.reset_free_baselines.demos import Demonstrations, available_demos, load_demos
from sb3_gcrl.reset_free_baselines.forward_backward import ForwardBackwardSAC
from sb3_gcrl.reset_free_baselines.ibc import IBC
from sb3_gcrl.reset_free_baselines.ibc_curriculum import IBCCurriculumScheduler, find_ibc_scheduler, ibc_go_explore
from sb3_gcrl.reset_free_baselines.medal import MEDAL
from sb3_gcrl.reset_free_baselines.r3l import R3L
from sb3_gcrl.reset_free_baselines.reward_models import RND, Discriminator
from sb3_gcrl.reset_free_baselines.wrapper import ForwardBackwardScheduler, ForwardBackwardWrapper

__all__ = [
    "IBC",
    "MEDAL",
    "R3L",
    "RND",
    "BackwardRewardSAC",
    "Demonstrations",
    "Discriminator",
    "ForwardBackwardSAC",
    "ForwardBackwardScheduler",
    "ForwardBackwardWrapper",
    "IBCCurriculumScheduler",
    "PhaseReplayBuffer",
    "available_demos",
    "find_ibc_scheduler",
    "ibc_go_explore",
    "load_demos",
]

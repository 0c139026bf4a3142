"""SB3 base classes of the episodic-control algorithms (CEC, MFEC), on the memories of :mod:`sb3_gcrl.memory`.

* :class:`EpisodicControlPolicy` (:mod:`sb3_gcrl.episodic_control.policies`): a policy without parameters that holds
  an episodic memory and the observation -> key embedding, acts on numpy and saves the memory in its ``state_dict``.
* :class:`EpisodicControlAlgorithm` (:mod:`sb3_gcrl.episodic_control.algorithm`): the learn loop (act with the
  memory, update it from each finished episode's returns), its logs, seeding and model files.
"""

from sb3_gcrl.episodic_control.algorithm import EpisodicControlAlgorithm
from sb3_gcrl.episodic_control.policies import EpisodicControlPolicy

__all__ = ["EpisodicControlAlgorithm", "EpisodicControlPolicy"]

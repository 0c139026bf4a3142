"""Base classes and building blocks shared by the episodic-control algorithms (CEC, MFEC) and the 2M agents.

* :mod:`sb3_gcrl.common.episodic_control` — :class:`EpisodicControlPolicy`, :class:`EpisodicControlAlgorithm`
  (SB3 base classes of CEC and MFEC), :func:`memory_state` / :func:`load_memory_state` (an episodic memory in a
  policy's ``state_dict``) and :class:`MemoryRestoreError`.
* :mod:`sb3_gcrl.common.actors` — :func:`cec_actions`, :func:`mfec_actions`: how a memory picks actions.
* :mod:`sb3_gcrl.common.saving` — :class:`ModelFileMixin` (every algorithm of the package: atomic ``save`` that
  records the class, ``load`` that checks the file first and raises :class:`ModelFileError` naming the fix) and
  the atomic writes (:func:`atomic_file`).

The memories themselves (data structures) are in :mod:`sb3_gcrl.memory`.
"""

from sb3_gcrl.common.actors import cec_actions, mfec_actions
from sb3_gcrl.common.episodic_control import (
    EpisodicControlAlgorithm,
    EpisodicControlPolicy,
    MemoryRestoreError,
    load_memory_state,
    memory_state,
)
from sb3_gcrl.common.saving import ModelFileError, ModelFileMixin, atomic_file

__all__ = [
    "EpisodicControlAlgorithm",
    "EpisodicControlPolicy",
    "MemoryRestoreError",
    "ModelFileError",
    "ModelFileMixin",
    "atomic_file",
    "cec_actions",
    "load_memory_state",
    "memory_state",
    "mfec_actions",
]

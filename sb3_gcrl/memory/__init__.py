"""Episodic memories and their exact kNN backend (shared by CEC, MFEC and the 2M agents).

Public API (all batched over queries; keys are ``(n, key_dim)`` float32 arrays):

* :class:`KeyEmbedding` — observation (Box or Dict, e.g. ``observation`` + ``desired_goal``) ->
  key, with an optional seeded Gaussian random projection (thesis Section 4.4).
* :class:`CECMemory` — continuous episodic control table (thesis Eq. 4.3-4.5):
  ``update_episode(keys, actions, returns)``, ``select_actions(keys, rng) -> (actions, found)``,
  ``greedy_actions(keys) -> (actions, found)``, ``state_dict()/load_state_dict()``.
* :class:`MFECMemory` (one :class:`MFECTable` per action; thesis Eq. 5.2):
  ``estimate(keys) -> (n, n_actions)``, ``greedy_actions(keys, rng)``,
  ``update_episode(keys, actions, returns)``, ``state_dict()/load_state_dict()``.
* :class:`KNNValueTable` — bounded (key, value) rows with a kNN index and least-recently-updated eviction, the
  base of :class:`MFECTable` and EMAC's memory.
* :class:`KNNIndex` — exact Euclidean kNN over a preallocated, row-overwritable table
  (lazily rebuilt KD-tree + brute-forced delta, or faiss brute force).
* :class:`RecencyOrder` — O(1) least-recently-updated eviction order.
* :class:`EpisodeBuffers`, :func:`discounted_returns` — per-env running episodes and their returns (the one
  episode layer of CEC, MFEC, the 2M agents, tabular episodic control and EMAC); :class:`EpisodeRecorder` hands
  over each finished episode (:class:`FinishedEpisode`), :class:`EpisodeRecordingMixin` keeps one in an SB3
  algorithm (:mod:`sb3_gcrl.memory.episode`).
* :func:`cec_actions`, :func:`mfec_actions` — how a CEC or MFEC memory picks actions, for CEC/MFEC and the episodic
  half of the 2M agents (:mod:`sb3_gcrl.memory.actors`).
* :func:`memory_state`, :func:`load_memory_state`, :class:`MemoryRestoreError` — a memory and its key embedding in a
  policy's ``state_dict`` (:mod:`sb3_gcrl.memory.serialization`).

Hyperparameters and saved states are checked by :mod:`sb3_gcrl.common.validation` (errors name the
parameter); the SB3 base classes of CEC and MFEC, built on these memories, are in :mod:`sb3_gcrl.episodic_control`.
"""

from sb3_gcrl.memory.actors import cec_actions, mfec_actions
from sb3_gcrl.memory.cec_memory import CECMemory
from sb3_gcrl.memory.embedding import GOAL_ENV_KEYS, KeyEmbedding
from sb3_gcrl.memory.episode import (
    EpisodeBuffers,
    EpisodeRecorder,
    EpisodeRecordingMixin,
    FinishedEpisode,
    discounted_returns,
    truncated_ends,
)
from sb3_gcrl.memory.knn import KNNIndex
from sb3_gcrl.memory.mfec_memory import MFECMemory, MFECTable
from sb3_gcrl.memory.recency import RecencyOrder
from sb3_gcrl.memory.serialization import MemoryRestoreError, load_memory_state, memory_state
from sb3_gcrl.memory.value_table import KNNValueTable

__all__ = [
    "GOAL_ENV_KEYS",
    "CECMemory",
    "EpisodeBuffers",
    "EpisodeRecorder",
    "EpisodeRecordingMixin",
    "FinishedEpisode",
    "KNNIndex",
    "KNNValueTable",
    "KeyEmbedding",
    "MFECMemory",
    "MFECTable",
    "MemoryRestoreError",
    "RecencyOrder",
    "cec_actions",
    "discounted_returns",
    "load_memory_state",
    "memory_state",
    "mfec_actions",
    "truncated_ends",
]

"""An episodic memory and its key embedding inside a policy's ``state_dict``.

The policies that hold a memory (CEC, MFEC, the episodic half of the 2M agents, EMAC) put it into their
``state_dict`` through ``get_extra_state``: :func:`memory_state` turns the memory's used rows and the embedding's
projection matrix into tensors, so ``save``/``load`` restore them exactly inside the usual ``policy.pth`` of the SB3
zip; :func:`load_memory_state` restores them and raises :class:`MemoryRestoreError` when they do not fit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th

from sb3_gcrl.memory.embedding import KeyEmbedding


class MemoryRestoreError(RuntimeError):
    """A saved episodic memory cannot be restored (corrupted file, or memory settings that do not fit it).

    A ``RuntimeError`` on purpose: SB3's ``BaseAlgorithm.load`` re-raises a ``RuntimeError`` from
    ``set_parameters`` unchanged, whereas it treats a ``ValueError`` as an old DQN optimizer state and then
    fails with an unrelated ``KeyError: 'policy.optimizer'``. The memory's own error is the ``__cause__``.
    """


def memory_state(memory: Any, embedding: KeyEmbedding) -> dict[str, th.Tensor]:
    """An episodic memory (used rows only) and its key embedding as tensors, for a policy's ``get_extra_state``.

    :param memory: the memory (``CECMemory``, ``MFECMemory``: anything with ``state_dict()``).
    :param embedding: the observation -> key embedding (its projection matrix).
    :return: ``{"memory/<name>": tensor, "embedding/<name>": tensor}``.
    """
    state = {f"memory/{k}": th.as_tensor(np.asarray(v).copy()) for k, v in memory.state_dict().items()}
    state.update({f"embedding/{k}": th.as_tensor(np.asarray(v).copy()) for k, v in embedding.get_state().items()})
    return state


def _unprefixed(state: dict[str, th.Tensor], prefix: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in state.items():
        if key.startswith(prefix):
            array = value.cpu().numpy()
            out[key[len(prefix) :]] = array.item() if array.ndim == 0 else array  # e.g. the recency clock
    return out


def load_memory_state(owner: Any, memory: Any, embedding: KeyEmbedding, state: dict[str, th.Tensor]) -> None:
    """Restore what :func:`memory_state` returned, in place.

    :param owner: the policy being restored (named in the error).
    :param memory: the memory to restore (``load_state_dict``).
    :param embedding: the key embedding to restore (``set_state``).
    :param state: the tensors of :func:`memory_state`.
    :raises MemoryRestoreError: if the saved memory or projection cannot be restored; the memory's own error (what
        is missing, mis-shaped or corrupted) is in the message and is the ``__cause__``.
    """
    try:
        embedding.set_state(_unprefixed(state, "embedding/"))
        memory.load_state_dict(_unprefixed(state, "memory/"))
    except (ValueError, TypeError, KeyError, AttributeError) as error:
        raise MemoryRestoreError(
            f"The saved episodic memory cannot be restored into this {type(owner).__name__}: {error}"
        ) from error

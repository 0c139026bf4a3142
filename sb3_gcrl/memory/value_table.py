"""A bounded table of (key, value) rows with an exact kNN index and least-recently-updated eviction.

The common part of the value memories keyed by vectors: MFEC's per-action tables (thesis Eq. 5.2,
:class:`~sb3_gcrl.memory.MFECTable`) and EMAC's (state, action) memory (:class:`~sb3_gcrl.emac.EMACMemory`).
Subclasses decide how a key is written (merged with an equal key, or appended) and how a value is estimated.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from sb3_gcrl.common.validation import check_int, check_saved_rows
from sb3_gcrl.memory.knn import KNNBackend, KNNIndex
from sb3_gcrl.memory.recency import RecencyOrder


class KNNValueTable:
    """Rows ``(key, value)`` in a preallocated :class:`~sb3_gcrl.memory.KNNIndex`, a float64 value per row, and a
    :class:`~sb3_gcrl.memory.RecencyOrder` that picks the row a full table overwrites.

    :param key_dim: key dimension.
    :param capacity: maximum number of rows.
    :param n_neighbors: ``k`` of the kNN estimate.
    :param knn_backend: see :class:`~sb3_gcrl.memory.KNNIndex`.
    :param rebuild_threshold: see :class:`~sb3_gcrl.memory.KNNIndex`.
    """

    #: name of the capacity in error messages (the argument the user sets)
    capacity_name: ClassVar[str] = "capacity"

    def __init__(
        self,
        key_dim: int,
        capacity: int,
        n_neighbors: int,
        knn_backend: KNNBackend = "auto",
        rebuild_threshold: int | None = None,
    ) -> None:
        self.key_dim = check_int("key_dim", key_dim)
        self.capacity = check_int(self.capacity_name, capacity)
        self.n_neighbors = check_int("n_neighbors (k)", n_neighbors)
        self.index = KNNIndex(self.key_dim, self.capacity, backend=knn_backend, rebuild_threshold=rebuild_threshold)
        self.values = np.zeros(self.capacity, dtype=np.float64)
        self.recency = RecencyOrder(self.capacity)

    def __len__(self) -> int:
        return self.index.size

    def write(self, key: np.ndarray, value: float) -> tuple[int, int]:
        """Write a new row (float32 ``key``), overwriting the least recently updated row when the table is full.

        :return: the row written and the row overwritten (-1 when none was; then it is the same row).
        """
        if self.index.size < self.capacity:
            row, overwritten = self.index.add(key), -1
        else:
            row = overwritten = self.recency.oldest()
            self._forget(row)
            self.index.set_key(row, key)
        self.values[row] = value
        self.recency.touch(row)
        return row, overwritten

    def _forget(self, row: int) -> None:
        """Hook: ``row`` is about to be overwritten (its key is still in the index)."""

    def state_dict(self) -> dict[str, Any]:
        """Used rows only, with their update times (which give the eviction order)."""
        n = len(self)
        return {
            "keys": self.index.keys[:n].copy(),
            "values": self.values[:n].copy(),
            "last_update": self.recency.last_update[:n].copy(),
            "clock": int(self.recency.clock),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore exactly what :meth:`state_dict` returned.

        :raises ValueError: if ``state`` is incomplete, mis-shaped, non-finite or larger than the capacity (the
            table is left unchanged then).
        """
        keys = check_saved_rows(state, type(self).__name__, self.key_dim, self.capacity, ("values",))
        n = len(keys)
        self.index.load_keys(keys)
        self.values[:n] = np.asarray(state["values"], dtype=np.float64)
        self.recency.rebuild_from_timestamps(np.asarray(state["last_update"], dtype=np.int64), int(state["clock"]))

    def clear(self) -> None:
        """Remove every row."""
        self.index.clear()
        self.recency.clear()

"""Least-recently-updated bookkeeping for fixed-capacity memories (O(1) touch and evict)."""

from __future__ import annotations

import numpy as np


class RecencyOrder:
    """Rows ordered from least to most recently updated, as a doubly linked list in numpy arrays.

    Thesis Eq. 4.4 and Section 5.2.3 evict "the least recently updated entry" when a memory is
    full. An ``argmin`` over timestamps would cost O(N) per eviction; this list gives O(1)
    :meth:`touch` (move a row to the most-recent end) and :meth:`oldest`. The logical timestamps
    (:attr:`last_update`) are kept too: they are what gets saved, and :meth:`rebuild_from_timestamps`
    recreates the list from them.

    :param capacity: maximum number of rows.
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self._prev = np.full(self.capacity, -1, dtype=np.int64)
        self._next = np.full(self.capacity, -1, dtype=np.int64)
        #: logical time of each row's last update (larger = more recent)
        self.last_update = np.zeros(self.capacity, dtype=np.int64)
        self.clock = 0
        self._head = -1  # least recently updated
        self._tail = -1  # most recently updated
        self._linked = np.zeros(self.capacity, dtype=bool)

    def touch(self, row: int) -> None:
        """Mark ``row`` as updated now (adds it to the order if it was not in it)."""
        self.clock += 1
        self.last_update[row] = self.clock
        if self._tail == row:
            return
        if self._linked[row]:
            prev, nxt = self._prev[row], self._next[row]
            if prev >= 0:
                self._next[prev] = nxt
            else:
                self._head = int(nxt)
            self._prev[nxt] = prev  # nxt >= 0 because row is not the tail
        self._linked[row] = True
        self._prev[row] = self._tail
        self._next[row] = -1
        if self._tail >= 0:
            self._next[self._tail] = row
        else:
            self._head = row
        self._tail = row

    def oldest(self) -> int:
        """Row id of the least recently updated row."""
        if self._head < 0:
            raise RuntimeError("RecencyOrder is empty")
        return int(self._head)

    def clear(self) -> None:
        """Forget every row."""
        self._prev[:] = -1
        self._next[:] = -1
        self._linked[:] = False
        self.last_update[:] = 0
        self.clock = 0
        self._head = self._tail = -1

    def rebuild_from_timestamps(self, last_update: np.ndarray, clock: int) -> None:
        """Restore the order of rows ``0 .. len(last_update) - 1`` from saved timestamps."""
        self.clear()
        n = len(last_update)
        self.last_update[:n] = last_update
        self.clock = int(clock)
        if n == 0:
            return
        order = np.argsort(last_update, kind="stable")
        self._prev[order[1:]] = order[:-1]
        self._next[order[:-1]] = order[1:]
        self._linked[:n] = True
        self._head, self._tail = int(order[0]), int(order[-1])

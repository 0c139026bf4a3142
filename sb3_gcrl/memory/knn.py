"""Exact k-nearest-neighbour index over a preallocated, row-overwritable key table.

Episodic memories query their table every environment step and change a few rows after every
episode. Rebuilding a search structure after every change (what the authors' code does with an
sklearn KD-tree) costs O(N log N) per episode or per insert; brute force costs O(N d) per query.
:class:`KNNIndex` keeps both costs low while staying *exact*:

* ``backend="kdtree"`` (default for key dimension <= 16): a :class:`scipy.spatial.cKDTree` over a
  snapshot of the table plus a small *delta* of rows written since the snapshot. Queries search
  the tree (skipping rows whose key changed since the snapshot) and brute-force the delta with
  faiss, then merge. The tree is rebuilt lazily, at the first query after the delta outgrew
  ``rebuild_threshold`` rows, so the rebuild cost is amortised over many writes.
* ``backend="flat"`` (default above 16 dims, where KD-trees degrade to brute force anyway): exact
  brute force with ``faiss.knn`` directly over the used rows of the key array (no copy, nothing
  to maintain).

Distances are Euclidean (not squared), matching ``f(s, s^c)`` in thesis Eq. 4.3/4.4.
"""

from __future__ import annotations

from typing import Literal

import faiss
import numpy as np
from scipy.spatial import cKDTree

from sb3_gcrl.common.validation import check_choice, check_int, check_optional_int

KNNBackend = Literal["auto", "kdtree", "flat"]
#: the values of :data:`KNNBackend`
KNN_BACKENDS: tuple[str, ...] = ("auto", "kdtree", "flat")

#: above this key dimension ``backend="auto"`` uses faiss brute force instead of a KD-tree
KDTREE_MAX_DIM = 16


class KNNIndex:
    """Exact Euclidean k-NN over ``keys[:size]``, a preallocated ``(capacity, dim)`` float32 table.

    Rows are only appended (:meth:`add`) or overwritten in place (:meth:`set_key`); they are never
    deleted, so the valid rows are always ``0 .. size - 1`` and row ids stay stable (the memories
    keep values/actions in parallel arrays indexed by row).

    :param dim: key dimension.
    :param capacity: maximum number of rows.
    :param backend: ``"kdtree"`` (KD-tree snapshot + brute-forced delta), ``"flat"`` (faiss brute
        force) or ``"auto"`` (KD-tree up to :data:`KDTREE_MAX_DIM` dims, flat above).
    :param rebuild_threshold: number of rows written since the last KD-tree build that triggers a
        rebuild at the next query. ``None``: ``max(256, 16 * sqrt(size))`` — balances the
        amortised rebuild cost O(N log N / threshold) against the delta scan O(threshold).
    """

    def __init__(
        self,
        dim: int,
        capacity: int,
        backend: KNNBackend = "auto",
        rebuild_threshold: int | None = None,
    ) -> None:
        self.dim = check_int("key dimension", dim)
        self.capacity = check_int("memory capacity", capacity)
        check_choice("knn_backend", backend, KNN_BACKENDS)
        check_optional_int("rebuild_threshold", rebuild_threshold)
        self.backend: Literal["kdtree", "flat"] = (
            ("kdtree" if dim <= KDTREE_MAX_DIM else "flat") if backend == "auto" else backend
        )
        self.rebuild_threshold = rebuild_threshold
        self.keys = np.zeros((self.capacity, self.dim), dtype=np.float32)
        self.size = 0
        #: number of KD-tree (re)builds, for diagnostics and benchmarks
        self.n_rebuilds = 0
        self._tree: cKDTree | None = None
        self._tree_size = 0
        self._current_threshold = 0
        # rows of the tree snapshot whose key was overwritten since the build
        self._stale = np.zeros(self.capacity, dtype=bool)
        self._n_stale = 0
        # rows written since the build: their ids and (a copy of) their current keys
        max_delta = self._threshold_for(self.capacity)
        self._delta_rows = np.empty(max_delta, dtype=np.int64)
        self._delta_keys = np.empty((max_delta, self.dim), dtype=np.float32)
        self._delta_pos = np.full(self.capacity, -1, dtype=np.int64)
        self._n_delta = 0
        self._delta_overflow = False

    # ------------------------------------------------------------------ writes
    def add(self, key: np.ndarray) -> int:
        """Append a row and return its id. Raises if the index is full (the caller evicts instead)."""
        if self.size >= self.capacity:
            raise RuntimeError("KNNIndex is full: overwrite a row with set_key() (eviction) instead of add()")
        row = self.size
        self.keys[row] = key
        self.size += 1
        self._record_write(row)
        return row

    def set_key(self, row: int, key: np.ndarray) -> None:
        """Overwrite the key of an existing row (replacement or eviction)."""
        self.keys[row] = key
        if row < self._tree_size and not self._stale[row]:
            self._stale[row] = True
            self._n_stale += 1
        self._record_write(row)

    def load_keys(self, keys: np.ndarray) -> None:
        """Replace the whole table by ``keys`` (used rows only), e.g. when restoring a saved memory."""
        n = len(keys)
        if n > self.capacity:
            raise ValueError(f"{n} keys do not fit into an index of capacity {self.capacity}")
        self.keys[:n] = keys
        self.size = n
        self._invalidate()

    def clear(self) -> None:
        """Remove every row."""
        self.size = 0
        self._invalidate()

    def _invalidate(self) -> None:
        self._tree = None
        self._tree_size = 0
        self._stale[:] = False
        self._n_stale = 0
        self._delta_pos[self._delta_rows[: self._n_delta]] = -1
        self._n_delta = 0
        self._delta_overflow = self.backend == "kdtree" and self.size > 0

    def _record_write(self, row: int) -> None:
        if self.backend != "kdtree" or self._delta_overflow:
            return
        pos = self._delta_pos[row]
        if pos < 0:
            if self._n_delta == len(self._delta_rows):
                # more writes than the delta can hold: the next query rebuilds the tree
                self._delta_overflow = True
                return
            pos = self._n_delta
            self._delta_rows[pos] = row
            self._delta_pos[row] = pos
            self._n_delta += 1
        self._delta_keys[pos] = self.keys[row]

    # ------------------------------------------------------------------ reads
    def _threshold_for(self, size: int) -> int:
        if self.rebuild_threshold is not None:
            return self.rebuild_threshold
        return max(256, int(16 * np.sqrt(size)))

    def rebuild(self) -> None:
        """Build the KD-tree over the current rows (done lazily by :meth:`search`)."""
        self._delta_pos[self._delta_rows[: self._n_delta]] = -1
        self._n_delta = 0
        self._delta_overflow = False
        self._stale[: self._tree_size] = False
        self._n_stale = 0
        self._tree_size = self.size
        self._current_threshold = self._threshold_for(self.size)
        # balanced_tree/compact_nodes off: ~2x faster builds, queries barely slower
        self._tree = cKDTree(self.keys[: self.size], leafsize=16, balanced_tree=False, compact_nodes=False)
        self.n_rebuilds += 1

    def search(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Exact k nearest rows of each query.

        :param queries: ``(n_queries, dim)`` array.
        :param k: number of neighbours.
        :return: ``(distances, rows)``, both ``(n_queries, k)``, sorted by increasing Euclidean
            distance; when fewer than ``k`` rows exist the tail is padded with ``inf`` / ``-1``.
        """
        if queries.dtype != np.float32 or not queries.flags.c_contiguous:
            queries = np.ascontiguousarray(queries, dtype=np.float32)
        if queries.ndim != 2 or queries.shape[1] != self.dim:
            raise ValueError(f"Queries must have shape (n, {self.dim}), got {queries.shape}")
        n_queries = len(queries)
        if self.size == 0 or k < 1:
            return np.full((n_queries, max(k, 0)), np.inf), np.full((n_queries, max(k, 0)), -1, dtype=np.int64)
        if self.backend == "flat":
            return self._search_flat(queries, k)
        if self._tree is None or self._delta_overflow or self._n_delta > self._current_threshold:
            self.rebuild()
        dist, rows = self._search_tree(queries, k)
        if self._n_delta:
            merge = self._merge_delta_single if n_queries == 1 else self._merge_delta
            dist, rows = merge(queries, k, dist, rows)
        rows = rows.astype(np.int64, copy=False)
        if dist.shape[1] < k:
            pad = k - dist.shape[1]
            dist = np.concatenate([dist, np.full((n_queries, pad), np.inf)], axis=1)
            rows = np.concatenate([rows, np.full((n_queries, pad), -1, dtype=np.int64)], axis=1)
        return dist, rows

    def _search_flat(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        kk = min(k, self.size)
        sq, rows = faiss.knn(queries, self.keys[: self.size], kk)
        dist = np.sqrt(np.maximum(sq, 0.0, dtype=np.float64))
        rows = rows.astype(np.int64, copy=False)
        if kk < k:
            n = len(queries)
            dist = np.concatenate([dist, np.full((n, k - kk), np.inf)], axis=1)
            rows = np.concatenate([rows, np.full((n, k - kk), -1, dtype=np.int64)], axis=1)
        return dist, rows

    def _query_tree(self, queries: np.ndarray, kq: int) -> tuple[np.ndarray, np.ndarray]:
        assert self._tree is not None
        dist, rows = self._tree.query(queries, k=kq)
        if kq == 1:
            dist, rows = dist[:, None], rows[:, None]
        return dist, rows

    def _search_tree(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        n_fresh = self._tree_size - self._n_stale  # tree rows whose key is still current
        if n_fresh <= 0:
            return np.empty((len(queries), 0)), np.empty((len(queries), 0), dtype=np.int64)
        k_fresh = min(k, n_fresh)
        if self._n_stale == 0:
            return self._query_tree(queries, k_fresh)
        # overwritten rows are still in the tree with their old key: ask for a few extra neighbours
        kq = min(self._tree_size, k_fresh + min(self._n_stale, k_fresh + 4))
        dist, rows = self._query_tree(queries, kq)
        stale = self._stale[rows]
        if not stale[:, :k_fresh].any():  # common case: the k nearest are all current
            return dist[:, :k_fresh], rows[:, :k_fresh]
        fresh = ~stale
        short = fresh.sum(axis=1) < k_fresh
        if short.any():
            # rare: too many stale rows among the nearest; exact re-query allowing for every stale row
            dist2, rows2 = self._query_tree(queries[short], min(self._tree_size, k_fresh + self._n_stale))
            out_d = np.empty((len(queries), k_fresh))
            out_r = np.empty((len(queries), k_fresh), dtype=rows.dtype)
            out_d[short], out_r[short] = self._first_valid(dist2, rows2, ~self._stale[rows2], k_fresh)
            keep = ~short
            out_d[keep], out_r[keep] = self._first_valid(dist[keep], rows[keep], fresh[keep], k_fresh)
            return out_d, out_r
        return self._first_valid(dist, rows, fresh, k_fresh)

    @staticmethod
    def _first_valid(dist: np.ndarray, rows: np.ndarray, valid: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        # stable sort on "invalid" keeps the distance order among valid entries
        order = np.argsort(~valid, axis=1, kind="stable")[:, :k]
        return np.take_along_axis(dist, order, axis=1), np.take_along_axis(rows, order, axis=1)

    def _search_delta(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """k nearest among the rows written since the last build: ``(distances, rows)``, unsorted."""
        m = self._n_delta
        delta_keys = self._delta_keys[:m]
        if len(queries) * m > 1 << 16:
            # many queries (batched episode updates): a throw-away KD-tree over the delta is cheaper
            dist, pos = cKDTree(delta_keys).query(queries, k=min(k, m))
            if dist.ndim == 1:
                dist, pos = dist[:, None], pos[:, None]
            return dist, self._delta_rows[pos]
        diff = delta_keys[None, :, :] - queries[:, None, :]
        sq = np.einsum("qmd,qmd->qm", diff, diff)
        if m > k:
            pos = np.argpartition(sq, k - 1, axis=1)[:, :k]
            sq = np.take_along_axis(sq, pos, axis=1)
        else:
            pos = np.broadcast_to(np.arange(m), sq.shape)
        return np.sqrt(sq, dtype=np.float64), self._delta_rows[pos]

    def _merge_delta_single(
        self, queries: np.ndarray, k: int, dist: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_merge_delta` for one query (every env step of an episodic agent): the same result with about
        half the numpy calls, since per-call overhead, not arithmetic, is what a single query costs."""
        m = self._n_delta
        diff = self._delta_keys[:m] - queries[0]
        d_delta = np.sqrt(np.einsum("md,md->m", diff, diff), dtype=np.float64)
        if dist.shape[1] == k and not d_delta.min() < dist[0, -1]:
            return dist, rows  # no written row is among the k nearest
        r_delta = self._delta_rows[:m]
        if m > k:
            pos = np.argpartition(d_delta, k - 1)[:k]
            d_delta, r_delta = d_delta[pos], r_delta[pos]
        all_d = np.concatenate([dist[0], d_delta])
        all_r = np.concatenate([rows[0], r_delta])
        order = np.argsort(all_d, kind="stable")[:k]
        return all_d[order][None], all_r[order][None]

    def _merge_delta(
        self, queries: np.ndarray, k: int, dist: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        d_delta, r_delta = self._search_delta(queries, k)
        if dist.shape[1] == k and not (d_delta.min(axis=1) < dist[:, -1]).any():
            return dist, rows  # no written row is among the k nearest
        all_d = np.concatenate([dist, d_delta], axis=1)
        all_r = np.concatenate([rows, r_delta], axis=1)
        order = np.argsort(all_d, axis=1, kind="stable")[:, :k]
        return np.take_along_axis(all_d, order, axis=1), np.take_along_axis(all_r, order, axis=1)

"""The CEC episodic memory: a bounded table of (state key, action, value) rows (thesis Section 4.4).

Update (after each episode, thesis Eq. 4.3/4.4), for every ``(s, a, v)`` of the episode, processed
from the last step backwards as in Algorithm 1, against the memory *as already updated by the later
steps of the same episode* (the authors' code queries a KD-tree that is stale within an episode;
ours is exact):

* memory empty, or the nearest row ``c`` is at distance ``>= d``: **add** the row; when the memory
  is full, **evict** the least recently updated row and write the new one in its place (Eq. 4.4);
* nearest row within ``d`` and ``v > v_c``: **replace** that row by ``(s, a, v)`` (Eq. 4.3);
* nearest row within ``d`` and ``v <= v_c``: keep it but **refresh** its last-update time (the
  authors' code does this; Eq. 4.3 alone leaves the row untouched). A region that keeps being
  visited therefore is not evicted.

Action selection (Eq. 4.5): the ``k`` nearest rows within ``n * d`` vote; one is sampled with
probability ``softmax(v / tau)`` (max-subtracted, so large returns cannot overflow) and its action is
returned. Greedy selection returns the action of the single nearest row, without a threshold.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_gcrl.common.validation import check_finite_returns, check_float, check_int, check_saved_rows
from sb3_gcrl.memory.knn import KNNBackend, KNNIndex
from sb3_gcrl.memory.recency import RecencyOrder

#: outcome codes of :meth:`CECMemory.update`
ADDED, REPLACED, REFRESHED, EVICTED = "added", "replaced", "refreshed", "evicted"


class CECMemory:
    """Continuous episodic control memory (thesis Ch. 4, Algorithm 1).

    :param key_dim: dimension of a state key (after any embedding).
    :param action_dim: dimension of an action.
    :param capacity: maximum number of rows (authors' default 1e6).
    :param distance_threshold: ``d`` of Table 4.4: a new state closer than ``d`` to a row updates
        that row, a farther one adds a row.
    :param filter_factor: ``n`` of Table 4.4: neighbours farther than ``n * d`` do not vote.
    :param n_neighbors: ``k`` of Table 4.4.
    :param temperature: ``tau`` of Eq. 4.5 (> 0); small = greedy among neighbours.
    :param knn_backend: see :class:`~sb3_gcrl.memory.knn.KNNIndex`.
    :param rebuild_threshold: see :class:`~sb3_gcrl.memory.knn.KNNIndex`.
    """

    def __init__(
        self,
        key_dim: int,
        action_dim: int,
        capacity: int = 1_000_000,
        distance_threshold: float = 0.1,
        filter_factor: float = 1.0,
        n_neighbors: int = 5,
        temperature: float = 0.1,
        knn_backend: KNNBackend = "auto",
        rebuild_threshold: int | None = None,
    ) -> None:
        self.key_dim = check_int("key_dim", key_dim)
        self.action_dim = check_int("action_dim", action_dim)
        self.capacity = check_int("capacity", capacity)
        self.distance_threshold = check_float("distance_threshold (d)", distance_threshold, 0.0, exclusive_minimum=True)
        self.filter_factor = check_float("filter_factor (n)", filter_factor, 0.0, exclusive_minimum=True)
        self.n_neighbors = check_int("n_neighbors (k)", n_neighbors)
        self.temperature = check_float("temperature (tau)", temperature, 0.0, exclusive_minimum=True)
        self.index = KNNIndex(key_dim, self.capacity, backend=knn_backend, rebuild_threshold=rebuild_threshold)
        self.actions = np.zeros((self.capacity, self.action_dim), dtype=np.float32)
        self.values = np.zeros(self.capacity, dtype=np.float64)
        self.recency = RecencyOrder(self.capacity)

    def __len__(self) -> int:
        return self.index.size

    @property
    def keys(self) -> np.ndarray:
        """Stored keys, ``(len(self), key_dim)`` (a view)."""
        return self.index.keys[: self.index.size]

    # ------------------------------------------------------------------ update
    def update(self, key: np.ndarray, action: np.ndarray, value: float) -> str:
        """Apply Eq. 4.3/4.4 to one ``(s, a, v)``; return ``"added"``, ``"evicted"`` (added in place of
        the least recently updated row), ``"replaced"`` or ``"refreshed"``.

        :raises ValueError: if ``value`` is NaN or infinite.
        """
        if not np.isfinite(value):
            check_finite_returns(np.array([value], dtype=np.float64))
        if self.index.size:
            dist, rows = self.index.search(key[None], 1)
            nearest, row = dist[0, 0], int(rows[0, 0])
            if nearest < self.distance_threshold:
                if value > self.values[row]:
                    self._write(row, key, action, value)
                    return REPLACED
                self.recency.touch(row)
                return REFRESHED
        if self.index.size < self.capacity:
            row = self.index.add(key)
            self.actions[row] = action
            self.values[row] = value
            self.recency.touch(row)
            return ADDED
        self._write(self.recency.oldest(), key, action, value)
        return EVICTED

    def _write(self, row: int, key: np.ndarray, action: np.ndarray, value: float) -> None:
        self.index.set_key(row, key)
        self.actions[row] = action
        self.values[row] = value
        self.recency.touch(row)

    def update_episode(self, keys: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> dict[str, int]:
        """Update the memory with one finished episode (thesis Algorithm 1, UPDATE).

        Equivalent to calling :meth:`update` for ``t = T-1, ..., 0``, but the nearest-row searches
        against the pre-episode table are batched into one query; rows written during the episode
        are searched by brute force (they are few), and a row the episode itself overwrote falls back
        to an exact live query.

        :param keys: ``(T, key_dim)`` state keys in time order.
        :param actions: ``(T, action_dim)`` actions taken.
        :param returns: ``(T,)`` discounted returns (see :func:`~sb3_gcrl.memory.episode.discounted_returns`).
        :return: how many steps were added / evicted / replaced / refreshed.
        :raises ValueError: if a return is NaN or infinite (nothing is written then).
        """
        keys = np.ascontiguousarray(keys, dtype=np.float32).reshape(len(keys), self.key_dim)
        actions = np.asarray(actions, dtype=np.float32).reshape(len(keys), self.action_dim)
        returns = np.asarray(returns, dtype=np.float64)
        if not (len(keys) == len(actions) == len(returns)):
            raise ValueError(f"keys, actions, returns lengths differ: {len(keys)}, {len(actions)}, {len(returns)}")
        check_finite_returns(returns)
        counts = {ADDED: 0, EVICTED: 0, REPLACED: 0, REFRESHED: 0}
        n_steps = len(keys)
        if n_steps == 0:
            return counts
        n_before = self.index.size
        n_candidates = min(4, n_before)
        if n_candidates:
            pre_dist, pre_rows = self.index.search(keys, n_candidates)
            pre_dist_list, pre_rows_list = pre_dist.tolist(), pre_rows.tolist()
        overwritten: set[int] = set()  # pre-episode rows whose key this episode changed
        written_rows = np.empty(n_steps, dtype=np.int64)  # rows written this episode and their keys
        written_keys = np.empty((n_steps, self.key_dim), dtype=np.float32)
        written_pos: dict[int, int] = {}
        n_written = 0
        threshold = self.distance_threshold
        returns_list = returns.tolist()
        for t in range(n_steps - 1, -1, -1):  # Algorithm 1 pops the episode from its end
            key, value = keys[t], returns_list[t]
            best_dist, best_row = np.inf, -1
            search_written = True
            if n_candidates:
                for dist, row in zip(pre_dist_list[t], pre_rows_list[t]):
                    if row not in overwritten:
                        best_dist, best_row = dist, row
                        break
                else:  # every candidate was overwritten by this episode: exact live query
                    live_dist, live_rows = self.index.search(key[None], 1)
                    best_dist, best_row = float(live_dist[0, 0]), int(live_rows[0, 0])
                    search_written = False
            if search_written and n_written:
                diff = written_keys[:n_written] - key
                sq = np.einsum("ij,ij->i", diff, diff)
                j = int(sq.argmin())
                dist = float(np.sqrt(sq[j]))
                if dist < best_dist:
                    best_dist, best_row = dist, int(written_rows[j])
            if best_row >= 0 and best_dist < threshold:
                if value > self.values[best_row]:
                    self._write(best_row, key, actions[t], value)
                    outcome = REPLACED
                else:
                    self.recency.touch(best_row)
                    counts[REFRESHED] += 1
                    continue
            elif self.index.size < self.capacity:
                best_row = self.index.add(key)
                self.actions[best_row] = actions[t]
                self.values[best_row] = value
                self.recency.touch(best_row)
                outcome = ADDED
            else:
                best_row = self.recency.oldest()
                self._write(best_row, key, actions[t], value)
                outcome = EVICTED
            counts[outcome] += 1
            if best_row < n_before:
                overwritten.add(best_row)
            pos = written_pos.get(best_row)
            if pos is None:
                pos = written_pos[best_row] = n_written
                written_rows[pos] = best_row
                n_written += 1
            written_keys[pos] = key
        return counts

    # ------------------------------------------------------------------ action selection
    def neighbours(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``knn(k, s, n, d)`` of Algorithm 1: the k nearest rows and which of them lie within ``n * d``.

        :return: ``(distances, rows, valid)``, each ``(n_queries, k)``.
        """
        dist, rows = self.index.search(keys, self.n_neighbors)
        valid = (dist <= self.filter_factor * self.distance_threshold) & (rows >= 0)
        return dist, rows, valid

    def selection_probabilities(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 4.5 over the valid neighbours: ``(rows, probabilities)``, each ``(n_queries, k)``
        (probability 0 for invalid neighbours; a row of zeros when no neighbour qualifies)."""
        _, rows, valid = self.neighbours(keys)
        logits = np.where(valid, self.values[np.maximum(rows, 0)] / self.temperature, -np.inf)
        row_max = logits.max(axis=1, keepdims=True)
        row_max[~np.isfinite(row_max)] = 0.0
        weights = np.exp(logits - row_max)  # max-subtracted: no overflow for large v / tau
        total = weights.sum(axis=1, keepdims=True)
        probs = np.divide(weights, total, out=np.zeros_like(weights), where=total > 0)
        return rows, probs

    def select_actions(self, keys: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Sample one stored action per query by Eq. 4.5 (no exploration noise: the caller adds it).

        Sampling uses the Gumbel-max trick, ``argmax_i (v_i / tau + Gumbel_i)``, which draws exactly
        from ``softmax(v / tau)`` without exponentials (so it cannot overflow) and in few array ops.

        :param keys: ``(n_queries, key_dim)``.
        :param rng: random generator used for sampling.
        :return: ``(actions, found)``: ``(n_queries, action_dim)`` actions and a boolean mask of the
            queries that had a neighbour within ``n * d``; for the others the action row is 0 and the
            caller should act randomly (Algorithm 1: uniform random action).
        """
        dist, rows = self.index.search(keys, self.n_neighbors)
        valid = dist <= self.filter_factor * self.distance_threshold  # padding has dist = inf
        found = valid[:, 0]  # neighbours are sorted by distance: any valid -> the nearest is valid
        scores = np.where(valid, self.values[rows] / self.temperature + rng.gumbel(size=rows.shape), -np.inf)
        chosen = rows[np.arange(len(rows)), scores.argmax(axis=1)]
        actions = self.actions[chosen]  # a copy (fancy indexing)
        actions[~found] = 0.0
        return actions, found

    def greedy_actions(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Action of the single nearest row, no distance filter (evaluation mode, Section 4.4).

        :return: ``(actions, found)``; ``found`` is False only while the memory is empty.
        """
        _, rows = self.index.search(keys, 1)
        found = rows[:, 0] >= 0
        actions = np.where(found[:, None], self.actions[np.maximum(rows[:, 0], 0)], 0.0).astype(np.float32)
        return actions, found

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        """Used rows only (so a saved model grows with the memory, not with its capacity)."""
        n = len(self)
        return {
            "keys": self.index.keys[:n].copy(),
            "actions": self.actions[:n].copy(),
            "values": self.values[:n].copy(),
            "last_update": self.recency.last_update[:n].copy(),
            "clock": int(self.recency.clock),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore exactly what :meth:`state_dict` returned.

        :raises ValueError: if ``state`` is incomplete, mis-shaped, non-finite or larger than the capacity
            (the memory is left unchanged then).
        """
        keys = check_saved_rows(state, "CECMemory", self.key_dim, self.capacity, ("actions", "values"))
        n = len(keys)
        if np.asarray(state["actions"]).size != n * self.action_dim:
            raise ValueError(
                f"Saved CECMemory is corrupted: 'actions' has shape {np.shape(state['actions'])}, "
                f"expected ({n}, {self.action_dim})"
            )
        self.index.load_keys(keys)
        self.actions[:n] = np.asarray(state["actions"], dtype=np.float32).reshape(n, self.action_dim)
        self.values[:n] = np.asarray(state["values"], dtype=np.float64)
        self.recency.rebuild_from_timestamps(np.asarray(state["last_update"], dtype=np.int64), int(state["clock"]))

    def clear(self) -> None:
        """Remove every row."""
        self.index.clear()
        self.recency.clear()

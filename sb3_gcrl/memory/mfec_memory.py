"""The MFEC episodic memory: one bounded value table per discrete action (thesis Section 5.2.3).

Update (Eq. 5.2): for a state key already stored for action ``a`` (exact match) the value becomes
``max(G, Q_ec(s, a))``; otherwise the key is added, evicting the least recently updated row of that
action's table when it is full. Exact matches are found with a hash map (O(1)), so updates never
search the kNN index.

Estimate: the stored value on an exact match; ``+inf`` while the action's table holds ``<= k``
rows (so untried actions are preferred, as in the authors' code); otherwise the mean value of the
``k`` nearest rows.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_gcrl.common.validation import check_finite_returns, check_int
from sb3_gcrl.memory.knn import KNNBackend
from sb3_gcrl.memory.value_table import KNNValueTable


def argmax_random_ties(q: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
    """Row-wise ``argmax`` of ``q`` ``(n, n_actions)``; ties (e.g. several untried actions at ``+inf``) are
    broken uniformly at random with ``rng``, or by lowest index when ``rng`` is None."""
    if rng is None:
        return q.argmax(axis=1)
    ties = q == q.max(axis=1, keepdims=True)
    return (rng.random(q.shape) * ties).argmax(axis=1)


class MFECTable(KNNValueTable):
    """The value table ``Q_ec(., a)`` of one action.

    :param key_dim: key dimension.
    :param capacity: maximum number of rows.
    :param n_neighbors: ``k`` of the kNN estimate.
    :param knn_backend: see :class:`~sb3_gcrl.memory.knn.KNNIndex`.
    :param rebuild_threshold: see :class:`~sb3_gcrl.memory.knn.KNNIndex`.
    """

    def __init__(
        self,
        key_dim: int,
        capacity: int,
        n_neighbors: int = 3,
        knn_backend: KNNBackend = "auto",
        rebuild_threshold: int | None = None,
    ) -> None:
        super().__init__(key_dim, capacity, n_neighbors, knn_backend, rebuild_threshold)
        self._row_of: dict[bytes, int] = {}  # exact key bytes -> row

    def lookup(self, key: np.ndarray) -> int:
        """Row holding exactly ``key`` (float32), or -1."""
        return self._row_of.get(key.tobytes(), -1)

    def update(self, key: np.ndarray, value: float) -> bool:
        """Eq. 5.2 for one ``(s, G)``; ``key`` must be float32. Returns True if a new row was written."""
        row = self._row_of.get(key.tobytes(), -1)
        if row >= 0:
            if value > self.values[row]:
                self.values[row] = value
            self.recency.touch(row)
            return False
        row, _ = self.write(key, value)
        self._row_of[key.tobytes()] = row
        return True

    def _forget(self, row: int) -> None:
        del self._row_of[self.index.keys[row].tobytes()]

    def estimate(self, keys: np.ndarray) -> np.ndarray:
        """``Q_ec(s, a)`` for a batch of float32 keys ``(n, key_dim)`` -> ``(n,)``.

        Exact matches are answered from the hash map; only the other keys are searched.
        """
        if len(keys) == 1:  # the per-step case: skip the batch bookkeeping
            row = self._row_of.get(keys[0].tobytes(), -1)
            if row >= 0:
                return self.values[row : row + 1].copy()
            if len(self) <= self.n_neighbors:
                return np.full(1, np.inf)
            return self.values[self.index.search(keys, self.n_neighbors)[1]].mean(axis=1)
        rows = np.fromiter((self._row_of.get(key.tobytes(), -1) for key in keys), dtype=np.int64, count=len(keys))
        out = self.values[rows]  # exact matches (garbage where rows == -1, overwritten below)
        missing = rows < 0
        if missing.any():
            if len(self) <= self.n_neighbors:
                out[missing] = np.inf
            else:
                query = keys if missing.all() else keys[missing]
                _, neighbours = self.index.search(query, self.n_neighbors)
                out[missing] = self.values[neighbours].mean(axis=1)
        return out

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore exactly what :meth:`state_dict` returned.

        :raises ValueError: if ``state`` is incomplete, mis-shaped, non-finite or larger than the capacity
            (the table is left unchanged then).
        """
        super().load_state_dict(state)
        keys = self.index.keys[: len(self)]
        self._row_of = {keys[i].tobytes(): i for i in range(len(self))}

    def clear(self) -> None:
        """Remove every row."""
        super().clear()
        self._row_of.clear()


class MFECMemory:
    """MFEC: one :class:`MFECTable` per action (thesis Section 5.2.3, Eq. 5.2).

    :param key_dim: key dimension (8 with the usual random projection).
    :param n_actions: number of discrete actions.
    :param capacity_per_action: rows per action table (authors: ``1e5 / (2 * n_actions)`` in 2M).
    :param n_neighbors: ``k`` of the kNN estimate (authors: 3).
    :param knn_backend: see :class:`~sb3_gcrl.memory.knn.KNNIndex`.
    :param rebuild_threshold: see :class:`~sb3_gcrl.memory.knn.KNNIndex`.
    """

    def __init__(
        self,
        key_dim: int,
        n_actions: int,
        capacity_per_action: int = 100_000,
        n_neighbors: int = 3,
        knn_backend: KNNBackend = "auto",
        rebuild_threshold: int | None = None,
    ) -> None:
        self.key_dim = check_int("key_dim", key_dim)
        self.n_actions = check_int("n_actions", n_actions)
        self.capacity_per_action = check_int("capacity_per_action", capacity_per_action)
        self.n_neighbors = check_int("n_neighbors (k)", n_neighbors)
        if self.capacity_per_action <= self.n_neighbors:
            raise ValueError(
                f"capacity_per_action={self.capacity_per_action} must exceed n_neighbors={self.n_neighbors} (k): a "
                "kNN estimate needs more than k rows per action, so every unseen state would stay at +inf; raise "
                "the capacity or lower k"
            )
        self.tables = [
            MFECTable(self.key_dim, self.capacity_per_action, self.n_neighbors, knn_backend, rebuild_threshold)
            for _ in range(n_actions)
        ]

    def __len__(self) -> int:
        return sum(len(t) for t in self.tables)

    def estimate(self, keys: np.ndarray) -> np.ndarray:
        """``Q_ec(s, a)`` for every action: ``(n, key_dim)`` keys -> ``(n, n_actions)``."""
        keys = np.ascontiguousarray(keys, dtype=np.float32)
        return np.stack([table.estimate(keys) for table in self.tables], axis=1)

    def greedy_actions(self, keys: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """``argmax_a Q_ec(s, a)``; ties (e.g. several untried actions at ``+inf``) are broken uniformly
        at random with ``rng``, or by lowest index when ``rng`` is None."""
        return argmax_random_ties(self.estimate(keys), rng)

    def update_episode(self, keys: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> int:
        """Eq. 5.2 for every step of a finished episode.

        :param keys: ``(T, key_dim)``; :param actions: ``(T,)`` ints; :param returns: ``(T,)``.
        :return: number of new rows written.
        :raises ValueError: if a return is NaN or infinite (nothing is written then).
        """
        keys = np.ascontiguousarray(keys, dtype=np.float32).reshape(len(keys), self.key_dim)
        actions = np.asarray(actions).reshape(-1).astype(np.int64)
        returns = np.asarray(returns, dtype=np.float64)
        if not (len(keys) == len(actions) == len(returns)):
            raise ValueError(f"keys, actions, returns lengths differ: {len(keys)}, {len(actions)}, {len(returns)}")
        if len(actions) and (actions.min() < 0 or actions.max() >= self.n_actions):
            raise ValueError(f"actions must lie in [0, {self.n_actions}), got {actions.min()}..{actions.max()}")
        check_finite_returns(returns)
        added = 0
        for t in range(len(keys) - 1, -1, -1):
            added += self.tables[actions[t]].update(keys[t], float(returns[t]))
        return added

    def state_dict(self) -> dict[str, Any]:
        """Used rows of every table, keys prefixed ``"a<i>/"``."""
        out: dict[str, Any] = {}
        for a, table in enumerate(self.tables):
            out.update({f"a{a}/{name}": value for name, value in table.state_dict().items()})
        return out

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore exactly what :meth:`state_dict` returned.

        :raises ValueError: if ``state`` holds tables of other actions than ``0 .. n_actions - 1`` or a table
            cannot be restored (see :meth:`MFECTable.load_state_dict`).
        """
        prefixes = [f"a{a}/" for a in range(self.n_actions)]
        unknown = sorted({k.split("/", 1)[0] for k in state if not k.startswith(tuple(prefixes))})
        if unknown:
            raise ValueError(
                f"Saved MFECMemory has tables {unknown} that this memory with n_actions={self.n_actions} lacks; "
                "it was saved for another action space"
            )
        for a, (table, prefix) in enumerate(zip(self.tables, prefixes)):
            try:
                table.load_state_dict({k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)})
            except ValueError as error:
                raise ValueError(f"action {a}: {error}") from error

    def clear(self) -> None:
        """Remove every row."""
        for table in self.tables:
            table.clear()

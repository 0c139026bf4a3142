"""Observation -> memory key: flattening (Dict observations included) and Gaussian random projection.

Thesis Section 4.4 ("Feature embedding"): high-dimensional states are multiplied by a fixed matrix
``A`` with standard-normal entries, ``s_new = A s_ori``; distances are approximately preserved
(Johnson-Lindenstrauss). MFEC/2M use the same projection to 8 dims (the authors' 2M code). The matrix is
drawn from its own seeded generator, so equal seeds give equal keys, and it is saved with the model.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from gymnasium import spaces

from sb3_gcrl.common.validation import check_optional_int

#: default Dict-observation keys (and their order) for goal-conditioned envs: the state and the goal
GOAL_ENV_KEYS: tuple[str, ...] = ("observation", "desired_goal")


def _space_dim(space: spaces.Space, name: str) -> int:
    if isinstance(space, spaces.Box | spaces.MultiBinary):
        return int(np.prod(space.shape))
    if isinstance(space, spaces.Discrete):
        return 1
    raise ValueError(
        f"Observation space {name}{space} cannot be used as a memory key: use Box, MultiBinary or Discrete "
        "(or a Dict of those), or flatten it with gymnasium.wrappers.FlattenObservation"
    )


class KeyEmbedding:
    """Maps a batch of observations to float32 memory keys of size :attr:`key_dim`.

    Step 1, :meth:`features`: flatten each observation; Dict observations are the concatenation of
    ``observation_keys`` in that order (default: ``("observation", "desired_goal")`` when both exist,
    i.e. a goal-conditioned key; otherwise every key in the Dict's own, sorted, order).
    Step 2: if ``projection_dim`` is set, multiply by a ``(input_dim, projection_dim)`` matrix with
    N(0, 1) entries drawn from ``numpy.random.default_rng(seed)`` (thesis Section 4.4).

    Subclass and override :meth:`features` to plug in another embedding (e.g. a pre-trained
    encoder, the future work suggested in thesis Section 4.6).

    :param observation_space: the env's observation space.
    :param projection_dim: target dimension of the random projection, ``None`` for no projection.
    :param seed: seed of the projection matrix.
    :param observation_keys: Dict keys to concatenate, in order (Dict spaces only).
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        projection_dim: int | None = None,
        seed: int | None = None,
        observation_keys: Sequence[str] | None = None,
    ) -> None:
        self.observation_space = observation_space
        if isinstance(observation_space, spaces.Dict):
            if observation_keys is None:
                names = list(observation_space.spaces)
                observation_keys = GOAL_ENV_KEYS if all(k in names for k in GOAL_ENV_KEYS) else names
            missing = [k for k in observation_keys if k not in observation_space.spaces]
            if missing:
                raise ValueError(
                    f"observation_keys {missing} are not in the Dict observation space "
                    f"(keys: {list(observation_space.spaces)}); pass observation_keys=<subset of those>"
                )
            if len(observation_keys) == 0:
                raise ValueError("observation_keys must name at least one Dict key")
            self.observation_keys: tuple[str, ...] | None = tuple(observation_keys)
            self._dims = [_space_dim(observation_space[k], f"[{k!r}] ") for k in self.observation_keys]
        else:
            if observation_keys is not None:
                raise ValueError("observation_keys is only meaningful for Dict observation spaces; pass None")
            self.observation_keys = None
            self._dims = [_space_dim(observation_space, "")]
        self.input_dim = int(sum(self._dims))
        projection_dim = check_optional_int("projection_dim", projection_dim)
        self.projection_dim = projection_dim
        self.seed = seed
        self.projection: np.ndarray | None = None
        if projection_dim is not None:
            rng = np.random.default_rng(seed)
            self.projection = rng.standard_normal((self.input_dim, projection_dim)).astype(np.float32)

    @property
    def key_dim(self) -> int:
        """Dimension of the keys."""
        return self.input_dim if self.projection is None else int(self.projection.shape[1])

    def features(self, observations: np.ndarray | dict[str, np.ndarray]) -> np.ndarray:
        """Flatten a batch of observations to ``(n, input_dim)`` float32 (before projection)."""
        if self.observation_keys is None:
            obs = np.asarray(observations)
            return obs.reshape(len(obs), -1).astype(np.float32, copy=False)
        if not isinstance(observations, dict):
            raise ValueError(f"Expected a dict observation with keys {self.observation_keys}, got {type(observations)}")
        parts = [np.asarray(observations[k]) for k in self.observation_keys]
        n = len(parts[0])
        return np.concatenate([p.reshape(n, -1) for p in parts], axis=1).astype(np.float32, copy=False)

    def __call__(self, observations: np.ndarray | dict[str, np.ndarray]) -> np.ndarray:
        """Keys of a batch of observations: ``(n, key_dim)`` float32, C-contiguous.

        :raises ValueError: if an observation contains NaN or inf.
        """
        feats = self.features(observations)
        if feats.shape[1] != self.input_dim:
            raise ValueError(f"Observation features have {feats.shape[1]} dims, expected {self.input_dim}")
        keys = feats if self.projection is None else feats @ self.projection
        if not np.isfinite(keys).all():
            raise ValueError(
                "Observation contains NaN or inf and cannot be stored in episodic memory; fix the env or wrap it "
                "with stable_baselines3.common.vec_env.VecCheckNan to find the source"
            )
        return np.ascontiguousarray(keys, dtype=np.float32)

    def get_state(self) -> dict[str, np.ndarray]:
        """Arrays needed to restore the embedding exactly (the projection matrix, if any)."""
        return {} if self.projection is None else {"projection": self.projection}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore what :meth:`get_state` returned."""
        if "projection" in state:
            projection = np.asarray(state["projection"], dtype=np.float32)
            if self.projection is None or projection.shape != self.projection.shape:
                raise ValueError(
                    f"Saved projection of shape {projection.shape} does not match this embedding "
                    f"(projection_dim={self.projection_dim}, input_dim={self.input_dim})"
                )
            self.projection = projection

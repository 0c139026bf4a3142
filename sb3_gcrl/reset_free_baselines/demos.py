"""Demonstrations for MEDAL (thesis Ch. 3, Section 3.7.2): states of successful episodes from rho_0 to rho_g*.

MEDAL's backward policy is rewarded for reaching the states of the demonstrations, and the official code also puts
the demonstrations into both policies' replay buffers. The thesis generates 30 demonstration episodes per task
(with a trained agent, for tasks outside EARL); ``scripts/make_demos.py`` makes them here with scripted controllers and
stores them as package data, one compressed file per task: ``sb3_gcrl/reset_free_baselines/demos/<task>.npz`` (the
gymnasium id without its namespace, e.g. ``PointUMazeGoal-v0.npz``).

File format (``np.savez_compressed``), N transitions of E episodes:

* ``observations/<key>`` and ``next_observations/<key>``: one array per key of the env's Dict observation space,
  shape ``(N, *space[key].shape)``;
* ``actions``: ``(N, *action_space.shape)``, the env's (unscaled) actions;
* ``rewards``: ``(N,)``, the env's rewards for its own goal;
* ``episode_starts``: ``(N,)`` booleans, True at the first transition of each episode;
* ``env_id`` (string), ``seeds`` (``(E,)`` ints, the reset seed of each episode) and ``controller`` (string): metadata.

:func:`load_demos` reads a file (or a task's shipped file) and checks it, naming what is wrong.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

#: folder of the shipped demonstration files
DEMOS_DIR = Path(__file__).resolve().parent / "demos"
#: arrays every demonstration file holds besides the observations
REQUIRED_ARRAYS = ("actions", "rewards", "episode_starts", "env_id", "seeds")


@dataclass
class Demonstrations:
    """Demonstration transitions (see the module docstring for the file format).

    :param observations: Dict observation arrays, each ``(N, ...)``.
    :param next_observations: the next observations, same keys and shapes.
    :param actions: ``(N, *action_shape)`` env actions.
    :param rewards: ``(N,)`` rewards.
    :param episode_starts: ``(N,)`` True at the first transition of each episode.
    :param metadata: ``env_id``, ``seeds`` and the other non-array entries of the file.
    """

    observations: dict[str, np.ndarray]
    next_observations: dict[str, np.ndarray]
    actions: np.ndarray
    rewards: np.ndarray
    episode_starts: np.ndarray
    metadata: dict[str, Any]

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def n_episodes(self) -> int:
        """Number of demonstration episodes."""
        return int(self.episode_starts.sum())

    def states(self, key: str = "observation") -> np.ndarray:
        """Every demonstrated state (observations and the last next observations), shape ``(M, dim)``.

        :param key: the observation key holding the state.
        :return: float32 array of the distinct visited states of the demonstrations.
        """
        first = self.observations[key].reshape(len(self), -1)
        nxt = self.next_observations[key].reshape(len(self), -1)
        last = np.append(self.episode_starts[1:], True)  # the last transition of each episode
        return np.concatenate([first, nxt[last]]).astype(np.float32)

    def check_spaces(
        self,
        observation_space: spaces.Space | None,
        action_space: spaces.Space | None,
        where: str = "demonstrations",
    ) -> None:
        """Check that the observations and actions fit an env's spaces.

        :param observation_space: the env's Dict observation space (``None``: not checked).
        :param action_space: the env's action space (``None``: not checked).
        :param where: what to call the demonstrations in the error message.
        :raises ValueError: a key or a shape differs, named in the message.
        """
        if observation_space is not None:
            if not isinstance(observation_space, spaces.Dict):
                raise TypeError(f"demonstrations are for Dict observation spaces (goal envs), got {observation_space}")
            if set(self.observations) != set(observation_space.spaces):
                raise ValueError(
                    f"{where}: observation keys {sorted(self.observations)} differ from the env's "
                    f"{sorted(observation_space.spaces)}"
                )
            for key, space in observation_space.spaces.items():
                for name, group in (("observations", self.observations), ("next_observations", self.next_observations)):
                    if group[key].shape[1:] != space.shape:
                        raise ValueError(
                            f"{where}: {name}/{key} has shape {group[key].shape[1:]} per row, the env's space "
                            f"{space.shape}; make demonstrations for this env with scripts/make_demos.py"
                        )
        if action_space is not None and self.actions.shape[1:] != action_space.shape:
            raise ValueError(
                f"{where}: actions have shape {self.actions.shape[1:]} per row, the env's action space "
                f"{action_space.shape}"
            )

    def save(self, path: str | Path) -> None:
        """Write the file format of :func:`load_demos` (compressed).

        :param path: file path (``.npz``).
        """
        arrays: dict[str, Any] = {f"observations/{k}": v for k, v in self.observations.items()}
        arrays.update({f"next_observations/{k}": v for k, v in self.next_observations.items()})
        arrays.update(actions=self.actions, rewards=self.rewards, episode_starts=self.episode_starts)
        arrays.update({k: np.asarray(v) for k, v in self.metadata.items()})
        np.savez_compressed(path, **arrays)


def demo_path(task: str) -> Path:
    """The shipped file of a task id (``GCRL/PointUMazeGoal-v0`` -> ``demos/PointUMazeGoal-v0.npz``).

    :param task: gymnasium id.
    :return: the path (which may not exist).
    """
    return DEMOS_DIR / f"{task.split('/')[-1]}.npz"


def available_demos() -> list[str]:
    """Task names (without namespace) that ship demonstrations."""
    return sorted(p.stem for p in DEMOS_DIR.glob("*.npz"))


def load_demos(
    path_or_task: str | Path,
    observation_space: spaces.Space | None = None,
    action_space: spaces.Space | None = None,
) -> Demonstrations:
    """Read and check a demonstration file.

    :param path_or_task: a ``.npz`` path, or a gymnasium task id whose file ships with the package.
    :param observation_space: when given, the Dict observation space every observation array must match.
    :param action_space: when given, the action space the actions must match.
    :return: the demonstrations.
    :raises FileNotFoundError: no such file, and no shipped file for that task.
    :raises ValueError: a missing key, a wrong shape, a non-finite value or inconsistent lengths, named in the message.
    """
    path = Path(path_or_task)
    if path.suffix != ".npz" or not path.exists():
        shipped = demo_path(str(path_or_task))
        if not shipped.exists():
            raise FileNotFoundError(
                f"no demonstrations at {path_or_task!r}: give a .npz path, or a task id among the shipped ones "
                f"{available_demos()} (make more with scripts/make_demos.py)"
            )
        path = shipped
    with np.load(path, allow_pickle=False) as data:
        content = {key: data[key] for key in data.files}
    where = f"demonstration file {path}"
    missing = [key for key in REQUIRED_ARRAYS if key not in content]
    obs = {k.split("/", 1)[1]: v for k, v in content.items() if k.startswith("observations/")}
    next_obs = {k.split("/", 1)[1]: v for k, v in content.items() if k.startswith("next_observations/")}
    if not obs:
        missing.append("observations/<key>")
    if not next_obs:
        missing.append("next_observations/<key>")
    if missing:
        raise ValueError(f"{where} lacks {missing}; see sb3_gcrl.reset_free_baselines.demos for the format")
    if set(obs) != set(next_obs):
        raise ValueError(
            f"{where}: observation keys {sorted(obs)} differ from next_observation keys {sorted(next_obs)}"
        )
    n = len(content["actions"])
    for name, array in [("rewards", content["rewards"]), ("episode_starts", content["episode_starts"])]:
        if array.shape != (n,):
            raise ValueError(f"{where}: {name} has shape {array.shape}, expected ({n},) (one per action)")
    for name, group in (("observations", obs), ("next_observations", next_obs)):
        for key, array in group.items():
            if len(array) != n:
                raise ValueError(f"{where}: {name}/{key} has {len(array)} rows, expected {n} (one per action)")
    if n == 0 or not content["episode_starts"][0]:
        raise ValueError(f"{where}: needs at least one transition, and episode_starts[0] must be True")
    for name, array in [("actions", content["actions"]), ("rewards", content["rewards"])] + [
        (f"{g}/{k}", v) for g, grp in (("observations", obs), ("next_observations", next_obs)) for k, v in grp.items()
    ]:
        if np.issubdtype(array.dtype, np.floating) and not np.all(np.isfinite(array)):
            raise ValueError(f"{where}: {name} holds NaN or infinite values")
    metadata = {
        key: (value.item() if value.ndim == 0 else value)
        for key, value in content.items()
        if key in ("env_id", "seeds", "controller")
    }
    demos = Demonstrations(
        observations=obs,
        next_observations=next_obs,
        actions=content["actions"],
        rewards=content["rewards"].astype(np.float32),
        episode_starts=content["episode_starts"].astype(bool),
        metadata=metadata,
    )
    demos.check_spaces(observation_space, action_space, where)
    return demos

"""Resumable checkpoints of a training run: everything that shapes what the run does next, saved as one set.

A checkpoint is a folder ``<run>/checkpoints/<N>_steps/`` holding

* ``model.zip``: the model (SB3's ``save``; the step counter, and for episodic control the memory, are in it);
* ``replay_buffer.pkl``: the replay buffer, for algorithms that have one;
* ``<env name>/vecnormalize.pkl``: ``VecNormalize``'s statistics, when the env is normalised;
* ``env_state.pkl``: what the mode-switched wrappers of every training env accumulated (learned task goals, visit
  counts of the goal schedulers, counters, their generators: :meth:`~sb3_gcrl.wrappers.mode.TrainingModeMixin.
  run_state`);
* ``rng_state.pkl``: the global generators of Python, numpy and torch;
* ``extra.json``: what the caller adds (optional: a comparison's run settings and evaluations so far);
* ``checkpoint.json``: the step count and the size of every other file, written last.

The layout is RL-Zoo's for ``-i``: a model file with ``replay_buffer.pkl`` and ``<env name>/vecnormalize.pkl``
beside it. The set is written into a temporary folder that is renamed when complete, and ``<run>/checkpoints/latest``
names the newest complete set (replaced atomically), so a process killed while saving leaves the previous checkpoint
intact. Older checkpoints are deleted once a newer one is complete.

Before a run resumes, :func:`check_checkpoint` reads the set through (file sizes, the model archive's checksums, the
pickles) and names a damaged file, so that a truncated or emptied file fails before any work, not deep inside a
load.

What is not saved: the simulator's physical state (a resumed run starts with a physical reset, as after a hard
reset) and the steps taken after the checkpoint (a killed run loses them; an interrupted ``sb3-gcrl train`` saves
a checkpoint at the interruption).
"""

from __future__ import annotations

import json
import os
import pickle
import random
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

from sb3_gcrl.common.saving import atomic_write_text
from sb3_gcrl.common.validation import check_int

#: folder of a run's checkpoints
CHECKPOINTS_DIR = "checkpoints"
#: file in :data:`CHECKPOINTS_DIR` naming the newest complete checkpoint
LATEST_FILE = "latest"
#: the model file of a checkpoint
MODEL_FILE = "model.zip"
#: the replay buffer file of a checkpoint (RL-Zoo's name: ``-i <checkpoint>/model.zip`` loads it)
REPLAY_BUFFER_FILE = "replay_buffer.pkl"
ENV_STATE_FILE = "env_state.pkl"
RNG_STATE_FILE = "rng_state.pkl"
#: what the caller saved with the checkpoint (JSON; ``sb3-gcrl compare``: the run's settings and evaluations)
EXTRA_FILE = "extra.json"
#: written last: its presence marks a complete checkpoint
MANIFEST_FILE = "checkpoint.json"


class CheckpointError(ValueError):
    """A run folder without a usable checkpoint."""


def save_checkpoint(
    model: BaseAlgorithm, run_dir: str | Path, env_name: str, extra: Mapping[str, Any] | None = None
) -> Path:
    """Save a resumable checkpoint of ``model``'s run (see the module's docstring for what it holds).

    :param model: the algorithm being trained (its ``env`` is the training env).
    :param run_dir: the run's folder.
    :param env_name: the env's name as RL-Zoo writes it in folder names (``GCRL-PointUMazeGoal-v0``).
    :param extra: what else to save with it (JSON-serialisable; :func:`checkpoint_extra` reads it back).
    :return: the checkpoint's folder.
    """
    root = Path(run_dir) / CHECKPOINTS_DIR
    name = f"{model.num_timesteps}_steps"
    partial = root / f".{name}.partial-{os.getpid()}"
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    model.save(partial / MODEL_FILE)
    if getattr(model, "replay_buffer", None) is not None:
        model.save_replay_buffer(partial / REPLAY_BUFFER_FILE)  # type: ignore[attr-defined]
    vec_normalize = model.get_vec_normalize_env()
    if vec_normalize is not None:
        (partial / env_name).mkdir()
        vec_normalize.save(str(partial / env_name / "vecnormalize.pkl"))
    env = model.get_env()
    env_states = env.env_method("run_state") if env is not None and env.has_attr("run_state") else None
    (partial / ENV_STATE_FILE).write_bytes(pickle.dumps(env_states))
    rng = {"python": random.getstate(), "numpy": np.random.get_state(), "torch": th.get_rng_state()}
    (partial / RNG_STATE_FILE).write_bytes(pickle.dumps(rng))
    if extra is not None:
        (partial / EXTRA_FILE).write_text(json.dumps(extra))
    sizes = {path.relative_to(partial).as_posix(): path.stat().st_size for path in partial.rglob("*") if path.is_file()}
    (partial / MANIFEST_FILE).write_text(json.dumps({"num_timesteps": int(model.num_timesteps), "sizes": sizes}))
    target = root / name
    shutil.rmtree(target, ignore_errors=True)  # a checkpoint of the same step (an interruption right after a save)
    partial.rename(target)
    atomic_write_text(root / LATEST_FILE, name + "\n")
    for old in root.iterdir():  # older checkpoints, and partial ones of killed processes
        if old.is_dir() and old != target:
            shutil.rmtree(old, ignore_errors=True)
    return target


def latest_checkpoint(run_dir: str | Path) -> Path:
    """The newest complete checkpoint of a run.

    :param run_dir: the run's folder (``logs/<algo>/<env>_<id>``).
    :return: the checkpoint's folder.
    :raises CheckpointError: the folder has no complete checkpoint.
    """
    root = Path(run_dir) / CHECKPOINTS_DIR
    latest = root / LATEST_FILE
    if not latest.is_file():
        raise CheckpointError(
            f"{run_dir} has no checkpoint ({latest} is missing): a run saves one when interrupted (Ctrl-C) and every "
            "--save-freq steps; a run killed before either cannot be resumed"
        )
    checkpoint = root / latest.read_text().strip()
    if not (checkpoint / MANIFEST_FILE).is_file():
        raise CheckpointError(f"{latest} names {checkpoint}, which is not a complete checkpoint")
    return checkpoint


def checkpoint_steps(checkpoint: str | Path) -> int:
    """The env steps a checkpoint was taken at."""
    return int(json.loads((Path(checkpoint) / MANIFEST_FILE).read_text())["num_timesteps"])


def checkpoint_extra(checkpoint: str | Path) -> dict[str, Any] | None:
    """What :func:`save_checkpoint` was given as ``extra``, or None when it was given nothing.

    :param checkpoint: the checkpoint's folder.
    """
    path = Path(checkpoint) / EXTRA_FILE
    return json.loads(path.read_text()) if path.is_file() else None


def check_checkpoint(checkpoint: str | Path, algo_class: type) -> None:
    """Check that every file of a checkpoint is whole before a run resumes from it: each file has the size the
    checkpoint wrote (recorded in :data:`MANIFEST_FILE`), the model passes
    :func:`~sb3_gcrl.common.saving.check_model_file` (the check of ``load``), the small pickles load, and the replay
    buffer ends as a complete pickle does.

    :param checkpoint: the checkpoint's folder.
    :param algo_class: the run's algorithm (its model file must be one of this class).
    :raises CheckpointError: naming the damaged file and what is wrong with it.
    """
    from sb3_gcrl.common.saving import ModelFileError, check_model_file

    checkpoint = Path(checkpoint)

    def damaged(name: str, what: str) -> CheckpointError:
        return CheckpointError(f"{checkpoint / name} is damaged: {what}")

    try:
        manifest = json.loads((checkpoint / MANIFEST_FILE).read_text())
        int(manifest["num_timesteps"])
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise damaged(MANIFEST_FILE, f"{type(error).__name__}: {error}") from None
    for name, size in manifest.get("sizes", {}).items():  # first, so that a missing file is named as such
        path = checkpoint / name
        if not path.is_file():
            raise damaged(name, "the file is missing (a copy that left it out, e.g. one that skips *.zip files?)")
        if path.stat().st_size != size:
            raise damaged(
                name, f"{path.stat().st_size:,} bytes where the checkpoint wrote {size:,} (cut off or altered)"
            )
    try:
        check_model_file(checkpoint / MODEL_FILE, algo_class)
    except (ModelFileError, OSError) as error:  # the message names the file
        raise CheckpointError(str(error)) from None
    for name in (ENV_STATE_FILE, RNG_STATE_FILE):
        try:
            pickle.loads((checkpoint / name).read_bytes())
        except Exception as error:  # a damaged pickle raises almost anything
            raise damaged(name, f"it does not load ({type(error).__name__}: {error})") from None
    replay_buffer = checkpoint / REPLAY_BUFFER_FILE
    if replay_buffer.is_file():
        with replay_buffer.open("rb") as file:
            file.seek(0, os.SEEK_END)
            end = file.tell()
            file.seek(max(0, end - 1))
            if file.read(1) != pickle.STOP:
                raise damaged(REPLAY_BUFFER_FILE, f"its {end:,} bytes end before the end of the pickle (cut off)")


def restore_checkpoint(model: BaseAlgorithm, checkpoint: str | Path) -> None:
    """Restore what the model file does not hold: the training envs' wrapper state and the global generators.

    Load the model (with the replay buffer and ``VecNormalize``) first, e.g. through RL-Zoo's ``-i``.

    :param model: the loaded model, with its training env.
    :param checkpoint: the checkpoint's folder.
    :raises CheckpointError: the checkpoint's env state does not fit the model's env.
    """
    checkpoint = Path(checkpoint)
    env_states: list[bytes] | None = pickle.loads((checkpoint / ENV_STATE_FILE).read_bytes())
    env = model.get_env()
    has_state = env is not None and env.has_attr("run_state")
    if env_states is not None:
        if not has_state or len(env_states) != env.num_envs:  # type: ignore[union-attr]
            raise CheckpointError(
                f"{checkpoint} holds the wrapper state of {len(env_states)} env(s), which the resumed run's env "
                "cannot take: resume with the run's own env_wrapper and n_envs"
            )
        for i, state in enumerate(env_states):
            env.env_method("load_run_state", state, indices=i)  # type: ignore[union-attr]
    rng: dict[str, Any] = pickle.loads((checkpoint / RNG_STATE_FILE).read_bytes())
    random.setstate(rng["python"])
    np.random.set_state(rng["numpy"])
    th.set_rng_state(rng["torch"])


class RunCheckpointCallback(BaseCallback):
    """Save a resumable checkpoint (:func:`save_checkpoint`) every ``save_freq`` calls, keeping the newest only.

    :param save_freq: calls (vectorised env steps) between checkpoints.
    :param run_dir: the run's folder.
    :param env_name: the env's name as RL-Zoo writes it in folder names.
    :param extra: called at each checkpoint for what to save with it (:func:`save_checkpoint`'s ``extra``).
    :param verbose: 1 prints each checkpoint's folder.
    """

    def __init__(
        self,
        save_freq: int,
        run_dir: str | Path,
        env_name: str,
        extra: Callable[[], Mapping[str, Any]] | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        self.save_freq = check_int("save_freq", save_freq)
        self.run_dir = Path(run_dir)
        self.env_name = env_name
        self.extra = extra

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            extra = None if self.extra is None else self.extra()
            path = save_checkpoint(self.model, self.run_dir, self.env_name, extra)
            if self.verbose:
                print(f"Saved a resumable checkpoint to {path}")
        return True

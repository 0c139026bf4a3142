"""The package's argument checks: hyperparameters, rewards and saved memory states, with errors that name the
offending parameter and the fix.

One module for every algorithm, memory, replay buffer, wrapper and env of the package, so that a bad value fails at
construction with the same message wherever it enters (``CEC(capacity=1.7)``, ``CECMemory(...)``,
``policy_kwargs``, a replay buffer's ``n_sampled_goal``), and a corrupted saved memory fails with what is wrong
with it.

* numbers: :func:`check_int`, :func:`check_optional_int`, :func:`check_float`, :func:`check_unit_interval`,
  :func:`check_step_size`;
* switches and names: :func:`check_bool`, :func:`check_choice`;
* HER: :func:`check_n_sampled_goal`;
* data: :func:`check_finite_rewards`, :func:`check_finite_returns`, :func:`check_saved_rows`;
* files: :func:`check_writable_folder` (an output folder, before work starts);
* (every reward an SB3 off-policy algorithm of the package stores is checked by
  :class:`~sb3_gcrl.common.transitions.TransitionHooksMixin` with :func:`check_finite_rewards`).
"""

from __future__ import annotations

import math
import numbers
import os
import shutil
import tempfile
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def check_int(name: str, value: Any, minimum: int = 1) -> int:
    """Return ``value`` as an ``int`` after checking that it is an integer ``>= minimum``.

    Integral floats (``1e6``, or YAML's ``!!float 1e6``) are accepted; ``1.7`` is not truncated.

    :param name: parameter name used in the error message.
    :param value: the value to check.
    :param minimum: smallest allowed value.
    :return: ``value`` as a Python ``int``.
    :raises TypeError: if ``value`` is not a real number (``bool`` included).
    :raises ValueError: if ``value`` is not integral or is below ``minimum``.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be an integer, got {value!r} of type {type(value).__name__}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite integer, got {value!r}")
    if value != math.floor(value):
        suggestion = max(minimum, round(value))
        raise ValueError(f"{name} must be an integer, got {value!r} (not truncated); pass e.g. {name}={suggestion}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    return int(value)


def check_optional_int(name: str, value: Any, minimum: int = 1) -> int | None:
    """:func:`check_int`, letting ``None`` through.

    :param name: parameter name used in the error message.
    :param value: the value to check, or ``None``.
    :param minimum: smallest allowed value.
    :return: ``value`` as an ``int``, or ``None``.
    """
    return None if value is None else check_int(name, value, minimum)


def check_float(
    name: str,
    value: Any,
    minimum: float | None = None,
    maximum: float | None = None,
    exclusive_minimum: bool = False,
) -> float:
    """Return ``value`` as a finite ``float`` within ``[minimum, maximum]`` (``(minimum, maximum]`` if
    ``exclusive_minimum``).

    :param name: parameter name used in the error message.
    :param value: the value to check.
    :param minimum: lower bound, ``None`` for none.
    :param maximum: upper bound (inclusive), ``None`` for none.
    :param exclusive_minimum: whether ``value == minimum`` is rejected.
    :return: ``value`` as a Python ``float``.
    :raises TypeError: if ``value`` is not a real number (``bool`` included).
    :raises ValueError: if ``value`` is NaN, infinite or out of bounds.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number, got {value!r} of type {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if minimum is not None and (value <= minimum if exclusive_minimum else value < minimum):
        raise ValueError(f"{name} must be {'>' if exclusive_minimum else '>='} {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be <= {maximum}, got {value!r}")
    return value


def check_unit_interval(name: str, value: Any, exclude_zero: bool = False) -> float:
    """Return ``value`` as a ``float`` after checking that it is a real number in [0, 1] (``(0, 1]`` with
    ``exclude_zero``): a probability, a discount, a tabular step size.

    :param name: parameter name used in the error message.
    :param value: the value to check.
    :param exclude_zero: also reject 0 (e.g. a tabular learning rate, which would never change the table).
    :return: ``value`` as a Python ``float``.
    :raises ValueError: naming ``name`` and the interval, for anything else (a non-number, NaN included).
    """
    try:
        return check_float(name, value, 0.0, 1.0, exclusive_minimum=exclude_zero)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number in {'(0' if exclude_zero else '[0'}, 1], got {value!r}") from error


def check_step_size(name: str, value: Any) -> None:
    """Check a tabular step size ``Q <- Q + lr * (target - Q)``, a constant or a schedule of the remaining progress
    (SB3's and RL-Zoo's ``learning_rate``): in (0, 1], since 0 never changes the table and above 1 each update
    overshoots its target and the table diverges. A schedule is checked at the start and the end of training.

    :param name: parameter name used in the error message.
    :param value: the step size, or a callable ``progress_remaining -> step size``.
    :raises ValueError: naming ``name`` (and the progress of a schedule), for a value outside (0, 1].
    """
    if not callable(value):
        check_unit_interval(name, value, exclude_zero=True)
        return
    for progress_remaining in (1.0, 0.0):
        check_unit_interval(
            f"{name} (schedule at progress_remaining={progress_remaining})",
            value(progress_remaining),
            exclude_zero=True,
        )


def check_bool(name: str, value: Any) -> bool:
    """Return ``value`` as a ``bool`` after checking that it is one (``"false"`` from a command line would be true).

    :param name: parameter name used in the error message.
    :param value: the value to check.
    :return: ``value`` as a Python ``bool``.
    :raises ValueError: naming ``name``, for anything but ``True`` / ``False``.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _one_of(choices: Collection[Any]) -> str:
    """``'a', 'b' or 'c'`` (``None`` unquoted)."""
    names = [repr(choice) for choice in choices]
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def check_choice(name: str, value: Any, choices: Collection[Any]) -> Any:
    """Return ``value`` after checking that it is one of ``choices``.

    :param name: parameter name used in the error message.
    :param value: the value to check.
    :param choices: the accepted values, in the order the message lists them.
    :return: ``value``.
    :raises ValueError: listing the choices.
    """
    if value not in choices:
        raise ValueError(f"{name} must be {_one_of(choices)}, got {value!r}")
    return value


def check_n_sampled_goal(n_sampled_goal: Any, minimum: int = 0, why: str = "") -> int:
    """Check HER's ``n_sampled_goal`` before a HER buffer divides by ``n_sampled_goal + 1``.

    HER relabels ``n_sampled_goal / (n_sampled_goal + 1)`` of each batch: 0 relabels nothing, -1 divides by zero
    and below -1 asks for more relabeled transitions than the batch has.

    :param n_sampled_goal: relabeled goals per real transition.
    :param minimum: the smallest value that makes sense where it is used (0, or 1 where relabeling is needed).
    :param why: why ``minimum`` is above 0 (appended to the message).
    :return: ``n_sampled_goal`` as an int.
    :raises ValueError: naming the valid range, for a value that is not an integer >= ``minimum``.
    """
    try:
        return check_int("n_sampled_goal", n_sampled_goal, minimum)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"n_sampled_goal must be an integer >= {minimum} (relabeled goals per real transition: HER relabels "
            f"n_sampled_goal / (n_sampled_goal + 1) of each batch, 0 none), got {n_sampled_goal!r}{why}"
        ) from error


def check_finite_rewards(rewards: float | np.ndarray, when: str, why: str, source: str | None = None) -> None:
    """Reject a NaN or infinite reward where it enters learning, naming where it came from and ``VecCheckNan``.

    :param rewards: one reward, or one per env.
    :param when: when it was returned (e.g. ``"at timestep 120"``).
    :param why: what a non-finite reward would break.
    :param source: what returned it (default: ``"Env <index of the first bad reward>"``).
    :raises ValueError: if a reward is NaN or infinite.
    """
    values = np.asarray(rewards, dtype=np.float64).reshape(-1)
    if np.isfinite(values).all():
        return
    index = int(np.flatnonzero(~np.isfinite(values))[0])
    raise ValueError(
        f"{source or f'Env {index}'} returned the reward {values[index]} {when}: {why}; fix the env's reward, or wrap "
        "it with stable_baselines3.common.vec_env.VecCheckNan to find the source"
    )


def check_finite_returns(returns: np.ndarray) -> None:
    """Reject NaN or infinite returns before they reach a memory (one NaN would spread to every value
    that is compared with it, silently).

    :param returns: ``(T,)`` discounted returns of one episode.
    :raises ValueError: if a return is NaN or infinite.
    """
    if not np.isfinite(returns).all():
        bad = returns[~np.isfinite(returns)]
        raise ValueError(
            f"Episode returns contain {bad[0]} ({len(bad)} non-finite of {len(returns)}): episodic memory values "
            "must be finite; fix the env's rewards (wrap it with stable_baselines3.common.vec_env.VecCheckNan to "
            "find the source) or lower their scale"
        )


def check_saved_rows(
    state: Mapping[str, Any],
    owner: str,
    key_dim: int,
    capacity: int,
    row_fields: Sequence[str],
) -> np.ndarray:
    """Check a saved memory state (``keys`` plus per-row fields, ``last_update`` and ``clock``) before
    restoring it, and return its keys.

    :param state: what the memory's ``state_dict()`` returned (possibly after a file round trip).
    :param owner: memory name used in the error message.
    :param key_dim: key dimension the restoring memory expects.
    :param capacity: capacity of the restoring memory.
    :param row_fields: names of the other per-row arrays (one entry per key, along the first axis).
    :return: the keys as a C-contiguous ``(n, key_dim)`` float32 array.
    :raises ValueError: naming what is missing, mis-shaped, non-finite or over capacity.
    """
    required = ["keys", *row_fields, "last_update", "clock"]
    missing = [name for name in required if name not in state]
    if missing:
        raise ValueError(f"Saved {owner} state lacks {missing} (has {sorted(state)}); it was not written by {owner}")
    keys = np.ascontiguousarray(state["keys"], dtype=np.float32)
    if keys.ndim != 2 or keys.shape[1] != key_dim:
        raise ValueError(f"Saved {owner} keys have shape {keys.shape}, this memory expects (n, {key_dim})")
    n = len(keys)
    if n > capacity:
        raise ValueError(f"Saved {owner} has {n} rows, more than capacity={capacity}; raise the capacity")
    for name in (*row_fields, "last_update"):
        rows = np.asarray(state[name])
        if rows.ndim == 0 or len(rows) != n:
            raise ValueError(f"Saved {owner} is corrupted: {name!r} has shape {rows.shape}, but there are {n} keys")
        if not np.isfinite(rows).all():
            raise ValueError(f"Saved {owner} is corrupted: {name!r} contains NaN or inf")
    if not np.isfinite(keys).all():
        raise ValueError(f"Saved {owner} is corrupted: 'keys' contains NaN or inf")
    last_update = np.asarray(state["last_update"])
    if n and int(state["clock"]) < int(last_update.max()):
        raise ValueError(f"Saved {owner} is corrupted: clock {int(state['clock'])} precedes its last update times")
    return keys


#: free bytes below which an output folder's disk counts as full
MIN_FREE_BYTES = 1 << 20


def check_writable_folder(name: str, folder: str | os.PathLike[str]) -> Path:
    """Check, before work starts, that files can be written in ``folder``: a small file is written, synced and removed
    there (or, when the folder does not exist yet, in its nearest existing parent, where it would be created), and the
    disk must have :data:`MIN_FREE_BYTES` free. Nothing is left behind.

    Without it a read-only or full folder fails at the run's first save, after the setup (or the training) it cost.

    :param name: what the folder is, for the message (``"the log folder (-f)"``).
    :param folder: the folder.
    :return: ``folder`` as a path.
    :raises ValueError: naming the folder, what is wrong (the system's reason, or the free space) and the fix.
    """
    folder = Path(folder)
    other = f"pass another {name.removeprefix('the ')}"
    existing = folder.absolute()
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"Cannot write in {name} {folder}: {existing} is a file, not a folder; {other}")
    try:
        with tempfile.TemporaryFile(dir=existing) as probe:
            probe.write(bytes(4096))
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as error:
        raise ValueError(
            f"Cannot write in {name} {folder} ({error.strerror or error}): {other}, or make this one writable "
            "(permissions, a read-write mount)"
        ) from None
    free = shutil.disk_usage(existing).free
    if free < MIN_FREE_BYTES:
        raise ValueError(
            f"{name[0].upper()}{name[1:]} {folder} is on a full disk ({free:,} bytes free): free some space there, or "
            f"{other}"
        )
    return folder

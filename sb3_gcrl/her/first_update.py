"""A HER buffer's first sample against the reset-free segments: refused before training when it would come too soon.

SB3's :class:`~stable_baselines3.HerReplayBuffer` samples finished episodes only, and raises "Unable to sample
before the end of the first episode" when the first update comes before any episode has ended. In reset-free
training the episodes SB3 sees are the wrappers' segments (:class:`~sb3_gcrl.wrappers.ResetFreeWrapper`: up to the
next hard reset, often 1e5 steps away, unless ``segment_length`` cuts them), so a ``learning_starts`` that suits
episodic training fails at the first update. :func:`check_her_first_update` finds it at the start of ``learn``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.type_aliases import TrainFrequencyUnit
from stable_baselines3.common.vec_env import VecEnv


def steps_per_env_before_first_update(model: Any, total_timesteps: int) -> int | None:
    """Steps each env takes before the first update of SB3's off-policy ``learn``, counted from now.

    ``learn`` collects ``train_freq`` steps (of every env) at a time and updates after a collection once
    ``num_timesteps > learning_starts``.

    :param model: an SB3 off-policy algorithm set up for ``learn`` (``num_timesteps``, ``n_envs``, ``learning_starts``,
        ``train_freq`` as a :class:`~stable_baselines3.common.type_aliases.TrainFreq`).
    :param total_timesteps: the step count at which ``learn`` ends.
    :return: the steps per env, or None when no update comes within the budget or a collection ends at an episode's
        end (``train_freq`` counted in episodes: an episode has then ended before the update).
    """
    train_freq = model.train_freq
    if train_freq.unit != TrainFrequencyUnit.STEP:
        return None
    n_envs, done = int(model.n_envs), int(model.num_timesteps)
    # the first vector step after which num_timesteps > learning_starts, rounded up to the end of its collection
    step = max(1, (int(model.learning_starts) - done) // n_envs + 1)
    collections = -(-step // train_freq.frequency)
    if done + (collections - 1) * train_freq.frequency * n_envs >= total_timesteps:  # learn ends before that collection
        return None
    return collections * train_freq.frequency


def check_her_first_update(model: Any, env: VecEnv, total_timesteps: int, caller: str) -> None:
    """Refuse a HER buffer whose first sample would come before the first training segment ends.

    Checked when the buffer holds no step yet (a run that resumes with its buffer has finished segments), for models
    that sample their HER buffer from the first update on (:class:`~sb3_gcrl.reset_free_baselines.ForwardBackwardSAC`
    waits for a finished segment: ``waits_for_finished_episodes``).

    :param model: the algorithm about to learn.
    :param env: its training env, in training mode (its wrappers report ``longest_segment``).
    :param total_timesteps: the step count at which ``learn`` ends.
    :param caller: who checks (named in the error).
    :raises ValueError: naming ``learning_starts``, the segment length and both fixes.
    """
    buffer = getattr(model, "replay_buffer", None)
    if not isinstance(buffer, HerReplayBuffer) or getattr(model, "waits_for_finished_episodes", False):
        return
    if buffer.full or buffer.pos > 0 or np.any(buffer.ep_length > 0) or not env.has_attr("longest_segment"):
        return
    bounds = [bound for bound in env.get_attr("longest_segment") if bound is not None]
    steps = steps_per_env_before_first_update(model, total_timesteps)
    if not bounds or steps is None or steps >= min(bounds):
        return
    segment, n_envs = min(bounds), int(model.n_envs)
    # the smallest learning_starts whose first update comes after `segment` steps per env
    minimum = int(model.num_timesteps) + (segment - 1) * n_envs
    per_env = f" ({n_envs} envs)" if n_envs > 1 else ""
    raise ValueError(
        f"{caller}: the {type(buffer).__name__} would be sampled at the first update, after {steps} steps per env "
        f"(learning_starts={model.learning_starts}{per_env}), but the first training segment lasts up to {segment} "
        "steps (ResetFreeWrapper's hard_reset_every or segment_length, GoExploreWrapper's go_steps + explore_steps; it "
        "ends earlier only at a terminal state or a success), and HER samples finished segments only (SB3: 'Unable "
        f"to sample before the end of the first episode'). Raise learning_starts to at least {minimum}, or shorten "
        "the segments (ResetFreeWrapper(segment_length=...))"
    )

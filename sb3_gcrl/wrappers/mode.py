"""Training vs evaluation mode of the reset-free and goal-commanding wrappers (thesis Ch. 3 and Ch. 6).

RL-Zoo wraps its evaluation env with the same ``env_wrapper`` as the training env, and evaluation must stay
episodic (reset to rho_0, the env's own goal from rho_g*). So every wrapper here starts in **evaluation mode**
and only the training env is switched to **training mode** (reset-free segments, commanded goals,
post-exploration), by the callback named in the wrapper's :attr:`TrainingModeMixin.switching_callback`
(:class:`~sb3_gcrl.callbacks.ResetFreeCallback`, :class:`~sb3_gcrl.post_exploration.PostExplorationCallback`).

Forgetting that callback would silently train episodically. The wrapper therefore checks, at the first step
after each physical reset while it is in evaluation mode that nobody chose, whether it is being stepped by an
SB3 algorithm's ``collect_rollouts`` (and not by ``evaluate_policy``); if so it warns once, naming the callback.
Calling ``set_training_mode(False)`` states that episodic training is meant and silences the check. The check
looks at the Python call stack of the process that steps the env, so it cannot see training through a
``SubprocVecEnv`` (the worker process runs no SB3 code): there, rely on the callback (``sb3-gcrl train`` and
``sb3-gcrl compare`` refuse configs without it).

In training mode the outermost mode-switched wrapper of a chain reports the segments it shows SB3 as episodes
(``info["episode"]``, the Monitor CSV; :mod:`sb3_gcrl.wrappers.segments`); wrappers below it pass the mode on only.
"""

from __future__ import annotations

import math
import pickle
import sys
import warnings
from typing import Any, SupportsFloat

import gymnasium as gym
from stable_baselines3.common.env_util import unwrap_wrapper
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv

from sb3_gcrl.common.validation import check_finite_rewards
from sb3_gcrl.wrappers.segments import SegmentRecorder


def stepped_by_sb3_training() -> bool:
    """Whether the current call comes from an SB3 algorithm collecting training data (not from evaluation).

    :return: True when an SB3 ``collect_rollouts`` frame is found on the call stack before any ``evaluate_policy``.
    """
    from stable_baselines3.common.base_class import BaseAlgorithm

    frame = sys._getframe(1)
    while frame is not None:
        name = frame.f_code.co_name
        if name == "evaluate_policy":
            return False
        if name == "collect_rollouts" and isinstance(frame.f_locals.get("self"), BaseAlgorithm):
            return True
        frame = frame.f_back  # type: ignore[assignment]
    return False


class TrainingModeMixin:
    """Evaluation/training mode of a wrapper, switched by a callback for the training env only.

    Subclasses call :meth:`_init_training_mode` in ``__init__``, :meth:`_arm_mode_check` at physical resets and
    :meth:`_check_mode` at the first evaluation-mode step after them, and may override
    :meth:`_on_training_mode` to apply the switch. In training mode, when :attr:`_recording` is True (the outermost
    mode-switched wrapper), they pass every step to :attr:`_segments` and call its ``begin`` at every reset.
    """

    #: dotted path of the callback that switches the training env to training mode (named in errors and warnings)
    switching_callback = "sb3_gcrl.callbacks.ResetFreeCallback"
    #: True in training mode, False in evaluation (episodic) mode
    training: bool
    #: attributes holding what training has accumulated (learned task goals, visit counts, counters, generators):
    #: saved with a run's checkpoint (:meth:`run_state`) and restored when the run resumes. The simulator's physical
    #: state is not among them: a resumed run starts with a physical reset.
    run_state_attributes: tuple[str, ...] = ()

    def _init_training_mode(self, warns: bool = True) -> None:
        """Start in evaluation mode.

        :param warns: whether this wrapper warns about training without the callback (False when a wrapper
            below it owns the mode and warns instead).
        """
        self.training = False
        self._mode_chosen = False
        self._mode_check_armed = warns
        #: True while this wrapper reports the segments SB3 sees (training mode, no mode-switched wrapper above it)
        self._recording = False
        self._has_mode_above = False
        env = self.env  # type: ignore[attr-defined]
        self._segments = SegmentRecorder(unwrap_wrapper(env, Monitor))

    def _pass_mode_to(self, below: TrainingModeMixin | None) -> None:
        """Make ``below`` (a mode-switched wrapper under this one) follow this wrapper's mode without reporting."""
        if below is not None:
            below._has_mode_above = True

    def set_training_mode(self, training: bool) -> None:
        """Switch between training mode (``True``) and evaluation mode (``False``, episodic).

        The switching callback calls ``set_training_mode(True)`` on the training env at the start of ``learn``.
        Call ``set_training_mode(False)`` yourself to train episodically on purpose (silences the warning).

        :param training: the mode.
        """
        self.training = bool(training)
        self._mode_chosen = True
        self._mode_check_armed = False
        self._recording = self.training and not self._has_mode_above
        self._segments.take_over_monitor(self._recording)
        self._on_training_mode(self.training)

    def close(self) -> None:
        """Give the Monitor its CSV back (it closes it), then close the env."""
        self._segments.close()
        super().close()  # type: ignore[misc]

    def _on_training_mode(self, training: bool) -> None:  # noqa: B027 (optional hook)
        """Apply a mode switch (no-op by default)."""

    def _check_reward(self, reward: SupportsFloat) -> None:
        """Reject a NaN or infinite reward where the chain hands it to SB3 (in the outermost mode-switched wrapper,
        in both modes), so that a plain SB3 algorithm stops at the step that returned it instead of failing later
        inside torch (the package's own algorithms check what they store: :class:`~sb3_gcrl.common.transitions.
        TransitionHooksMixin`).

        :param reward: the reward this wrapper returns.
        :raises ValueError: naming the wrapper, the mode and ``VecCheckNan``, for a non-finite reward.
        """
        if self._has_mode_above or (isinstance(reward, float) and math.isfinite(reward)):  # hot path: every step
            return
        check_finite_rewards(
            reward,  # type: ignore[arg-type]
            f"in {'training' if self.training else 'evaluation'} mode",
            "SB3 learns from it (a NaN makes the networks' losses and actions NaN, and training fails later inside "
            "torch)",
            source=f"The env wrapped in {type(self).__name__}",
        )

    @property
    def longest_segment(self) -> int | None:
        """The most steps a training-mode segment (what SB3 sees as an episode) lasts from its reset: the tightest
        bound of this wrapper and the mode-switched wrappers below it, None when none of them bounds it. A segment
        ends earlier at a terminal state, or where a wrapper ends it at success.
        """
        bounds = [bound for wrapper in self._mode_chain() if (bound := wrapper._segment_bound()) is not None]
        return min(bounds) if bounds else None

    def _segment_bound(self) -> int | None:
        """This wrapper's own bound on the training-mode segments (None: it does not cut them)."""
        return None

    # --- run state (checkpoints, resume) --------------------------------------------------------------------------
    def _mode_chain(self) -> list[TrainingModeMixin]:
        """This wrapper and the mode-switched wrappers below it, outermost first."""
        chain: list[TrainingModeMixin] = []
        inner: Any = self
        while isinstance(inner, gym.Wrapper):
            if isinstance(inner, TrainingModeMixin):
                chain.append(inner)
            inner = inner.env
        return chain

    def run_state(self) -> bytes:
        """What this wrapper and the mode-switched wrappers below it accumulated in training, pickled together (so
        objects they share stay shared): each wrapper's :attr:`run_state_attributes`.

        :return: the pickled state, for :meth:`load_run_state` on a wrapper chain built the same way.
        """
        return pickle.dumps(
            [
                (type(wrapper).__name__, {name: getattr(wrapper, name) for name in wrapper.run_state_attributes})
                for wrapper in self._mode_chain()
            ]
        )

    def load_run_state(self, state: bytes) -> None:
        """Restore what :meth:`run_state` saved (pickle: load trusted files only).

        :param state: the pickled state.
        :raises ValueError: the state was saved from a different chain of wrappers.
        """
        saved = pickle.loads(state)
        chain = self._mode_chain()
        saved_names = [name for name, _ in saved]
        names = [type(wrapper).__name__ for wrapper in chain]
        if saved_names != names:
            raise ValueError(
                f"the saved run state is of the wrappers {saved_names}, but this env has {names}: resume with the "
                "env_wrapper of the run that saved it"
            )
        for wrapper, (_, attributes) in zip(chain, saved):
            for name, value in attributes.items():
                setattr(wrapper, name, value)
            wrapper._on_run_state_loaded()

    def _on_run_state_loaded(self) -> None:  # noqa: B027 (optional hook)
        """Reconnect what the saved state could not hold (references to the env); no-op by default."""

    def _arm_mode_check(self) -> None:
        """Check the next step (called at physical resets while the mode was never chosen)."""
        if not self._mode_chosen:
            self._mode_check_armed = True

    def _check_mode(self) -> None:
        """Warn once if SB3 trains on this env while it was left in evaluation mode."""
        self._mode_check_armed = False
        if self._mode_chosen or not stepped_by_sb3_training():
            return
        self._mode_chosen = True  # warn once
        callback = self.switching_callback.rsplit(".", 1)[-1]
        warnings.warn(
            f"{type(self).__name__} is being trained on but was never switched to training mode, so training is "
            f"plain episodic training: pass callback={callback}() to model.learn (RL-Zoo: list "
            f"{self.switching_callback} under callback), or call set_training_mode(False) on the env to train "
            "episodically on purpose.",
            UserWarning,
            stacklevel=3,
        )


def switch_training_envs(env: VecEnv, callback_path: str, wrap_hint: str) -> None:
    """Put every env of a training VecEnv in training mode, after checking it is meant for this callback.

    :param env: the training VecEnv.
    :param callback_path: dotted path of the calling callback.
    :param wrap_hint: what to wrap the env in, for the error message.
    :raises TypeError: when the env has no mode-switched wrapper, or one switched by another callback.
    """
    callback = callback_path.rsplit(".", 1)[-1]
    if not env.has_attr("switching_callback"):
        raise TypeError(f"{callback}: the training env has no mode-switched wrapper; wrap it in {wrap_hint}")
    wanted = set(env.get_attr("switching_callback"))
    if wanted != {callback_path}:
        raise TypeError(f"{callback}: the training env's wrappers are switched by {sorted(wanted)}; use that callback")
    env.env_method("set_training_mode", True)

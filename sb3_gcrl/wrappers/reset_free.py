"""Reset-free training wrapper (thesis Ch. 3, Section 3.7.1; EARL/IBC protocol).

In reset-free training the physical env is reset only every ``hard_reset_every`` steps (EARL: 1e5-2e5) and
at true terminal states the agent cannot leave; every physical reset is an *intervention* and is counted.
The agent (SB3) still sees finite *segments*: a segment ends with ``truncated=True`` (the ``TimeLimit``
semantics SB3 turns into ``info["TimeLimit.truncated"]``, so the value target bootstraps), never with a fake
terminal, and the next ``reset()`` returns the *current* state instead of resetting.

The wrapper has two modes (:mod:`sb3_gcrl.wrappers.mode`):

* evaluation mode (the default, at construction): every ``reset()`` is physical, episodes last at most
  ``eval_horizon`` steps. This is what evaluation and ``rl_zoo3 enjoy`` see. RL-Zoo wraps its eval env with the
  same ``env_wrapper`` as the train env, so the wrapper must be episodic unless told otherwise.
* training mode (reset-free): switched on for the *training* env only, by ``set_training_mode(True)``, which
  :class:`sb3_gcrl.callbacks.ResetFreeCallback` calls at the start of ``learn``.

Any gymnasium env can be trained reset-free (EARL's tasks need not be goal envs): this wrapper accepts plain
envs. What needs a goal env is what MoReFree adds on top, the task-relevant goals rho_0/rho_g* and commanded
goals (:class:`~sb3_gcrl.wrappers.GoalCommandWrapper`, :class:`~sb3_gcrl.wrappers.GoExploreWrapper`,
:class:`~sb3_gcrl.her.TaskRelevantHerReplayBuffer`), which refuse other envs.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
from gymnasium.wrappers import TimeLimit

from sb3_gcrl.envs.tasks import EARL_HARD_RESET_EVERY, find_task
from sb3_gcrl.wrappers.goal_env import record_constructor_args
from sb3_gcrl.wrappers.mode import TrainingModeMixin
from sb3_gcrl.wrappers.segments import missing_info_keyword


class ResetFreeWrapper(TrainingModeMixin, gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Physical resets every ``hard_reset_every`` steps; SB3 sees truncated segments in between.

    :param env: the env to train without resets: any gymnasium env (a plain env is fine; the goal wrappers on
        top, which MoReFree needs, require a goal env).
    :param hard_reset_every: env steps between two physical resets (interventions) in reset-free mode; ``None``:
        the task's (:data:`sb3_gcrl.envs.tasks.TASKS`, EARL/IBC protocol), or EARL's 2e5 for an env the table lacks.
    :param segment_length: length of the segments SB3 sees in reset-free mode (``None``: segments end only at
        hard resets, or when an outer wrapper truncates, e.g. :class:`GoExploreWrapper` after each Go-Explore).
    :param eval_horizon: episode length in episodic mode (evaluation); ``None``: the task's (the table's, which
        is also its registered ``max_episode_steps``), or the inner env's own time limit for an env the table
        lacks (``None`` when it has none).
    """

    run_state_attributes = ("interventions", "terminal_interventions", "total_steps")

    def __init__(
        self,
        env: gym.Env,
        hard_reset_every: int | None = None,
        segment_length: int | None = None,
        eval_horizon: int | None = None,
    ) -> None:
        record_constructor_args(self, locals())
        super().__init__(env)
        for name, value in (
            ("hard_reset_every", hard_reset_every),
            ("segment_length", segment_length),
            ("eval_horizon", eval_horizon),
        ):
            if value is not None and (int(value) != value or value < 1):
                raise ValueError(f"{name} must be a positive integer, got {value}")
        task = find_task(env)
        if hard_reset_every is None:
            hard_reset_every = task.hard_reset_every if task is not None and task.reset_free else EARL_HARD_RESET_EVERY
        if eval_horizon is None and task is not None:
            eval_horizon = task.eval_horizon
        self.hard_reset_every = int(hard_reset_every)
        self.segment_length = None if segment_length is None else int(segment_length)
        self.eval_horizon = None if eval_horizon is None else int(eval_horizon)
        self._init_training_mode()
        #: physical resets so far (every reset in episodic mode, hard/terminal resets in reset-free mode)
        self.interventions = 0
        #: physical resets caused by a terminal state the agent could not leave
        self.terminal_interventions = 0
        self.total_steps = 0
        self._steps_since_reset = 0
        self._segment_steps = 0
        self._needs_physical_reset = True
        self._last_obs: Any = None
        self._last_info: dict[str, Any] = {}
        # Inner time limits end the physical episodes, which is what SB3's Monitor (placed below the env_wrapper
        # by make_vec_env / RL-Zoo) records and what evaluate_policy counts: they are set to eval_horizon in
        # episodic mode and to hard_reset_every in reset-free mode.
        self._time_limits: list[TimeLimit] = []
        inner = self.env
        has_monitor = False
        while isinstance(inner, gym.Wrapper):
            if isinstance(inner, TimeLimit):
                self._time_limits.append(inner)
            has_monitor = has_monitor or type(inner).__name__ == "Monitor"
            inner = inner.env
        self._own_limits = [limit._max_episode_steps for limit in self._time_limits]
        if self.eval_horizon is None and self._own_limits:  # an env of your own: its time limit
            self.eval_horizon = int(min(self._own_limits))
        if self.eval_horizon is not None:
            if not self._time_limits and has_monitor:
                raise ValueError(
                    "ResetFreeWrapper(eval_horizon=...) needs a TimeLimit inside the Monitor so that evaluation "
                    "episodes end where Monitor/evaluate_policy see them: register the env with max_episode_steps "
                    "(or wrap it in gymnasium.wrappers.TimeLimit before Monitor)"
                )
            for limit in self._time_limits:
                limit._max_episode_steps = self.eval_horizon

    def _on_training_mode(self, training: bool) -> None:
        """Set inner time limits to ``hard_reset_every`` (training) or ``eval_horizon`` (evaluation).

        Inner ``TimeLimit`` wrappers (e.g. PointMaze's 300 steps) would otherwise end the physical episode early
        in training; their limit becomes the hard-reset interval so that they coincide with the hard reset.
        """
        for limit, own in zip(self._time_limits, self._own_limits):
            if training:
                limit._max_episode_steps = self.hard_reset_every
            else:
                limit._max_episode_steps = own if self.eval_horizon is None else self.eval_horizon

    def _segment_bound(self) -> int:
        """A segment ends at the next hard reset, or after ``segment_length`` steps."""
        return min(self.hard_reset_every, self.segment_length or self.hard_reset_every)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if not self.training or self._needs_physical_reset or seed is not None or options:
            obs, info = self.env.reset(seed=seed, options=options)
            self._arm_mode_check()
            self.interventions += 1
            self._steps_since_reset = 0
            self._needs_physical_reset = False
            info = dict(info, physical_reset=True)
        else:
            obs, info = self._last_obs, dict(self._last_info, physical_reset=False)
        self._segment_steps = 0
        self._segments.begin()
        self._last_obs, self._last_info = obs, info
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        try:
            obs, reward, terminated, truncated, info = self.env.step(action)
        except KeyError as error:  # SB3's Monitor below, at an episode's end, missing one of its info_keywords
            if error.args and error.args[0] in self._segments.info_keywords:
                raise missing_info_keyword(error.args[0]) from error
            raise
        self._check_reward(reward)
        self.total_steps += 1
        self._steps_since_reset += 1
        self._segment_steps += 1
        if not self.training:
            if self._mode_check_armed:
                self._check_mode()
            if self.eval_horizon is not None and self._segment_steps >= self.eval_horizon:
                truncated = True
            return obs, reward, terminated, truncated, info
        if terminated:
            # a true terminal state: the episode really ends and a physical reset (intervention) follows
            self.terminal_interventions += 1
            self._needs_physical_reset = True
        elif truncated or self._steps_since_reset >= self.hard_reset_every:
            # inner time limit (lifted to hard_reset_every) or hard reset due: cut the segment, reset next time
            self._needs_physical_reset = True
            truncated = True
        elif self.segment_length is not None and self._segment_steps >= self.segment_length:
            truncated = True
        self._last_obs, self._last_info = obs, info
        if self._recording:  # no goal wrapper above: this wrapper reports the segments (Monitor CSV, rollout/*)
            self._segments.step(reward, terminated or truncated, info, None)  # type: ignore[arg-type]
        return obs, reward, terminated, truncated, info

"""Go/Explore phases, thesis Algorithm 1 (Go-Explore), with goals from a scheduler (Algorithm 3 for MoReFree).

Each segment SB3 sees is one Go-Explore: a Go phase of at most ``go_steps`` steps toward the commanded goal (it
ends early once the goal is reached), then an Explore phase of ``explore_steps`` steps in which an exploration
policy *replaces* the agent's action. The thesis sets H_G = H_E = half the evaluation horizon (Section 3.7.2,
"reset-free PEG"); so do the defaults here.

Executed actions: during Explore the env executes the exploration action, not the agent's.
The wrapper reports it as ``info["executed_action"]`` and the replay buffers of :mod:`sb3_gcrl.her`
(:class:`~sb3_gcrl.her.ExecutedActionHerReplayBuffer` and subclasses) store that action instead of the ignored
policy action. This works with stock SB3 algorithms and from an RL-Zoo YAML (``replay_buffer_class``).

Departure from the thesis: the exploration policy pi_E is uniform random by default (the thesis trains pi_E on
a world-model disagreement reward); any callable ``(obs, rng) -> action`` can be plugged in.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import unwrap_wrapper

from sb3_gcrl.goals.schedulers import GoalScheduler
from sb3_gcrl.wrappers.goal_command import GoalCommandWrapper
from sb3_gcrl.wrappers.reset_free import ResetFreeWrapper

ExplorePolicy = Callable[[dict[str, np.ndarray], np.random.Generator], np.ndarray]

#: info key holding the action the env really executed when it differs from the agent's
EXECUTED_ACTION_KEY = "executed_action"


class GoExploreWrapper(GoalCommandWrapper):
    """Go toward a scheduled goal, then explore; one Go-Explore per SB3 segment (thesis Algorithms 1 and 3).

    :param env: goal env, normally wrapped in :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` (with
        ``segment_length=None``: this wrapper ends the segments).
    :param scheduler: goal scheduler or its name (see :class:`GoalCommandWrapper`); ``"back_and_forth"`` is
        MoReFree's Back-and-Forth Go-Explore, ``"novelty"`` alone is reset-free Go-Explore (alpha = 0).
    :param scheduler_kwargs: keyword arguments of :func:`~sb3_gcrl.goals.make_scheduler`.
    :param eval_horizon: evaluation episode length T_eval; the default H_G = H_E = T_eval // 2. Read from the
        :class:`~sb3_gcrl.wrappers.ResetFreeWrapper` below when left out (state it once, there); giving both
        with different values is an error.
    :param go_steps: H_G, the longest Go phase (overrides the default from ``eval_horizon``).
    :param explore_steps: H_E, the Explore phase length, may be 0 (overrides the default from ``eval_horizon``).
    :param explore_policy: ``"random"`` (uniform actions from the action space) or a callable
        ``(obs, rng) -> action`` returning an action of the env's action space.
    :param end_go_on_success: end the Go phase as soon as the commanded goal is reached (Algorithm 1 always runs
        H_G steps).
    :param success_distance: see :class:`GoalCommandWrapper`.
    :param task_goal_capacity: see :class:`GoalCommandWrapper`.
    """

    #: random exploration actions drawn per block
    RANDOM_BLOCK = 1024
    run_state_attributes = (*GoalCommandWrapper.run_state_attributes, "phase_steps_total")

    def __init__(
        self,
        env: gym.Env,
        scheduler: GoalScheduler | str = "back_and_forth",
        scheduler_kwargs: dict[str, Any] | None = None,
        eval_horizon: int | None = None,
        go_steps: int | None = None,
        explore_steps: int | None = None,
        explore_policy: str | ExplorePolicy = "random",
        end_go_on_success: bool = True,
        success_distance: float | None = None,
        task_goal_capacity: int = 10_000,
    ) -> None:
        # record this class's arguments (so gym.make can re-create the wrapper), before the parent records its own
        gym.utils.RecordConstructorArgs.__init__(
            self,
            scheduler=scheduler,
            scheduler_kwargs=scheduler_kwargs,
            eval_horizon=eval_horizon,
            go_steps=go_steps,
            explore_steps=explore_steps,
            explore_policy=explore_policy,
            end_go_on_success=end_go_on_success,
            success_distance=success_distance,
            task_goal_capacity=task_goal_capacity,
        )
        super().__init__(env, scheduler, scheduler_kwargs, success_distance, task_goal_capacity)
        reset_free = unwrap_wrapper(env, ResetFreeWrapper)
        below = None if reset_free is None else reset_free.eval_horizon
        if eval_horizon is not None and below is not None and int(eval_horizon) != below:
            raise ValueError(
                f"eval_horizon given twice with different values: GoExploreWrapper(eval_horizon={eval_horizon}) but "
                f"ResetFreeWrapper(eval_horizon={below}) below it; give it once, to ResetFreeWrapper"
            )
        eval_horizon = below if eval_horizon is None else eval_horizon
        if (go_steps is None or explore_steps is None) and eval_horizon is None:
            raise ValueError(
                "GoExploreWrapper needs eval_horizon (H_G = H_E = eval_horizon // 2): give it to the ResetFreeWrapper "
                "below (or to GoExploreWrapper), or give go_steps and explore_steps"
            )
        half = None if eval_horizon is None else max(1, int(eval_horizon) // 2)
        self.go_steps = int(go_steps if go_steps is not None else half)  # type: ignore[arg-type]
        self.explore_steps = int(explore_steps if explore_steps is not None else half)  # type: ignore[arg-type]
        if self.go_steps < 1 or self.explore_steps < 0:
            raise ValueError(f"need go_steps >= 1 and explore_steps >= 0, got {self.go_steps}, {self.explore_steps}")
        if explore_policy == "random":
            self._explore_policy: ExplorePolicy = self._random_action
        elif callable(explore_policy):
            self._explore_policy = explore_policy
        else:
            raise ValueError(
                f"explore_policy must be 'random' or a callable (obs, rng) -> action, got {explore_policy!r}"
            )
        self.end_go_on_success = end_go_on_success
        self.phase = "go"
        self._phase_steps = 0
        self._obs: dict[str, np.ndarray] | None = None
        #: steps spent in each phase (reset-free mode)
        self.phase_steps_total = {"go": 0, "explore": 0}
        self._random_block: np.ndarray | None = None
        self._random_pos = 0

    def _random_action(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        # uniform actions drawn in blocks from the wrapper's seeded generator (Box.sample costs ~20 us per call)
        space = self.action_space
        if self._random_block is None or self._random_pos == len(self._random_block):
            if isinstance(space, spaces.Box) and space.is_bounded():
                self._random_block = rng.uniform(space.low, space.high, (self.RANDOM_BLOCK, *space.shape))
                self._random_block = self._random_block.astype(space.dtype)
            elif isinstance(space, spaces.Discrete):
                self._random_block = space.start + rng.integers(0, space.n, self.RANDOM_BLOCK, dtype=space.dtype)
            else:
                return space.sample()
            self._random_pos = 0
        self._random_pos += 1
        return self._random_block[self._random_pos - 1].copy()

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if seed is not None:
            self.action_space.seed(seed)
            self._random_block = None
        obs, info = super().reset(seed=seed, options=options)
        self.phase, self._phase_steps, self._obs = "go", 0, obs
        return obs, info

    def _training_step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        phase = self.phase
        if phase == "explore":
            action = self._explore_policy(self._obs, self._rng)  # type: ignore[arg-type]
        obs, reward, terminated, truncated, info = super()._training_step(action)
        self.phase_steps_total[phase] += 1
        self._phase_steps += 1
        if phase == "explore":
            info[EXECUTED_ACTION_KEY] = action
        elif self._phase_steps >= self.go_steps or (self.end_go_on_success and info["is_success"]):
            self.phase, self._phase_steps = "explore", 0
        if self.phase == "explore" and self._phase_steps >= self.explore_steps:
            truncated = True  # one Go-Explore per segment: SB3 bootstraps through the cut
        self._obs = obs
        return obs, reward, terminated, truncated, info

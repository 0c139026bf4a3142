"""Go/Explore phases, thesis Algorithm 1 (Go-Explore), with goals from a scheduler (Algorithm 3 for MoReFree).

Each segment SB3 sees is one Go-Explore: a Go phase of at most ``go_steps`` steps toward the commanded goal (it
ends early once the goal is reached), then an Explore phase of ``explore_steps`` steps. The thesis sets
H_G = H_E = half the evaluation horizon (Section 3.7.2, "reset-free PEG"); so do the defaults here.

Who acts in the Explore phase: either the wrapper's own exploration policy, which *replaces* the agent's action
(uniform random by default, or any callable ``(obs, rng) -> action``), or, with ``explore_policy="agent"``, the
agent itself with its explorer pi_E (MoReFree's Plan2Explore policy): the env then executes the action it is sent.

Executed actions: during Explore the wrapper reports the action the env executed as ``info["executed_action"]``,
and the replay buffers of :mod:`sb3_gcrl.her` (:class:`~sb3_gcrl.her.ExecutedActionHerReplayBuffer` and subclasses)
store that action instead of the ignored policy action. This works with stock SB3 algorithms and from an RL-Zoo YAML
(``replay_buffer_class``).

Public interface for agents (read per env through ``VecEnv.get_attr`` / ``VecEnv.env_method``, so that it works in
any VecEnv, a ``SubprocVecEnv`` included; nothing but plain data crosses the process boundary):

* :attr:`GoExploreWrapper.phase` (``"go"`` / ``"explore"``), :attr:`GoExploreWrapper.agent_explores` and
  :attr:`GoExploreWrapper.acting_policy`, which says whose action the env executes at the next step: the agent's
  goal-conditioned policy (``"goal"``), the agent's explorer (``"explorer"``) or the wrapper's exploration policy
  (``"wrapper"``).
* Goals planned by the agent (MoReFree's PEG goals): an :class:`AgentGoalScheduler` in the wrapper's scheduler leaves
  its goals to an agent that declared itself with :meth:`GoExploreWrapper.set_goal_planning`. The reset that needs
  such a goal marks its info with ``GOAL_REQUEST_KEY``; the agent reads the request
  (:meth:`GoExploreWrapper.goal_request`: the observation and the wrapper's generator) and answers it
  (:meth:`GoExploreWrapper.answer_goal_request`) before the next step. The planner draws from the wrapper's generator,
  so a run does not depend on the VecEnv class.

Departure from the thesis: the model-free setup's pi_E is uniform random by default (the thesis trains pi_E on
a world-model disagreement reward, as the world-model agent :class:`~sb3_gcrl.morefree.MoReFree` does).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import unwrap_wrapper

from sb3_gcrl.common.validation import check_bool, check_int
from sb3_gcrl.goals.schedulers import GoalScheduler
from sb3_gcrl.wrappers.goal_command import GoalCommandWrapper
from sb3_gcrl.wrappers.goal_env import record_constructor_args
from sb3_gcrl.wrappers.reset_free import ResetFreeWrapper

ExplorePolicy = Callable[[dict[str, np.ndarray], np.random.Generator], np.ndarray]

#: info key holding the action the env executed in an Explore-phase step
EXECUTED_ACTION_KEY = "executed_action"
#: reset-info key, True when the new segment's goal waits for the agent's plan (:meth:`GoExploreWrapper.goal_request`)
GOAL_REQUEST_KEY = "goal_request"
#: values of :attr:`GoExploreWrapper.acting_policy`: the agent's goal-conditioned policy, the agent's explorer, the
#: wrapper's exploration policy
ACTING_GOAL, ACTING_EXPLORER, ACTING_WRAPPER = "goal", "explorer", "wrapper"


class AgentGoalScheduler(GoalScheduler):
    """Goals planned by the agent in its own process, asked for through the wrapper (e.g. MoReFree's PEG goals).

    While no agent plans (before ``learn``, ``rl_zoo3 enjoy``, an agent that does not plan goals) the goals come from
    ``fallback``. While one does (:meth:`GoExploreWrapper.set_goal_planning`), :meth:`next_goal` records a request and
    returns a placeholder (the current achieved goal, no random draw); the :class:`GoExploreWrapper` reports the
    request in the reset info and commands the agent's answer (:meth:`answer`) before the next step. An answer of
    None (the agent cannot plan yet) takes the fallback's goal, drawn then.

    Use it as the wrapper's scheduler or as the ``exploratory`` scheduler of a
    :class:`~sb3_gcrl.goals.BackAndForthScheduler`.

    :param fallback: scheduler of the goals the agent does not plan (e.g. :class:`~sb3_gcrl.goals.NoveltyScheduler`);
        it also sees every achieved goal.
    """

    kind = "explore"

    def __init__(self, fallback: GoalScheduler) -> None:
        self.fallback = fallback
        #: whether an agent answers the requests (set through :meth:`GoExploreWrapper.set_goal_planning`)
        self.planning = False
        #: the observation of the pending request, None when no goal waits
        self.request: dict[str, np.ndarray] | None = None
        #: goals planned by the agent / taken from the fallback
        self.n_planned = 0
        self.n_fallback = 0

    def observe(self, achieved_goal: np.ndarray) -> None:
        self.fallback.observe(achieved_goal)

    def observe_task_goal(self, goal: np.ndarray) -> None:
        self.fallback.observe_task_goal(goal)

    def reset_pending(self) -> None:
        self.fallback.reset_pending()

    def next_goal(self, obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
        if not self.planning:
            self.n_fallback += 1
            return self.fallback.next_goal(obs, rng)
        self.request = {key: np.array(value, copy=True) for key, value in obs.items()}
        return np.array(obs["achieved_goal"], dtype=np.float64, copy=True)

    def answer(self, goal: np.ndarray | None, rng: np.random.Generator) -> np.ndarray:
        """Close the pending request with the agent's goal (None: the fallback's goal for the request's observation).

        :param goal: the planned goal, or None.
        :param rng: the wrapper's generator (the fallback draws from it).
        :return: the goal to command.
        """
        if self.request is None:
            raise RuntimeError("no goal request is pending: answer a request only after a reset reported one")
        obs, self.request = self.request, None
        if goal is None:
            self.n_fallback += 1
            return self.fallback.next_goal(obs, rng)
        self.n_planned += 1
        return np.asarray(goal, dtype=np.float64)

    def __getstate__(self) -> dict[str, Any]:
        # the planning agent declares itself again at the start of learn; a saved copy takes the fallback's goals
        return {**self.__dict__, "planning": False, "request": None}


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
    :param explore_policy: who acts in the Explore phase: ``"random"`` (uniform actions from the action space), a
        callable ``(obs, rng) -> action`` returning an action of the env's action space (both replace the agent's
        action), or ``"agent"`` (the env executes the agent's action: its explorer pi_E when it reads
        :attr:`acting_policy`, e.g. :class:`~sb3_gcrl.morefree.MoReFree`; a stock SB3 agent keeps its own policy).
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
        record_constructor_args(self, locals())
        super().__init__(env, scheduler, scheduler_kwargs, success_distance, task_goal_capacity)
        reset_free = unwrap_wrapper(env, ResetFreeWrapper)
        below = None if reset_free is None else reset_free.eval_horizon
        if eval_horizon is not None and below is not None and int(eval_horizon) != below:
            raise ValueError(
                f"eval_horizon given twice with different values: GoExploreWrapper(eval_horizon={eval_horizon}) but "
                f"ResetFreeWrapper(eval_horizon={below}) below it; give it once, to ResetFreeWrapper"
            )
        eval_horizon = below if eval_horizon is None else check_int("eval_horizon", eval_horizon, minimum=2)
        if (go_steps is None or explore_steps is None) and eval_horizon is None:
            raise ValueError(
                "GoExploreWrapper needs eval_horizon (H_G = H_E = eval_horizon // 2): give it to the ResetFreeWrapper "
                "below (or to GoExploreWrapper), or give go_steps and explore_steps"
            )
        half = None if eval_horizon is None else int(eval_horizon) // 2
        self.go_steps = check_int("go_steps", go_steps if go_steps is not None else half)
        self.explore_steps = check_int("explore_steps", explore_steps if explore_steps is not None else half, 0)
        self._explore_policy: ExplorePolicy | None
        if explore_policy == "random":
            self._explore_policy = self._random_action
        elif explore_policy == "agent":
            self._explore_policy = None
        elif callable(explore_policy):
            self._explore_policy = explore_policy
        else:
            raise ValueError(
                f"explore_policy must be 'random', 'agent' or a callable (obs, rng) -> action, got {explore_policy!r}"
            )
        #: whether the Explore phase executes the agent's action (``explore_policy="agent"``)
        self.agent_explores = self._explore_policy is None
        self.end_go_on_success = check_bool("end_go_on_success", end_go_on_success)
        #: phase of the next training step: ``"go"`` or ``"explore"``
        self.phase = "go"
        self._phase_steps = 0
        self._obs: dict[str, np.ndarray] | None = None
        self._goal_request_open = False
        #: steps spent in each phase (reset-free mode)
        self.phase_steps_total = {"go": 0, "explore": 0}
        self._random_block: np.ndarray | None = None
        self._random_pos = 0

    # --- public interface for agents (VecEnv.get_attr / env_method) ---------------------------------------------
    @property
    def acting_policy(self) -> str:
        """Whose action the env executes at the next step.

        ``"goal"``: the agent's goal-conditioned policy pi_G, toward the observation's ``desired_goal`` (the Go phase,
        and every step in evaluation mode); ``"explorer"``: the agent's explorer pi_E (the Explore phase with
        ``explore_policy="agent"``); ``"wrapper"``: the wrapper's exploration policy (the Explore phase otherwise;
        the agent's action is ignored, any action of the action space will do).
        """
        if not self.training or self.phase == "go":
            return ACTING_GOAL
        return ACTING_EXPLORER if self.agent_explores else ACTING_WRAPPER

    @property
    def replaces_actions(self) -> bool:
        """Whether the Explore phase executes the wrapper's own actions instead of the agent's (a replay buffer must
        then store ``info["executed_action"]``: :class:`~sb3_gcrl.her.ExecutedActionHerReplayBuffer`)."""
        return not self.agent_explores and self.explore_steps > 0

    @property
    def agent_goal_scheduler(self) -> AgentGoalScheduler | None:
        """The :class:`AgentGoalScheduler` of this wrapper (its scheduler, or the exploratory scheduler of a
        Back-and-Forth scheduler), None when the goals are never planned by the agent."""
        scheduler = self.scheduler
        scheduler = getattr(scheduler, "exploratory", scheduler)
        return scheduler if isinstance(scheduler, AgentGoalScheduler) else None

    @property
    def takes_planned_goals(self) -> bool:
        """Whether some goals of this wrapper can be planned by the agent (it has an :class:`AgentGoalScheduler`)."""
        return self.agent_goal_scheduler is not None

    @property
    def planned_goal_counts(self) -> dict[str, int]:
        """Goals of the :class:`AgentGoalScheduler` so far: ``{"planned": planned by the agent, "fallback": taken
        from the fallback scheduler}`` (both 0 without one)."""
        scheduler = self.agent_goal_scheduler
        if scheduler is None:
            return {"planned": 0, "fallback": 0}
        return {"planned": scheduler.n_planned, "fallback": scheduler.n_fallback}

    def set_goal_planning(self, planning: bool) -> None:
        """Declare that the agent plans (True) or stops planning (False) the :class:`AgentGoalScheduler`'s goals.

        While planning, every reset that draws such a goal reports ``info[GOAL_REQUEST_KEY] = True`` and the agent
        must answer it (:meth:`goal_request`, :meth:`answer_goal_request`) before the next step.

        :param planning: whether the agent answers the goal requests.
        """
        scheduler = self.agent_goal_scheduler
        if scheduler is None:
            raise ValueError(
                "this GoExploreWrapper's scheduler has no AgentGoalScheduler, so no goal is planned by the agent: "
                "read takes_planned_goals first"
            )
        scheduler.planning = bool(planning)
        if not planning:
            scheduler.request = None
            self._goal_request_open = False

    def goal_request(self) -> tuple[dict[str, np.ndarray], np.random.Generator] | None:
        """The pending goal request: the observation to plan from and the generator the planner draws from (pass it
        back to :meth:`answer_goal_request`); None when no goal waits."""
        scheduler = self.agent_goal_scheduler
        if scheduler is None or scheduler.request is None:
            return None
        return scheduler.request, self._rng

    def answer_goal_request(self, goal: np.ndarray | None, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Command the agent's goal for the pending request and return the segment's first observation with it.

        :param goal: the planned goal, or None to take the fallback scheduler's goal.
        :param rng: the generator of :meth:`goal_request`, advanced by the planner (in a ``SubprocVecEnv`` a copy:
            the wrapper continues from its state).
        :return: the observation of the reset, commanding the new goal.
        """
        scheduler = self.agent_goal_scheduler
        if scheduler is None or scheduler.request is None:
            raise RuntimeError("no goal request is pending: answer a request only after a reset reported one")
        self._rng = rng
        self._set_goal(scheduler.answer(goal, rng))
        self._goal_request_open = False
        assert self._obs is not None
        self._obs = self._command(self._obs)
        return self._obs

    def _segment_bound(self) -> int:
        """One Go-Explore per segment: at most ``go_steps`` Go steps, then ``explore_steps`` Explore steps."""
        return self.go_steps + self.explore_steps

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
        scheduler = self.agent_goal_scheduler
        self._goal_request_open = scheduler is not None and scheduler.request is not None
        if self._goal_request_open:
            info[GOAL_REQUEST_KEY] = True
        return obs, info

    def _training_step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        phase = self.phase
        if self._goal_request_open:
            raise RuntimeError(
                "the segment's goal is still waiting for the agent's plan: answer the reset's goal request "
                "(goal_request, then answer_goal_request) before stepping, or call set_goal_planning(False)"
            )
        if phase == "explore" and self._explore_policy is not None:
            action = self._explore_policy(self._obs, self._rng)  # type: ignore[arg-type]
            if self._explore_policy != self._random_action and not self.action_space.contains(
                np.asarray(action, dtype=self.action_space.dtype)
            ):
                raise ValueError(
                    f"explore_policy returned {action!r}, which is not an action of the env's {self.action_space}: "
                    "return an action of that shape, within its bounds (the env would run it, the buffer would "
                    "store it clipped)"
                )
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
